"""Given normals: used as they come when consistent and outward; flipped when inward; re-signed when unoriented."""

from __future__ import annotations

import numpy as np
import pytest

from estimation import estimate, make_cloud
from scenes.sampling import sample_surface
from scenes.shapes import make_shapes

SHAPES = make_shapes(12, 11)


def _spoil(normals: np.ndarray, how: str, rng: np.random.Generator) -> np.ndarray:
    if how == "inward":  # another tool's convention
        return -normals
    if how == "unoriented":  # PCA normals with arbitrary signs (Open3D's estimate_normals)
        return normals * rng.choice([-1.0, 1.0], size=(len(normals), 1))
    return normals * np.where(rng.uniform(size=(len(normals), 1)) < 0.1, -1.0, 1.0)  # a tenth flipped


@pytest.mark.parametrize("index", [0, 11])  # a 1 mm-walled cup (no normals: +150 %), a mug
@pytest.mark.parametrize("how", ["inward", "unoriented", "a tenth flipped"])
def test_spoiled_normals_give_what_good_ones_give_and_say_so(index, how):
    shape = SHAPES[index]
    cloud = sample_surface(shape.mesh, 30_000, seed=[index, 4], with_normals=True)
    good = estimate(cloud, 1000.0)
    assert not any("normals" in w for w in good.warnings)
    assert abs(good.mass.volume / shape.volume - 1) < 0.01
    spoiled = estimate(make_cloud(cloud.points, _spoil(cloud.normals, how, np.random.default_rng(index))), 1000.0)
    # Trusted as they came, spoiled normals put shapes up to +466 % off (bench/given_normals.py).
    # A few points on the cup's rim may stay wrong: within 1 % of what the good normals give.
    assert spoiled.mass.volume == pytest.approx(good.mass.volume, rel=0.01)
    said = "point into the object" if how == "inward" else "not consistently oriented"
    assert any(said in w for w in spoiled.warnings), spoiled.warnings


def test_consistent_normals_are_used_exactly_as_given():
    from estimation.grid import grid_around, occupancy
    from estimation.normals import orient_given

    shape = SHAPES[6]
    cloud = sample_surface(shape.mesh, 20_000, seed=[6, 4], with_normals=True)
    grid = grid_around(cloud.points, float(np.ptp(cloud.points, axis=0).max()) / 100)
    normals, note = orient_given(cloud.points, cloud.normals, grid, occupancy(cloud.points, grid))
    assert normals is cloud.normals and note is None
