"""Convex hull of the points: a tight upper bound for convex objects, an overestimate for the rest."""

from __future__ import annotations

import numpy as np


def convex_hull(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (v, 3) and outward faces (f, 3) of the convex hull of ``points`` ((n, 3) metres)."""
    import trimesh

    # trimesh merges vertices closer than an absolute 1e-8: on a 10 um object that merges real hull
    # vertices (-15 % volume at 5 um radius). The hull of the points moved to the origin and scaled to
    # unit size is the same hull, moved back.
    center = (points.max(axis=0) + points.min(axis=0)) / 2
    size = float(np.ptp(points, axis=0).max()) or 1.0
    hull = trimesh.convex.convex_hull((points - center) / size, qhull_options="QbB Pp")
    return np.asarray(hull.vertices) * size + center, np.asarray(hull.faces)


def simplified_hull(points: np.ndarray, tolerance: float, most: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (v, 3) and outward faces of the hull of as few of ``points``' hull vertices ((n, 3) metres) as
    leave none of them farther than ``tolerance`` metres from it, and at most ``most`` of them (past the 14 seeds;
    then some lie farther).

    Greedy, farthest first: starting from the extreme points along the hull's principal axes, each round adds,
    for every face some hull vertex lies beyond by more than ``tolerance``, the vertex farthest beyond it. Qhull's
    own cap ('TA n', MuJoCo's ``maxhullvert``) stops after n vertices in the order it meets them, not the farthest:
    at 64, a 4.7 cm ball's hull lies over 3 mm inside it (``tests/test_primitives.py``), and a 9 cm blob rested
    2.15 mm into a table (``bench/hull_sink.py``). Once no vertex lies beyond a face's plane by more than
    ``tolerance``, the distance to the hull itself is checked (past an edge or a corner it is larger: a 10 cm disc
    0.5 mm thick, its rim beyond the nearly flat faces of a hull of 8 vertices by 0.2 mm, lay 14.6 mm outside it,
    a review's probe), and the vertices still farther are added, the farthest first.
    """
    from scipy.spatial import ConvexHull, QhullError

    vertices, faces = convex_hull(np.asarray(points, dtype=np.float64))
    if len(vertices) <= 4:
        return vertices, faces
    # Seeds: the two extremes along each principal axis and each diagonal of them, a hull with some volume.
    centred = vertices - vertices.mean(axis=0)
    axes = np.linalg.svd(centred, full_matrices=False)[2]
    directions = np.concatenate([axes, axes[[0, 0, 1]] + axes[[1, 2, 2]], axes.sum(axis=0, keepdims=True)])
    along = centred @ directions.T
    chosen = np.unique(np.concatenate([along.argmax(axis=0), along.argmin(axis=0)]))
    while True:
        try:
            hull = ConvexHull(vertices[chosen])
        except QhullError:  # the seeds lie on a plane (a flat hull): the whole hull, as it is
            return vertices, faces
        if len(chosen) >= most:
            return convex_hull(vertices[chosen])
        beyond, face = _beyond_faces(vertices, hull.equations)
        far = beyond > tolerance
        if not far.any():
            beyond = _distance_outside(vertices, vertices[chosen][hull.simplices], hull.equations)
            far = beyond > tolerance
            if not far.any():
                return convex_hull(vertices[chosen])
        out = np.flatnonzero(far)
        by_face = out[np.lexsort((-beyond[out], face[out]))]  # each face's farthest first
        farthest = by_face[np.r_[True, face[by_face][1:] != face[by_face][:-1]]]
        farthest = farthest[np.argsort(-beyond[farthest])][:most - len(chosen)]
        chosen = np.union1d(chosen, farthest)


#: Rows of (points x faces) taken at a time by the hull's distance tests.
_BLOCK = 4096


def _beyond_faces(points: np.ndarray, planes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n,) how far each of ``points`` (metres) lies beyond the farthest of the hull's face ``planes`` ((f, 4),
    unit outward normals and offsets), and (n,) which face: a lower bound of its distance to the hull."""
    beyond = np.empty(len(points))
    face = np.empty(len(points), dtype=np.int64)
    for start in range(0, len(points), _BLOCK):
        d = points[start:start + _BLOCK] @ planes[:, :3].T + planes[:, 3]
        face[start:start + _BLOCK], beyond[start:start + _BLOCK] = d.argmax(axis=1), d.max(axis=1)
    return beyond, face


def _distance_outside(points: np.ndarray, triangles: np.ndarray, planes: np.ndarray) -> np.ndarray:
    """(n,) each of ``points``' distance (metres) to the convex hull whose faces are ``triangles`` ((f, 3, 3)) on
    ``planes``; 0 inside. Outside, the nearest point of a convex solid lies on a face the point sees (beyond its
    plane), so only those faces are measured."""
    from trimesh.triangles import closest_point

    distance = np.zeros(len(points))
    for start in range(0, len(points), _BLOCK):
        d = points[start:start + _BLOCK] @ planes[:, :3].T + planes[:, 3]
        rows, seen = np.nonzero(d > 0)
        if not len(rows):
            continue
        rows_at = rows + start
        gap = np.linalg.norm(closest_point(triangles[seen], points[rows_at]) - points[rows_at], axis=1)
        nearest = np.full(len(d), np.inf)
        np.minimum.at(nearest, rows, gap)
        measured = np.isfinite(nearest)
        distance[start:start + _BLOCK][measured] = nearest[measured]
    return distance
