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
    leave none of them more than ``tolerance`` metres outside it, and at most ``most`` of them (then the
    farthest is wherever those leave it).

    Greedy, farthest first: starting from the extreme points along the hull's principal axes, each round adds,
    for every face some hull vertex lies beyond by more than ``tolerance``, the vertex farthest beyond it. Qhull's
    own cap ('TA n', MuJoCo's ``maxhullvert``) stops after n vertices in the order it meets them, not the farthest:
    at 64, a 4.7 cm ball's hull lies over 3 mm inside it (``tests/test_primitives.py``), and a 9 cm blob rested
    2.15 mm into a table (``bench/hull_sink.py``).
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
            planes = ConvexHull(vertices[chosen]).equations
        except QhullError:  # the seeds lie on a plane (a flat hull): the whole hull, as it is
            return vertices, faces
        beyond = np.empty(len(vertices))
        face = np.empty(len(vertices), dtype=np.int64)
        for start in range(0, len(vertices), 4096):  # (rows x faces) at a time, not (n x faces)
            d = vertices[start:start + 4096] @ planes[:, :3].T + planes[:, 3]
            face[start:start + 4096], beyond[start:start + 4096] = d.argmax(axis=1), d.max(axis=1)
        out = np.flatnonzero(beyond > tolerance)
        if not len(out) or len(chosen) >= most:
            return convex_hull(vertices[chosen])
        by_face = out[np.lexsort((-beyond[out], face[out]))]  # each face's farthest first
        farthest = by_face[np.r_[True, face[by_face][1:] != face[by_face][:-1]]]
        farthest = farthest[np.argsort(-beyond[farthest])][:most - len(chosen)]
        chosen = np.union1d(chosen, farthest)
