"""Points apart from the object: outliers and small clusters well away from the rest of the cloud.

A scan holds a few points that are not on the object: a reflection, flying pixels a filter missed, a speck
of background left by a crop. Each one is a tiny island the reconstruction must close and the flood fill
must get around: 46 points scattered around a 10 cm ball of 20,000 put its volume 5.7 % high and called its
surface open, and small objects came out several times their size (``bench/strays.py``). The points are split
into islands by proximity (cells of ``STRAY_CELL_SPACINGS`` point spacings, neighbouring cells joined) and the
islands holding less than ``STRAY_SHARE`` of the points are dropped, if what is left is most of the cloud.
Several large islands stay: they may be one object seen in pieces, or several objects, which the caller is
told of.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product

import numpy as np

#: Islands are joined across gaps of this many point spacings (always; up to ~3.5 times it along a diagonal).
#: A scan's density varies a few times across an object (near and far sides, grazing angles); an occlusion
#: gap is a different matter, and its pieces are each large.
STRAY_CELL_SPACINGS = 4.0

#: An island with less than this share of the points is a stray: a part of the object so small would hold
#: no volume an estimate could resolve anyway.
STRAY_SHARE = 0.01

#: Points the islands are told apart at: a denser cloud is looked at with the cell of this many points.
ISLAND_POINTS = 100_000

#: Strays are dropped only while what stays holds at least this share of the points: a cloud that is mostly
#: islands (a sparse scan, uniform noise) is left as it came.
KEEP_SHARE = 0.9


@dataclass(frozen=True)
class Islands:
    """The cloud split into islands. ``keep``: (n,) bool, the points not in strays; ``strays``: points
    dropped; ``stray_islands``: how many islands they formed; ``parts``: the islands of at least
    ``STRAY_SHARE`` of the points (1 for one connected object; 0 for a cloud that is all small islands);
    ``part_shares``: each one's share of the points, largest first."""

    keep: np.ndarray
    strays: int
    stray_islands: int
    parts: int
    part_shares: tuple[float, ...]


def islands(points: np.ndarray, spacing: float) -> Islands:
    """Split ``points`` ((n, 3) metres, point ``spacing`` metres) into islands.

    The cell is ``STRAY_CELL_SPACINGS`` spacings of the cloud thinned to ``ISLAND_POINTS``: past that, a
    denser scan resolves nothing more that a stray could spoil (the reconstruction works on fewer points
    still, ``tolerances.POINT_BUDGET``), and a cell fixed by the data keeps the work linear in the points,
    with no sort (a million points: 46 ms, ``bench/strays.py``). Where that finds strays or several parts and the
    points lie along lines at least ``tolerances.LINE_GAP_CELLS`` spacings apart (``spacing.line_gap``), the
    cell is ``STRAY_CELL_SPACINGS`` times the lines' gap instead.
    """
    n = len(points)
    if n == 0 or not spacing > 0:
        return Islands(np.ones(n, dtype=bool), 0, 0, 1, (1.0,))
    cell = STRAY_CELL_SPACINGS * spacing * max(1.0, float(np.sqrt(n / ISLAND_POINTS)))
    found = _islands(points, cell)
    if found.strays or found.parts > 1:
        # Points along lines far apart (a laser line scanner's slices): the spacing is read along them, and where the
        # lines part wider than the cell (a ball's slices near its poles), whole lines fell apart as strays (an 8 cm ball
        # sliced every 2 mm lost its caps, 558 points). The gap between the lines is the spacing that counts there.
        from estimation.spacing import line_gap
        from estimation.tolerances import LINE_GAP_CELLS

        gap = line_gap(points)
        if gap >= LINE_GAP_CELLS * spacing and STRAY_CELL_SPACINGS * gap > cell:
            found = _islands(points, STRAY_CELL_SPACINGS * gap)
    return found


