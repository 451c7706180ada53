"""Coverage: how much of a closed surface some measured point saw, and faced.

A face of the reconstruction counts as seen when a measured point lies near it, and, where the points'
normals are known, faces its way. The second test tells apart the two faces of a slab the reconstruction
closed around one sheet of points: the points face only one of them.
"""

from __future__ import annotations

import numpy as np

from estimation.contracts import as_points
from estimation.inertia import triangle_areas

#: With the observed points' normals, a face is observed only by a point within ``radius`` whose normal is within
#: 60 degrees of the face's: a noisy normal on a small part is off by tens of degrees, while the faces a point
#: cannot have seen (the base under a side wall's lowest points) turn 90 degrees from it.
FACING_COS = 0.5

#: Observed points compared with each face (their normals, their depth): the nearest this many within ``radius``.
FACING_NEIGHBOURS = 8


def coverage(vertices: np.ndarray, faces: np.ndarray, observed: np.ndarray, *, radius: float,
             normals: np.ndarray | None = None, depth: float | None = None) -> tuple[float, float]:
    """How much of a closed surface some sensor saw: (observed area, total area), m^2.

    A face counts as observed when its centroid lies within ``radius`` of an observed point (with ``normals``:
    of one facing its way, ``FACING_COS``; with ``depth``: of one no further than that from the face's plane);
    the rest was closed by completion or by the reconstruction's hole closing. Without normals, a small
    object's base counted as seen from its side walls' lowest points: a 14 mm nut on a table reported 1.00.

    Args:
        vertices: (v, 3) float64 metres; faces: (f, 3) int64, the closed surface (outward winding).
        observed: (n, 3) float64 metres, same frame: the points a sensor returned (completed ones excluded).
        radius: metres, about two reconstruction cells (a face between two measured points is observed).
        normals: (n, 3) unit outward normals of ``observed`` (NaN rows: unknown, facing any way), or None.
        depth: metres, or None: how far off a face's plane a point may lie and still measure it.
    """
    from scipy.spatial import cKDTree

    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64)]
    area = triangle_areas(tri)
    obs = as_points(observed, "observed")
    if len(obs) == 0 or len(tri) == 0:
        return 0.0, float(area.sum())
    centres = tri.mean(axis=1)
    k = 1 if normals is None and depth is None else min(FACING_NEIGHBOURS, len(obs))
    dist, index = cKDTree(obs).query(centres, k=k, distance_upper_bound=radius, workers=-1)
    if k == 1:
        return float(area[np.isfinite(dist)].sum()), float(area.sum())
    dist, index = dist.reshape(len(tri), k), index.reshape(len(tri), k)
    seen = np.isfinite(dist)
    index = np.where(seen, index, 0)
    facing = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    facing /= np.maximum(np.linalg.norm(facing, axis=1, keepdims=True), 1e-300)
    if normals is not None:
        agree = np.einsum("fkc,fc->fk", np.asarray(normals, dtype=np.float64)[index], facing)
        seen &= (agree >= FACING_COS) | np.isnan(agree)
    if depth is not None:
        seen &= np.abs(np.einsum("fkc,fc->fk", obs[index] - centres[:, None], facing)) <= depth
    seen = seen.any(axis=1)
    return float(area[seen].sum()), float(area.sum())
