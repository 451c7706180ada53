"""Watertight reconstruction from oriented points: implicit moving least squares, then marching cubes.

Near the surface (the occupancy shell), the signed distance of a node is the weighted mean of its
nearest points' plane distances ``n_i . (x - p_i)`` (Kolluri's IMLS). Far from it, the sign comes from
the flood fill and the value is clamped. Marching cubes over that field gives a closed, consistently
oriented surface by construction; tiny spurious pieces are dropped.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from estimation.errors import ReconstructionError
from estimation.grid import Grid, Occupancy
from estimation.inertia import signed_volumes

#: Gaussian width of the IMLS weights, in cells. Small keeps edges sharp (the nearest face dominates);
#: large averages noise. One cell is both: the downsampled spacing is half a cell.
KERNEL_CELLS = 1.0

#: Far-field magnitude of the distance field, cells. Anything over one cell lets marching cubes place
#: the surface only inside the band.
CLAMP_CELLS = 2.0

#: Nearest points averaged at shell nodes that no point's scatter reached.
FALLBACK_NEIGHBOURS = 8

#: How far (cells) node values are kept from the zero level.
NUDGE_CELLS = 1e-3

#: Closed pieces smaller than this fraction of the largest are noise, not object.
MIN_PIECE_FRACTION = 1e-3


def signed_distance(
    points: np.ndarray, normals: np.ndarray, grid: Grid, occ: Occupancy, tree: cKDTree
) -> np.ndarray:
    """Signed distance (metres, positive outside) on every grid node, float32 of ``grid.shape``.

    Each point adds its Gaussian-weighted plane distance to the 27 nodes around it (a scatter with
    ``bincount``, several times faster than a neighbour query per node). Shell nodes farther than a
    cell from every point (the shell is wider where it had to close holes) take the same average over
    their nearest points instead.

    Args:
        points: (n, 3) metres; normals: (n, 3) unit, outward; tree: KD-tree over ``points``.
    """
    clamp = CLAMP_CELLS * grid.cell
    field = np.where(occ.outside, clamp, -clamp).astype(np.float32)
    h = KERNEL_CELLS * grid.cell
    size = int(np.prod(grid.shape))
    # For node offset o from a point's nearest node, d = r + cell * o with r = node - point, so the
    # (points x 27) distances and plane values are two small matrix products, then one bincount.
    base = grid.index_of(points)
    r = grid.position(base) - points
    offsets = _NEIGHBOUR_OFFSETS * grid.cell
    dist2 = (r * r).sum(axis=1)[:, None] + 2 * (r @ offsets.T) + (offsets * offsets).sum(axis=1)[None]
    w = np.exp(-dist2 / h**2).ravel()
    plane = ((normals * r).sum(axis=1)[:, None] + normals @ offsets.T).ravel()
    strides = np.array([grid.shape[1] * grid.shape[2], grid.shape[2], 1])
    linear = (base @ strides)[:, None] + (_NEIGHBOUR_OFFSETS @ strides)[None]
    weight_sum = np.bincount(linear.ravel(), weights=w, minlength=size)
    value_sum = np.bincount(linear.ravel(), weights=w * plane, minlength=size)
    shell = occ.shell.ravel()
    band = shell & (weight_sum > 0)
    flat = field.ravel()
    flat[band] = np.clip(value_sum[band] / weight_sum[band], -clamp, clamp)
    uncovered = np.flatnonzero(shell & (weight_sum == 0))
    if len(uncovered):
        x = grid.position(np.stack(np.unravel_index(uncovered, grid.shape), axis=1))
        k = min(FALLBACK_NEIGHBOURS, len(points))
        dist, nbr = tree.query(x, k=k, workers=-1)
        dist, nbr = dist.reshape(len(x), k), nbr.reshape(len(x), k)
        # Weights relative to the nearest point: the same kernel, without underflow far from the data.
        w = np.exp(-(dist**2 - dist[:, :1] ** 2) / h**2)
        plane = np.einsum("nkj,nkj->nk", normals[nbr], x[:, None, :] - points[nbr])
        flat[uncovered] = np.clip((w * plane).sum(axis=1) / w.sum(axis=1), -clamp, clamp)
    # The border is outside by construction; pinning it keeps every level set closed.
    for axis in range(3):
        field.swapaxes(0, axis)[[0, -1]] = clamp
    return field


_NEIGHBOUR_OFFSETS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)])


def surface_from_field(field: np.ndarray, grid: Grid) -> trimesh.Trimesh:
    """Zero level set of ``field`` as a watertight mesh with outward faces, metres.

    Raises:
        ReconstructionError: the field has no zero crossing or no closed piece of any size.
    """
    from skimage.measure import marching_cubes

    if field.min() >= 0 or field.max() <= 0:
        raise ReconstructionError("the reconstructed field has no surface (no inside found)")
    # A node at ~0 makes marching cubes put several vertices on it; merged, they become degenerate
    # slivers (and deleting those opens the surface). Moving such nodes off the level by a
    # thousandth of a cell changes the surface by no more than that.
    nudge = NUDGE_CELLS * grid.cell
    field = np.where(np.abs(field) < nudge, np.float32(nudge), field)
    verts, faces, _, _ = marching_cubes(field, level=0.0, spacing=(grid.cell,) * 3)
    mesh = trimesh.Trimesh(verts + grid.origin, faces, process=True)
    if mesh.body_count > 1:
        pieces = mesh.split(only_watertight=False)
        volumes = np.array([signed_volumes(p.triangles).sum() for p in pieces])
        # Inward-facing closed pieces would be cavities no sensor could see: noise, like tiny pieces.
        keep = [p for p, v in zip(pieces, volumes, strict=True) if v > MIN_PIECE_FRACTION * volumes.max()]
        mesh = keep[0] if len(keep) == 1 else trimesh.util.concatenate(keep)
    if signed_volumes(mesh.triangles).sum() <= 0:
        raise ReconstructionError("reconstruction produced no closed solid")
    if not mesh.is_watertight:
        raise ReconstructionError("reconstruction is not watertight")
    return mesh

