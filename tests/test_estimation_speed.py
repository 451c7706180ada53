"""The fast paths of 'auto' against their slow references, the point budget and its refinement, and the lazy package.

No timing is asserted: these check that what was made fast still computes the same thing.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy import ndimage

from estimation import estimate
from estimation import tolerances as tol
from estimation.dualcontour import QEF_RELATIVE_EIGENVALUE, _pinv_2x2
from estimation.grid import CLOSING_RADII, _ball_radius2, grid_around, occupancy
from estimation.implicit import NEIGHBOURS_27, _locate_27
from estimation.normals import estimate_normals
from estimation.obb import column_bounds, oriented_box_local
from estimation.sparsegrid import narrow_band
from scenes.sampling import sample_surface
from scenes.shapes import make_shapes

RHO = 1000.0


@pytest.fixture(scope="module")
def shapes():
    return {s.name: s for s in make_shapes(44, 0)}


@pytest.mark.parametrize("ratio", [2, 3, 4])
def test_locate_27_matches_band_locate(ratio, shapes):
    points = sample_surface(shapes["thin-cup-00"].mesh, 5000, seed=1).points
    grid = grid_around(points, 0.0015 * ratio)
    band = narrow_band(grid, occupancy(points, grid), ratio)
    base = np.rint((points - band.origin) / band.h).astype(np.int64)
    slow = band.locate((base[:, None, :] + NEIGHBOURS_27[None]).reshape(-1, 3))
    assert (slow >= 0).any()
    np.testing.assert_array_equal(_locate_27(band, base), np.where(slow < 0, band.size, slow))


@pytest.mark.parametrize("name", ["thin-cup-00", "concave-mug-11", "crease-star-08"])
def test_every_closing_shell_is_the_ball_dilation_of_the_occupied_nodes(name, shapes):
    # occupancy thresholds one distance transform; each shell must be what dilating by the ball gives.
    points = sample_surface(shapes[name].mesh, 4000, seed=2).points
    grid = grid_around(points, 0.004)
    occupied = np.zeros(grid.shape, dtype=bool)
    idx = grid.index_of(points)
    occupied[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    distance2 = np.rint(ndimage.distance_transform_edt(~occupied) ** 2)
    for radius in CLOSING_RADII:
        r = np.arange(-radius, radius + 1)
        x, y, z = np.meshgrid(r, r, r, indexing="ij")
        ball = (x**2 + y**2 + z**2) <= max(radius**2, 3)
        np.testing.assert_array_equal(distance2 <= _ball_radius2(radius),
                                      ndimage.binary_dilation(occupied, structure=ball))
    result = occupancy(points, grid)
    np.testing.assert_array_equal(result.shell, distance2 <= _ball_radius2(result.closing))


def test_closed_form_2x2_pseudo_inverse_matches_numpy():
    rng = np.random.default_rng(4)
    rank2 = rng.normal(size=(300, 2, 2))
    rank1 = rng.normal(size=(300, 2, 1))
    near1 = rank1 @ rank1.transpose(0, 2, 1) + 1e-3 * np.eye(2)  # a small second eigenvalue: dropped
    matrices = np.concatenate([rank2 @ rank2.transpose(0, 2, 1), rank1 @ rank1.transpose(0, 2, 1), near1,
                               np.zeros((5, 2, 2))])
    got = _pinv_2x2(matrices[:, 0, 0], matrices[:, 0, 1], matrices[:, 1, 1], QEF_RELATIVE_EIGENVALUE)
    want = np.linalg.pinv(matrices, rcond=QEF_RELATIVE_EIGENVALUE, hermitian=True)
    scale = np.abs(want).max(axis=(1, 2), keepdims=True) + 1e-300
    assert np.abs((got - want) / scale).max() < 1e-8
    # Spreads at or below the floor are dropped whatever their ratio.
    assert not _pinv_2x2(np.array([1e-24]), np.array([0.0]), np.array([1e-24]), 0.05, 1e-20).any()


def test_box_frame_points_are_the_box_transform():
    rng = np.random.default_rng(1)
    points = rng.normal(size=(5000, 3)) * [0.3, 0.1, 0.02] + [1.0, -2.0, 0.5]
    box, local = oriented_box_local(points)
    np.testing.assert_allclose(local, box.to_local(points), atol=1e-12)
    np.testing.assert_allclose(box.to_cloud(local), points, atol=1e-12)
    low, high = column_bounds(local)
    np.testing.assert_allclose(high - low, box.extents, atol=1e-12)
    np.testing.assert_allclose((low + high) / 2, 0, atol=1e-12)


def test_numpy_normals_are_radial_on_a_sphere():
    rng = np.random.default_rng(2)
    points = rng.normal(size=(4000, 3))
    points /= np.linalg.norm(points, axis=1, keepdims=True)
    normals = estimate_normals(points, 16)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1, atol=1e-9)
    assert np.abs(np.einsum("ij,ij->i", normals, points)).min() > 0.98


def test_dense_smooth_cloud_is_thinned_to_the_budget_and_stays_accurate(shapes):
    shape = shapes["smooth-blob-19"]
    est = estimate(sample_surface(shape.mesh, 4 * tol.POINT_BUDGET, seed=3), RHO)
    assert 0.7 * tol.POINT_BUDGET < est.points_used < 1.2 * tol.POINT_BUDGET
    assert abs(est.volume / shape.volume - 1) < 0.001


def test_a_thin_wall_the_budget_cannot_resolve_gets_a_finer_second_pass(shapes, monkeypatch):
    # A 1.6 mm tube wall: at 8k points the cells are wider than the wall and the first pass's volume
    # bounds say so; the second pass uses more of the cloud.
    shape = shapes["thin-tube-02"]
    cloud = sample_surface(shape.mesh, 60_000, seed=4)
    monkeypatch.setattr(tol, "POINT_BUDGET", 8000)
    est = estimate(cloud, RHO)
    assert est.points_used > 2 * 8000
    assert abs(est.volume / shape.volume - 1) < 0.005
    monkeypatch.setattr(tol, "REFINE_DOUBT", 1.0)  # never refine: the one pass is worse
    coarse = estimate(cloud, RHO)
    assert coarse.points_used < 1.2 * 8000
    assert abs(coarse.volume / shape.volume - 1) > abs(est.volume / shape.volume - 1)


def test_the_package_is_lazy_and_estimate_stays_the_function():
    code = (
        "import sys\n"
        "import estimation.errors\n"
        "assert 'numpy' not in sys.modules, 'estimation.errors pulled in numpy'\n"
        "import estimation.estimate\n"
        "from estimation import estimate\n"
        "import estimation\n"
        "assert callable(estimate) and estimation.estimate is estimate, estimation.estimate\n"
        "from estimation.estimate import Timings\n"
        "assert estimation.estimate is estimate\n"
        # materials too: the function, though its submodule was imported first (by material, estimate)
        "from estimation import material, materials\n"
        "assert callable(materials) and 'water' in materials(), materials\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
