"""Convex hull of the points: a tight upper bound for convex objects, an overestimate for the rest."""

from __future__ import annotations

import numpy as np


def convex_hull(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (v, 3) and outward faces (f, 3) of the convex hull of ``points`` ((n, 3) metres)."""
    import trimesh

    hull = trimesh.convex.convex_hull(points, qhull_options="QbB Pp")
    return np.asarray(hull.vertices), np.asarray(hull.faces)
