"""``volume_bounds_m3`` where the points cannot pin the volume down, found by a review that fed real-scanner
clouds the benchmark has none of: a cup whose inner floor no point reached (-12 %, the truth outside an interval
as wide as the closing shell), and coordinates written rounded to whole millimetres (a 40.5 mm cube is a 40 mm
cube to them: -3.6 %, an interval of +-0.1 %, no warning)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation
from trimesh.transformations import rotation_matrix

from estimation import estimate, make_cloud
from estimation.lattice import lattice_step


def _inside(result, truth: float) -> bool:
    low, high = result.volume_bounds_m3
    return low <= truth <= high


def test_a_mug_whose_inner_floor_no_point_reached_holds_its_volume_in_the_interval():
    outer = trimesh.creation.cylinder(radius=0.04, height=0.09, sections=128)
    inner = trimesh.creation.cylinder(radius=0.036, height=0.09, sections=128)
    inner.apply_translation([0.0, 0.0, 0.005])  # a 5 mm base, open at the top
    handle = trimesh.creation.torus(major_radius=0.027, minor_radius=0.006, major_sections=64, minor_sections=24)
    handle.apply_transform(rotation_matrix(np.pi / 2, [1, 0, 0]))
    handle.apply_translation([0.0535, 0.0, 0.0])
    # With its handle: without one, the points were taken for one sheet, the interval 0..inf.
    cup = outer.difference(inner).union(handle)
    floor = -0.045 + 0.005
    points = trimesh.sample.sample_surface(cup, 100_000, seed=0)[0]
    r = np.hypot(points[:, 0], points[:, 1])
    seen = ~((np.abs(points[:, 2] - floor) < 2e-4) & (r < 0.036 - 1e-4))
    result = estimate(make_cloud(points[seen]), 1000.0)
    assert result.volume < 0.97 * cup.volume  # the base below the unseen floor taken for outside
    assert _inside(result, cup.volume), (result.volume_bounds_m3, cup.volume)
    assert any("not measured" in w for w in result.warnings)
    # The whole cup, every face measured: a tight interval, as before.
    whole = estimate(make_cloud(points), 1000.0)
    assert whole.volume == pytest.approx(cup.volume, rel=0.01) and _inside(whole, cup.volume)
    low, high = whole.volume_bounds_m3
    assert high - low < 0.05 * cup.volume


def test_coordinates_rounded_to_a_lattice_widen_the_interval_and_say_so():
    cube = trimesh.creation.box((0.0405, 0.0405, 0.0405))
    points = trimesh.sample.sample_surface(cube, 60_000, seed=1)[0]
    rounded = np.round(points, 3)  # written with three decimals in metres: whole millimetres
    assert lattice_step(rounded) == pytest.approx(1e-3, rel=1e-6)
    result = estimate(make_cloud(rounded), 1000.0)
    assert result.volume == pytest.approx(0.040**3, rel=0.01)  # what the points say: a 40 mm cube
    assert _inside(result, cube.volume), (result.volume_bounds_m3, cube.volume)
    assert any("1 mm lattice" in w for w in result.warnings), result.warnings
    # The same cube turned, not rounded: no lattice, no such warning.
    turned = points @ Rotation.random(random_state=2).as_matrix().T
    assert lattice_step(turned) == 0.0
    plain = estimate(make_cloud(turned), 1000.0)
    assert not any("lattice" in w for w in plain.warnings)
    low, high = plain.volume_bounds_m3
    assert high - low < 0.01 * cube.volume


def test_a_lattice_is_found_in_float32_and_far_from_the_origin_and_not_in_noise():
    rng = np.random.default_rng(3)
    points = rng.uniform(-0.05, 0.05, (50_000, 3))
    assert lattice_step(np.round(points * 2000) / 2000) == pytest.approx(5e-4, rel=1e-6)
    assert lattice_step(np.round(points, 3).astype(np.float32)) == pytest.approx(1e-3, rel=1e-5)
    assert lattice_step(np.round(points, 3) + np.array([20.0, -7.0, 3.0])) == pytest.approx(1e-3, rel=1e-6)
    assert lattice_step(points) == 0.0
    assert lattice_step(np.round(points, 3) + rng.normal(0, 1e-5, points.shape)) == 0.0
