"""The k nearest neighbours, with ties broken by index so that a rigid motion keeps the same ones.

``cKDTree.query`` orders points at equal distances as its tree happens to visit them. On a lattice, as
a quantised depth camera's pixels make, many points share a distance, and a rigid motion (which changes
distances by about 1e-16) can swap which of them is the k-th: the normals fitted to those neighbours,
and the volume, then move with the site's coordinates (a Kinect scan of a bracket: 0.45 % for 7 of its
2,716 normals).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

#: Neighbours fetched beyond k, to order those tied with the k-th: a square lattice puts up to eight
#: points at one distance.
TIE_EXTRA = 8

#: Distances within this relative difference are one distance (a rigid motion moves them by ~1e-16).
TIE_RELATIVE = 1e-9


#: Queries at least this many are split across every core; fewer run in the caller's thread (scipy starts
#: its threads at every call: a few hundred queries, as ICP asks for a target's normals, waited on them
#: longer than they searched).
PARALLEL_QUERIES = 2000


def nearest(tree: cKDTree, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Distances (q, k) and indices (q, k) of each query's ``k`` nearest points in ``tree``, nearest
    first; points at one distance (``TIE_RELATIVE``) in ascending index order.

    Args:
        tree: the points searched, metres.
        queries: (q, 3) float64 metres.
        k: neighbours wanted, at most ``tree.n``.
    """
    fetch = min(k + TIE_EXTRA, tree.n)
    dist, index = tree.query(queries, k=fetch, workers=-1 if len(queries) >= PARALLEL_QUERIES else 1)
    dist = dist.reshape(len(queries), fetch)
    index = index.reshape(len(queries), fetch)
    step = np.diff(dist, axis=1) > TIE_RELATIVE * dist[:, 1:]
    # A row with no tie among its first k + 1 distances is in order already; only the others are sorted
    # (off a lattice that is nearly every row, and sorting them all cost more than the search at k = 96).
    tied = np.flatnonzero(~step[:, :k].all(axis=1))
    near_dist, near_index = dist[:, :k].copy(), index[:, :k].copy()
    if len(tied):
        group = np.concatenate([np.zeros((len(tied), 1), dtype=np.int64), np.cumsum(step[tied], axis=1)], axis=1)
        order = np.lexsort((index[tied], group))[:, :k]
        near_dist[tied] = np.take_along_axis(dist[tied], order, axis=1)
        near_index[tied] = np.take_along_axis(index[tied], order, axis=1)
    return near_dist, near_index
