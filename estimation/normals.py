"""Normals: estimate them from the points, and orient them out of the object.

The paper's surface failed because normals were estimated without a viewpoint and pointed the wrong way.
We orient each normal by looking, along it, at the flood-filled outside (``grid.occupancy``): the side
where the outside is nearer is out. An optional viewpoint is used instead where given (single-view scans).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from estimation import tolerances as tol
from estimation.grid import Grid, Occupancy

#: How far (cells) beyond the shell's closing radius we look for the outside on either side of a point.
PROBE_CELLS = 1.0

#: Blur (cells) of the outside indicator: turns the 0/1 mask into a ramp we can compare on both sides.
OUTSIDE_BLUR_CELLS = 1.5

#: Below this difference of blurred outside-ness the probe cannot tell (thin walls with outside on both
#: sides); such normals take their confident neighbours' side.
CONFIDENT_DIFFERENCE = 0.05


def estimate_normals(points: np.ndarray, k: int = tol.NORMAL_NEIGHBOURS) -> np.ndarray:
    """Unoriented unit normals (n, 3): smallest principal direction of each point's ``k`` neighbours.

    Args:
        points: (n, 3) float64, metres.
        k: neighbours per point (including itself).
    """
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=min(k, len(points))))
    return np.asarray(pcd.normals).copy()


def orient_outward(
    points: np.ndarray, normals: np.ndarray, grid: Grid, occ: Occupancy, tree: cKDTree
) -> np.ndarray:
    """Flip ``normals`` ((n, 3), unit) so that each points out of the solid bounded by ``points``."""
    outside = ndimage.gaussian_filter(occ.outside.astype(np.float32), OUTSIDE_BLUR_CELLS)
    # The shell reaches ``closing`` cells from the points; the outside starts just beyond.
    step = (occ.closing + PROBE_CELLS) * grid.cell * normals
    ahead = ndimage.map_coordinates(outside, grid.fractional(points + step), order=1, mode="nearest")
    behind = ndimage.map_coordinates(outside, grid.fractional(points - step), order=1, mode="nearest")
    difference = ahead - behind
    sign = np.where(difference < 0, -1.0, 1.0)
    unsure = np.abs(difference) < CONFIDENT_DIFFERENCE
    if unsure.any() and (~unsure).any():
        # Take the side that agrees with the confident neighbours' (already flipped) normals.
        oriented = normals * sign[:, None]
        _, nbr = tree.query(points[unsure], k=min(tol.NORMAL_NEIGHBOURS, len(points)), workers=-1)
        weight = (~unsure[nbr]).astype(float)
        votes = np.einsum("nk,nkj,nj->n", weight, oriented[nbr], normals[unsure])
        sign[unsure] = np.where(votes < 0, -1.0, 1.0)
    return normals * sign[:, None]


def orient_to_viewpoint(points: np.ndarray, normals: np.ndarray, viewpoint: np.ndarray) -> np.ndarray:
    """Flip normals to face ``viewpoint`` ((3,) metres, same frame): a sensor sees the outside."""
    facing = np.einsum("ij,ij->i", normals, np.asarray(viewpoint) - points)
    return np.where(facing[:, None] < 0, -normals, normals)
