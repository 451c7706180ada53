"""Clouds sampled unevenly: a side seen from afar, or views of unequal resolution, leaves part of the surface
far sparser than the rest. The cell follows the typical spacing; the sparse part's gaps were holes the flood
fill could not close, and a ball sampled 30 times less densely on its lower half came out with its volume
unknown (0..inf m^3). estimate._at_sparse_spacing reconstructs again at the sparse parts' spacing."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from estimation import estimate, make_cloud
from estimation.spacing import point_spacing, sparse_spacing


def _uneven(mesh: trimesh.Trimesh, thinning: float, n: int = 50_000, seed: int = 3) -> np.ndarray:
    """``n`` surface points of ``mesh``, those below its middle kept with probability ``thinning``."""
    points = np.asarray(trimesh.sample.sample_surface(mesh, n, seed=seed)[0])
    # Not the sampler's seed: trimesh draws the points from default_rng(seed), and the same stream would thin
    # exactly the lower half's points away.
    keep = (points[:, 2] > mesh.centroid[2]) | (np.random.default_rng([seed, 1]).random(n) < thinning)
    return points[keep]


BALL = trimesh.creation.icosphere(subdivisions=5, radius=0.05)
BOX = trimesh.creation.box((0.08, 0.06, 0.04))


def test_the_sparse_spacing_tells_an_uneven_cloud_from_an_even_one():
    even, uneven = _uneven(BALL, 1.0), _uneven(BALL, 1 / 30)
    assert sparse_spacing(even, 0.1) / point_spacing(even) < 1.5
    # The lower half at a 30th of the density: spaced sqrt(30) = 5.5 times wider.
    assert sparse_spacing(uneven, 0.1) / point_spacing(uneven) > 4.0
    assert sparse_spacing(np.zeros((1, 3)), 0.1) == 0.0


@pytest.mark.parametrize("mesh", [BALL, BOX], ids=["ball", "box"])
@pytest.mark.slow  # 2-3 s each, and the default run is near its 10 minutes
@pytest.mark.parametrize("thinning", [1 / 15, 1 / 30])
def test_a_cloud_sparse_on_one_side_is_estimated_at_the_sparse_spacing(mesh, thinning):
    est = estimate(make_cloud(_uneven(mesh, thinning)), 1000.0)
    assert est.volume == pytest.approx(mesh.volume, rel=0.005)
    assert est.volume_bounds_m3 is not None and np.isfinite(est.volume_bounds_m3[1])
    assert any("spaced unevenly" in w for w in est.warnings), est.warnings


@pytest.mark.slow
def test_an_even_cloud_is_estimated_at_its_own_spacing_and_says_nothing_of_it():
    est = estimate(make_cloud(_uneven(BALL, 1.0)), 1000.0)
    assert est.volume == pytest.approx(BALL.volume, rel=0.001)
    assert est.cell < 2 * point_spacing(_uneven(BALL, 1.0))
    assert not any("spaced unevenly" in w for w in est.warnings)