def _islands(points: np.ndarray, cell: float) -> Islands:
    """:func:`islands` with cells of ``cell`` metres."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from estimation.obb import column_bounds

    n = len(points)
    everything = Islands(np.ones(n, dtype=bool), 0, 0, 1, (1.0,))
    low, high = column_bounds(points)
    dims = np.floor((high - low) / cell).astype(np.int64) + 3  # a margin: every neighbour offset stays in range
    total = float(np.prod(dims.astype(np.float64)))
    if total >= 2.0**62:
        return everything  # far_points keeps clouds from this; no key would fit
    scaled = points - (low - cell)  # one cell of margin below
    scaled *= 1.0 / cell
    ijk = scaled.astype(np.int64)
    key = ijk[:, 0] * (dims[1] * dims[2])
    key += ijk[:, 1] * dims[2]
    key += ijk[:, 2]
    if total <= max(4 * n, 1 << 20):  # a dense count: linear, no sort
        counts = np.bincount(key, minlength=int(total))
        cells = np.flatnonzero(counts)
        count = counts[cells]
    else:
        cells, count = np.unique(key, return_counts=True)
    m = len(cells)
    rows, cols = [np.arange(m)], [np.arange(m)]
    for offset in product((-1, 0, 1), repeat=3):
        if offset <= (0, 0, 0):  # half the 26 neighbours: the graph is undirected
            continue
        step = (offset[0] * dims[1] + offset[1]) * dims[2] + offset[2]
        at = np.searchsorted(cells, cells + step)
        found = at < m
        found[found] = cells[at[found]] == cells[found] + step
        rows.append(np.flatnonzero(found))
        cols.append(at[found])
    r, c = np.concatenate(rows), np.concatenate(cols)
    count_islands, label = connected_components(coo_matrix((np.ones(len(r)), (r, c)), shape=(m, m)), directed=False)
    if count_islands == 1:
        return everything
    size = np.bincount(label, weights=count, minlength=count_islands)
    stray = size < STRAY_SHARE * n
    if size[~stray].sum() < KEEP_SHARE * n:
        stray[:] = False
    island = label[np.searchsorted(cells, key)]
    keep = ~stray[island]
    if not keep.all():
        keep, stray = _sparse_kin(points, keep, island, stray, cell)
    # Parts are the large islands; a small one given back (sparse kin) belongs to the part it is near.
    big = size >= STRAY_SHARE * n
    shares = tuple(float(s) / n for s in sorted(size[big], reverse=True))
    return Islands(keep, int(n - keep.sum()), int(stray.sum()), int(big.sum()), shares)


def _sparse_kin(points: np.ndarray, keep: np.ndarray, island: np.ndarray, stray: np.ndarray,
                cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Give back the candidate strays that are only as far from the rest as the rest is sparse there.

    The cell is set by the median spacing; where a scan is sparser (a face seen at a grazing angle, 4x the
    spacing of the face seen square on), points a few of its own spacings apart fell into islands of their
    own. A candidate island stays a stray if its gap to the nearest kept point is also more than
    ``STRAY_CELL_SPACINGS`` of that point's own spacing (from its ``k`` nearest kept neighbours, among at
    most ``ISLAND_POINTS`` of them, as the cell is).
    """
    from scipy.spatial import cKDTree

    from estimation.spacing import SPACING_NEIGHBOURS

    kept = points[keep]
    kept = kept[:: max(1, -(-len(kept) // ISLAND_POINTS))]
    k = min(SPACING_NEIGHBOURS, len(kept) - 1)
    if k < 1:
        return keep, stray
    tree = cKDTree(kept)
    candidates = np.flatnonzero(~keep)
    gap, nearest = tree.query(points[candidates], k=1)
    local = np.sqrt(np.pi / k) * tree.query(kept[nearest], k=k + 1)[0][:, -1]
    near = gap <= STRAY_CELL_SPACINGS * np.maximum(local, cell / STRAY_CELL_SPACINGS)
    rescued = np.unique(island[candidates[near]])
    stray = stray.copy()
    stray[rescued] = False
    return ~stray[island], stray
