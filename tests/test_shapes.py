"""`auto` on a seeded subset of the generalisation benchmark (bench/shapes.py), against the issue's targets.

The tolerances are the targets themselves, per shape (the benchmark's "max" column) and over the
subset (its "median" column); they are not fitted to what the code reaches. The subset covers every
family: thin shells and plates (1.6-3 mm walls), sharp low-poly polyhedra, concave shapes with handles
and holes, smooth, elongated and flat ones, 1 cm to 1 m. 80k points per cloud (the benchmark uses
100k): a little sparser, so a little harder.
"""

from __future__ import annotations

import numpy as np
import pytest

from estimation import estimate
from scenes.sampling import sample_surface
from scenes.shapes import inside_out, make_shapes

RHO = 1000.0
POINTS = 80_000

#: Shape indices in ``make_shapes(22)``: cup, tray, plate, random hull, star, wedge, mug, frame,
#: torus, blob, rod, disc.
SUBSET = (0, 1, 4, 6, 8, 10, 11, 12, 18, 19, 20, 21)

#: (median, max) absolute volume error, % -- the issue's targets.
VOLUME_TARGETS = {"given": (0.25, 1.0), "estimated": (0.5, 2.0), "noisy": (1.0, 3.0)}

#: Inertia (relative Frobenius norm of the tensor error, %) with given normals: median, max.
INERTIA_TARGET = (0.3, 1.0)

#: Centre of mass, metres.
COM_TARGET = 0.2e-3


@pytest.fixture(scope="module")
def shapes():
    return make_shapes(22)


def _errors(shape, condition: str, seed: int) -> tuple[float, float, float, object]:
    noisy = condition == "noisy"
    cloud = sample_surface(shape.mesh, POINTS, seed=seed, noise_sigma=0.0005 if noisy else 0.0,
                           with_normals=condition == "given")
    est = estimate(cloud, RHO)
    truth = shape.inertia(RHO)
    return (100 * abs(est.volume / shape.volume - 1),
            float(np.linalg.norm(est.mass.center_of_mass - shape.center_of_mass)),
            100 * float(np.linalg.norm(est.mass.inertia - truth) / np.linalg.norm(truth)), est)


# "estimated" (~18 s) and "noisy" run in CI's slow run; "given" keeps the benchmark subset in the default one.
@pytest.mark.parametrize("condition", ["given", pytest.param("estimated", marks=pytest.mark.slow),
                                       pytest.param("noisy", marks=pytest.mark.slow)])
def test_volume_com_and_inertia_meet_the_targets(shapes, condition):
    rows = []
    for i in SUBSET:
        shape = shapes[i]
        if condition == "noisy" and shape.min_wall < 0.003:
            continue  # the target covers walls of 3 mm and more under 0.5 mm noise
        volume, com, inertia, est = _errors(shape, condition, seed=i)
        rows.append((shape.name, volume, com, inertia))
        assert est.volume_bounds_m3 is not None
    volumes = np.array([r[1] for r in rows])
    median_target, max_target = VOLUME_TARGETS[condition]
    worst = max(rows, key=lambda r: r[1])
    assert volumes.max() < max_target, f"worst volume error {worst[1]:.3f} % on {worst[0]}"
    assert np.median(volumes) < median_target
    if condition != "noisy":
        worst_com = max(rows, key=lambda r: r[2])
        assert worst_com[2] < COM_TARGET, f"centre of mass off by {1000 * worst_com[2]:.3f} mm on {worst_com[0]}"
    if condition == "given":
        inertias = np.array([r[3] for r in rows])
        assert np.median(inertias) < INERTIA_TARGET[0]
        assert inertias.max() < INERTIA_TARGET[1]


def test_true_volume_lies_within_the_reported_bounds_on_a_thin_shell(shapes):
    cup = shapes[0]
    est = estimate(sample_surface(cup.mesh, POINTS, seed=7, with_normals=False), RHO)
    low, high = est.volume_bounds_m3
    assert low <= est.volume <= high
    assert low <= cup.volume * 1.01 and high >= cup.volume * 0.99


def test_walls_thinner_than_the_point_spacing_are_flagged():
    # A 0.6 mm plate sampled at ~1 mm spacing: the cloud cannot say how thick it is.
    import trimesh

    plate = trimesh.creation.box(extents=(0.12, 0.10, 0.0006))
    est = estimate(sample_surface(plate, 25_000, seed=8), RHO)
    assert any("thinner than the point spacing" in w for w in est.warnings)
    low, high = est.volume_bounds_m3
    assert low <= plate.volume <= high


def test_a_drilled_blocks_wall_is_its_thinnest_bore_wall():
    # The block's smallest extent (in its random pose, at that) was taken for the wall of any drilled block.
    from scenes.shapes import _drilled_wall

    extents = np.array([1.0, 0.6, 0.4])
    near_face = (0, np.array([0.0, 0.0, 0.1]), 0.09)  # along x, 0.01 under the top face (z = 0.2)
    assert _drilled_wall(extents, [near_face]) == pytest.approx(0.01)
    parallel = (0, np.array([0.0, 0.15, -0.05]), 0.05)  # 0.158 from the other's axis: a 0.018 wall between them
    assert _drilled_wall(extents, [parallel, (0, np.array([0.0, 0.0, 0.0]), 0.09)]) == pytest.approx(
        np.hypot(0.15, 0.05) - 0.14)
    crossing = [(0, np.array([0.0, 0.0, 0.05]), 0.05), (1, np.array([0.0, 0.0, -0.07]), 0.05)]  # 0.12 apart in z
    assert _drilled_wall(extents, crossing) == pytest.approx(0.02)
    through = (0, np.array([0.0, 0.12, 0.19]), 0.05)  # breaks out of the top face: an open slot, no wall there
    assert _drilled_wall(extents, [through]) == pytest.approx(0.3 - 0.12 - 0.05)  # the side face's is the thinnest


@pytest.mark.slow  # ~13 s: in CI's slow run, to keep the default run under ten minutes
def test_a_bore_the_probe_cannot_read_takes_its_normals_side_from_its_most_parallel_neighbours():
    """bench/shapes.py seed 1's drilled block (two crossing 9-10 mm bores in a 7 cm block) under 0.5 mm of noise,
    no normals: the outside probe could not read most of a bore's wall, whose points then voted with every sure
    neighbour across the crease at its mouth, square to them, where noise casts the vote. 7 % of the normals came
    out inside out and the block +5.0 %."""
    shape = make_shapes(44, 1)[35]
    assert shape.name == "concave-drilled-35"
    cloud = sample_surface(shape.mesh, 100_000, seed=[1, 35, 2], noise_sigma=0.0005, with_normals=False)
    est = estimate(cloud, RHO)
    assert inside_out(shape.mesh, est.points, est.normals) < 0.03  # 0.071 before
    assert abs(est.volume / shape.volume - 1) < VOLUME_TARGETS["noisy"][1] / 100  # +4.97 % before
