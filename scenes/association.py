"""Which segment of a camera scan is which object: pure functions of segments and predicted positions.

A scan's segments (:class:`scenes.cameras.Segment`: points, centroid, box) carry no names. An object is the
segment its model's points lie on, placed where it is predicted, or for an object not observed yet the segment
of the scan point nearest where it is labelled (:func:`gate`); failing that, the nearest segment no other object is
predicted in, within how far it could have moved unseen (:func:`search`, :func:`reach`). Objects predicted in
one segment that stand clear of its footprint are not in it (:func:`outsiders`). :class:`scenes.sensing.CameraSensor`
keeps the state (predictions, claims, counts, logs); nothing here does.

Positions are world-frame metres.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from scenes.cameras import Segment

#: A segment further than this from an object's last position is not that object, metres: more than an
#: object at rest moves between scans, less than the gaps in the clutter scene.
ASSOCIATION_RADIUS = 0.08

#: Metres outside a shared segment's footprint an object's centre may be and still share it when another
#: object's centre is over it (:func:`outsiders`): a few clustering cells of a 1 mm camera at a metre.
SHARED_MARGIN = 0.02

#: The fastest an object is expected to move, m/s: what a teleoperated arm pushes or carries across a table.
#: An object lost for t seconds is looked for within ``ASSOCIATION_RADIUS + MAX_SPEED t`` of where it was.
MAX_SPEED = 1.0

#: Share of an object's model points, placed where it is predicted, that one segment must hold (each point
#: counted for the segment of its nearest scan point, within ``ASSOCIATION_RADIUS``) to be that object's by
#: overlap (:func:`gate`): the majority of what a partial view would still show of it.
MIN_OVERLAP = 0.5


def reach(since: float) -> float:
    """Metres an object may have moved in ``since`` seconds unseen."""
    return ASSOCIATION_RADIUS + MAX_SPEED * max(since, 0.0)


def _grown_box_holds(seg: Segment, here: np.ndarray) -> bool:
    low, high = seg.bounds
    return bool(((here >= low - ASSOCIATION_RADIUS) & (here <= high + ASSOCIATION_RADIUS)).all())


def gate(segments: Sequence[Segment], predicted: Mapping[str, np.ndarray],
         placed: Mapping[str, np.ndarray] | None = None) -> dict[str, int]:
    """Each object's segment at its ``predicted`` position.

    An object with ``placed`` points (its model, (n, 3), moved to where it is predicted) is in the segment
    that holds at least ``MIN_OVERLAP`` of them (:func:`overlap`), even one it shares with others. Otherwise
    (not observed yet, or too little of it lies on any segment) it is in the segment of the scan point
    nearest its position, if that segment's box grown by ``ASSOCIATION_RADIUS`` holds the position
    (:func:`nearest`). Neither is the segment with the nearest centroid: a segment of several large objects
    has its centroid between them, nearer other segments than some of its own (the paper's table: a mug
    1 m from the centroid of the segment it was in, 0.7 m from another's, was looked for in a 54-point speck
    and lost; a staircase sharing a segment with a bridge was never found). Objects a segment's
    :func:`outsiders` leave out have none."""
    if not segments:
        return {}
    index = _indexed(segments)
    gates = overlap(segments, {i: p for i, p in (placed or {}).items() if i in predicted}, index=index)
    gates |= nearest(segments, {i: p for i, p in predicted.items() if i not in gates}, index=index)
    by_segment: dict[int, list[str]] = {}
    for object_id, k in gates.items():
        by_segment.setdefault(k, []).append(object_id)
    for k, owners in by_segment.items():
        for object_id in outsiders(segments[k], {i: predicted[i] for i in owners}):
            del gates[object_id]
    return gates


def _indexed(segments: Sequence[Segment]):  # type: ignore[no-untyped-def]
    """A k-d tree of every segment's points, and each point's segment index."""
    from scipy.spatial import cKDTree

    which = np.concatenate([np.full(len(seg.points), k) for k, seg in enumerate(segments)])
    return cKDTree(np.concatenate([seg.points for seg in segments])), which


def overlap(segments: Sequence[Segment], placed: Mapping[str, np.ndarray], *, index=None) -> dict[str, int]:  # type: ignore[no-untyped-def]
    """Each object's segment by overlap: the one holding at least ``MIN_OVERLAP`` of its ``placed`` points
    ((n, 3) each), every point counted for the segment of the scan point nearest it, if that is within
    ``ASSOCIATION_RADIUS``. Objects with no such segment are left out. ``index``: :func:`_indexed`'s, if
    built."""
    placed = {i: p for i, p in placed.items() if len(p)}
    if not segments or not placed:
        return {}
    tree, which = index or _indexed(segments)
    out: dict[str, int] = {}
    for object_id, points in placed.items():
        distance, near = tree.query(points, distance_upper_bound=ASSOCIATION_RADIUS)
        held = np.bincount(which[near[np.isfinite(distance)]], minlength=len(segments))
        k = int(np.argmax(held))
        if held[k] >= MIN_OVERLAP * len(points):
            out[object_id] = k
    return out


def nearest(segments: Sequence[Segment], predicted: Mapping[str, np.ndarray], *, index=None) -> dict[str, int]:  # type: ignore[no-untyped-def]
    """Each object's segment by the scan point nearest its ``predicted`` position, if that segment's box grown
    by ``ASSOCIATION_RADIUS`` holds the position; objects with none are left out. ``index``: as in
    :func:`overlap`."""
    if not segments or not predicted:
        return {}
    tree, which = index or _indexed(segments)
    out: dict[str, int] = {}
    for object_id, here in predicted.items():
        k = int(which[tree.query(here)[1]])
        if _grown_box_holds(segments[k], here):
            out[object_id] = k
    return out


def sharing(segments: Sequence[Segment], predicted: Mapping[str, np.ndarray]) -> dict[int, list[str]]:
    """The objects in each segment by :func:`nearest` (segment index -> object ids)."""
    out: dict[int, list[str]] = {}
    for object_id, k in nearest(segments, predicted).items():
        out.setdefault(k, []).append(object_id)
    return out


def search(segments: Sequence[Segment], last: np.ndarray, within: float, *, taken: set[int]) -> int | None:
    """The segment nearest ``last`` (by the distance to its box: a box, not the centroid, for the reason in
    :func:`gate`) that is not ``taken`` and no further than ``within`` metres; None if there is none."""
    best, best_d = None, np.inf
    for k, seg in enumerate(segments):
        if k in taken:
            continue
        low, high = seg.bounds
        d = float(np.linalg.norm(np.maximum(0.0, np.maximum(low - last, last - high))))
        if d <= within and d < best_d:
            best, best_d = k, d
    return best


def outsiders(seg: Segment, predicted: Mapping[str, np.ndarray]) -> set[str]:
    """Of the objects ``predicted`` in one segment, those that are not in it: when some stand over the segment's
    footprint (the world's x-y box of its points), the others further than ``SHARED_MARGIN`` outside it. A
    centre of mass stands over its object's footprint, and a segment seen from above covers the footprints of
    the objects in it; the box ``ASSOCIATION_RADIUS`` around a segment is wide for objects whose visible part is
    small (one mostly hidden behind another), and a 3 mm disc flat on the table, all of it below the
    clustering cut, took a ball's segment 9 cm away for its own.
    """
    if len(predicted) < 2:
        return set()
    low, high = seg.bounds[0][:2], seg.bounds[1][:2]
    gap = {i: float(np.linalg.norm(np.maximum(0.0, np.maximum(low - p[:2], p[:2] - high)))) for i, p in predicted.items()}
    if min(gap.values()) > 0:
        return set()  # none over it: nothing tells them apart here
    return {i for i, g in gap.items() if g > SHARED_MARGIN}
