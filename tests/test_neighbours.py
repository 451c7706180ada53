"""k nearest neighbours whose ties do not depend on the frame (``estimation.neighbours``)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from estimation.neighbours import nearest


def _lattice() -> np.ndarray:
    """A 12 x 12 pixel lattice on two depth layers, 2 mm apart: many points share each distance."""
    i, j = np.meshgrid(np.arange(12), np.arange(12), indexing="ij")
    flat = np.stack([i.ravel(), j.ravel(), np.zeros(i.size)], axis=1) * 0.002
    return np.concatenate([flat, flat[::3] + np.array([0.001, 0.001, 0.002])])


def test_a_rigid_motion_keeps_each_points_k_nearest():
    points = _lattice()
    k = 16
    dist, index = nearest(cKDTree(points), points, k)
    assert (np.diff(dist, axis=1) >= -1e-15).all() and (dist[:, 0] == 0).all()  # ties: rounding apart
    # The lattice really ties the k-th neighbour with the next for most points.
    full = np.sort(cKDTree(points).query(points, k=k + 1)[0], axis=1)
    assert (np.isclose(full[:, k - 1], full[:, k], rtol=1e-9, atol=0)).mean() > 0.5
    rng = np.random.default_rng(3)
    for _ in range(5):
        rot = Rotation.random(random_state=rng).as_matrix()
        moved = points @ rot.T + rng.uniform(-3, 3, 3)
        dist_m, index_m = nearest(cKDTree(moved), moved, k)
        assert (index_m == index).all()
        np.testing.assert_allclose(dist_m, dist, rtol=1e-9, atol=1e-15)


def test_ties_are_taken_in_index_order_and_k_may_be_every_point():
    points = np.array([[0.0, 0, 0], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]])
    dist, index = nearest(cKDTree(points), points[:1], 3)
    assert index.tolist() == [[0, 1, 2]] and dist.tolist() == [[0.0, 1.0, 1.0]]
    dist, index = nearest(cKDTree(points), points[:1], 5)
    assert index.tolist() == [[0, 1, 2, 3, 4]]


def test_a_mixed_cloud_matches_a_brute_force_order():
    """Rows with and without ties in one query (the untied ones skip the sort): each row is its ``k``
    nearest by distance, ties by index, as a brute-force sort of every distance gives."""
    rng = np.random.default_rng(5)
    rot = Rotation.random(random_state=rng).as_matrix()  # the tree's own order of ties is then not the index's
    points = np.concatenate([_lattice() @ rot.T, rng.uniform(0.03, 0.05, (300, 3))])
    full = np.linalg.norm(points[:, None] - points[None], axis=2)
    for k in range(1, 18):  # every k: the k-th sits at the start of a lattice shell for some
        _check_brute_force(points, k, full)


def _check_brute_force(points: np.ndarray, k: int, full: np.ndarray) -> None:
    dist, index = nearest(cKDTree(points), points, k)
    for row in range(len(points)):
        # Distances that differ only by rounding are one distance, as in ``nearest``.
        level = np.round(full[row] / 1e-12)
        want = np.lexsort((np.arange(len(points)), level))[:k]
        assert index[row].tolist() == want.tolist(), row
        np.testing.assert_allclose(dist[row], full[row, want], rtol=1e-12, atol=1e-15)
