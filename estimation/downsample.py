"""Voxel-grid downsampling: the centroid (and mean normal) of the points in each voxel, as PCL's
``VoxelGrid`` does. Pure numpy: on a million points it is several times faster than open3d's, which
dominated the estimate's time."""

from __future__ import annotations

import numpy as np

from estimation import tolerances as tol
from estimation.obb import column_bounds

#: Largest voxel grid (cells) counted densely; beyond it we sort instead (memory ~16 bytes a cell).
DENSE_LIMIT = 16_000_000


def _rotation(axis_angle: tuple[float, float, float]) -> np.ndarray:
    """The 3 x 3 rotation of ``axis_angle`` (radians along the axis; Rodrigues' formula).

    Not scipy's ``Rotation``: this module is imported with the estimate, which leaves ``scipy.spatial`` (over
    0.1 s to import) to the functions that search points, and ``twin --help`` must start in 0.3 s."""
    v = np.asarray(axis_angle, float)
    angle = float(np.linalg.norm(v))
    k = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]]) / angle
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)


#: :func:`thin_to_budget` turns its voxels by this rotation off the frame the points are given in. In an
#: object's own box frame a manufactured object's faces lie along the axes, and a face parallel to the voxels
#: sits at one offset within them all over it: one point kept per voxel keeps the noise's sparse tail, in the
#: layer of voxels the face only grazes, as often as its dense middle, so the whole face moved (bench/noise_bias.py:
#: a 20 x 16 x 12 cm box, 200,000 points at sigma 0.5 mm, six poses: -0.115 to -0.334 % where the thinned pass
#: answered, its faces 0.05-0.13 mm in). Turned, the offset runs through the voxels along each face and the
#: tails cancel (-0.000 to +0.060 %, every pose).
#: This turn leaves every axis, face and body diagonal and 2:1 direction of the frame at least 15.7 degrees off
#: the voxels' axes (the best of 20,000 random rotations, 15.8, rounded).
LATTICE_TURN = _rotation((-1.79, -0.33, 0.0))


def _linear(key: np.ndarray, dims: np.ndarray) -> tuple[np.ndarray, float]:
    """Each row of ``key`` ((n, 3) int64 voxel indices, each below ``dims``) as one int64 in row-major order,
    and the grid's cell count (a float: it may pass int64's range).

    A grid past that range (copies of points 1e-12 m apart, over 10 cm: 1e33 cells) would wrap the keys and
    merge unrelated voxels; there the occupied voxels are numbered instead, in the same order.
    """
    cells = float(np.prod(dims.astype(np.float64)))
    if cells < 2.0**62:
        return (key[:, 0] * dims[1] + key[:, 1]) * dims[2] + key[:, 2], cells
    return np.unique(key, axis=0, return_inverse=True)[1].reshape(-1), cells


def voxel_downsample(
    points: np.ndarray, voxel: float, normals: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Average points (and normals) that fall in the same cube of side ``voxel``.

    Args:
        points: (n, 3) float64, metres.
        voxel: cube side, metres, > 0.
        normals: (n, 3) unit vectors or None. Averaged normals are renormalised; a voxel where opposite
            normals cancel (a sheet thinner than a voxel) keeps the unnormalised mean's direction.

    Returns:
        (m, 3) centroids, (m, 3) unit normals or None, and (m,) points per voxel.
    """
    key = np.floor(points / voxel).astype(np.int64)
    key -= key.min(axis=0)
    dims = key.max(axis=0) + 1
    linear, cells = _linear(key, dims)
    if cells <= DENSE_LIMIT:
        # Counting into the full voxel grid is O(n); np.unique would sort.
        dense = np.bincount(linear, minlength=int(cells))
        occupied = np.flatnonzero(dense)
        slot = np.zeros(len(dense), dtype=np.int64)
        slot[occupied] = np.arange(len(occupied))
        inverse, counts = slot[linear], dense[occupied]
    else:
        _, inverse, counts = np.unique(linear, return_inverse=True, return_counts=True)

    def mean(values: np.ndarray) -> np.ndarray:
        return np.stack([np.bincount(inverse, weights=values[:, i]) for i in range(3)], axis=1)

    centroids = mean(points) / counts[:, None]
    if normals is None:
        return centroids, None, counts
    summed = mean(normals)
    length = np.linalg.norm(summed, axis=1, keepdims=True)
    return centroids, summed / np.maximum(length, np.finfo(float).tiny), counts


def voxel_subsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """Indices of one point of ``points`` in each occupied cube of side ``voxel``, ascending.

    Unlike :func:`voxel_downsample` the kept points are measured ones, not centroids: the centroid of a
    patch of a curved surface lies inside it by about ``voxel**2 / (12 R)`` at radius ``R``, which
    shrank a 2 cm sphere by ~0.25 % at 2 mm voxels. Which point of a voxel is kept is arbitrary but
    deterministic for a given input. The voxels lie along the points' axes (:func:`thin_to_budget` turns
    them off an object's box frame).

    Args:
        points: (n, 3) float64, metres.
        voxel: cube side, metres, > 0.

    Returns:
        (m,) int64 indices into ``points``, m = occupied voxels.
    """
    low, high = column_bounds(points)
    # Measured from the lowest point the coordinates are >= 0, so truncation is the floor.
    key = ((points - low) * (1.0 / voxel)).astype(np.int64)
    dims = ((high - low) * (1.0 / voxel)).astype(np.int64) + 1
    linear, cells = _linear(key, dims)
    if cells <= DENSE_LIMIT:
        # Scatter every point's index into its voxel and read back which survived: one per voxel. Only
        # the written slots are read, so the grid is left unset (its untouched pages never cost a thing).
        chosen = np.empty(int(cells), dtype=np.int64)
        index = np.arange(len(points))
        chosen[linear] = index
        return np.flatnonzero(chosen[linear] == index)
    return np.sort(np.unique(linear, return_index=True)[1])


def thin_to_budget(points: np.ndarray, spacing: float, noise: float, budget: int, *, seed: int = 0) -> np.ndarray:
    """Ascending indices of about ``budget`` of ``points`` ((n, 3) metres, ``spacing`` and ``noise`` metres
    their spacing and sigma), all of them when there are no more.

    One measured point per voxel of the budget's spacing keeps about ``budget`` points, evenly (centroids would
    sit inside curved surfaces; see :func:`voxel_subsample`). Where the noisy shell is thicker than half a
    voxel, one point per voxel would keep the sparse tails as often as the dense middle, widening the noise
    and, on a convex surface (more voxels outside than in), moving it outward (a 15 mm sphere at sigma 0.5 mm:
    +1.0 % against +0.1 % unthinned): there a random share (seeded by ``seed``) keeps the noise as it was.
    Thinner noise is thinned on voxels turned off the points' axes (:data:`LATTICE_TURN`).
    """
    if len(points) <= budget:
        return np.arange(len(points))
    voxel = spacing * np.sqrt(tol.VOXELS_PER_AREA * len(points) / budget)
    if noise > voxel / 2:
        return np.sort(np.random.default_rng(seed).choice(len(points), budget, replace=False))
    return voxel_subsample(points @ LATTICE_TURN.T, voxel)
