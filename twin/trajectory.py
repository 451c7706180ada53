"""What the operator does: end-effector targets as functions of twin time (world frame, metres)."""

from __future__ import annotations

import csv
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from estimation.errors import TwinError
from sync.messages import MAX_COORDINATE

Trajectory = Callable[[float], np.ndarray]

#: The header row a trajectory CSV may start with.
TRAJECTORY_HEADER = ("t", "x", "y", "z")


class TrajectoryError(TwinError, ValueError):
    """A trajectory file that cannot be read or does not describe a trajectory."""


def push_trajectory(start: np.ndarray, end: np.ndarray, duration: float, *, start_time: float = 0.0) -> Trajectory:
    """A straight push from ``start`` to ``end`` over ``duration`` seconds from ``start_time`` (twin time,
    seconds), holding ``start`` before it and ``end`` after."""
    start, end = np.asarray(start, float), np.asarray(end, float)

    def at(t: float) -> np.ndarray:
        s = min(1.0, max(0.0, (t - start_time) / duration))
        return start + s * (end - start)

    return at


def held_trajectory(times: np.ndarray, points: np.ndarray, *, start_time: float = 0.0,
                    ) -> Callable[[float], np.ndarray | None]:
    """Targets taken at ``times`` (twin seconds, ascending), each held until the next (a zero-order hold, as a
    device's commands are), shifted so the first is taken at ``start_time``; None before it.

    Half a millisecond of slack: step times are float sums, so a target recorded at t is found at t.
    """
    times = np.asarray(times, float) - (float(times[0]) - start_time if len(times) else 0.0)
    points = np.asarray(points, float)
    slack = 5e-4

    def at(t: float) -> np.ndarray | None:
        i = int(np.searchsorted(times, t + slack, side="right")) - 1
        return None if i < 0 else points[i]

    return at


def load_trajectory(path: str | Path) -> Trajectory:
    """An end-effector trajectory from a CSV file.

    Format: one row per waypoint, ``t,x,y,z``: time in seconds (strictly increasing) and the target
    position in metres, world frame. An optional first row ``t,x,y,z`` names the columns; blank lines and
    lines starting with ``#`` are skipped. Between waypoints the target moves linearly; before the first
    it is the first, after the last it stays at the last. Example::

        t,x,y,z
        0.0,0.30,0.00,0.12
        2.0,0.45,0.00,0.12

    Args:
        path: the CSV file.

    Returns:
        ``trajectory(t) -> (3,) float64``, metres, world frame.

    Raises:
        TrajectoryError: the file is not a regular file or cannot be read, a row has other than four
            columns or a value that is not a finite number, a position beyond
            :data:`sync.messages.MAX_COORDINATE` (what the wire carries), there are no waypoints, or the
            times do not increase.
    """
    path = Path(path)
    if path.exists() and not path.is_file() and not path.is_dir():  # a FIFO or device: reading blocks forever
        raise TrajectoryError(f"{path}: not a regular file")
    try:
        # utf-8-sig: a spreadsheet's CSV starts with a byte-order mark, which made the header "not a number".
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise TrajectoryError(f"{path}: cannot read trajectory ({exc.__class__.__name__}: {exc})") from None
    rows: list[tuple[float, ...]] = []
    reader = csv.reader(text.splitlines())
    try:
        numbered = list(enumerate(reader, start=1))
    except csv.Error as exc:  # a stray quote makes one field of the rest of the file, past csv's field limit
        raise TrajectoryError(f"{path}:{reader.line_num}: not CSV ({exc})") from None
    for number, row in numbered:
        cells = [c.strip() for c in row]
        if not cells or cells == [""] or cells[0].startswith("#"):
            continue
        if not rows and tuple(c.lower() for c in cells) == TRAJECTORY_HEADER:
            continue
        if len(cells) != 4:
            raise TrajectoryError(f"{path}:{number}: expected 4 columns t,x,y,z, got {len(cells)}")
        try:
            values = tuple(float(c) for c in cells)
        except ValueError:
            raise TrajectoryError(f"{path}:{number}: not a number in {','.join(cells)!r}") from None
        if not all(math.isfinite(v) for v in values):
            raise TrajectoryError(f"{path}:{number}: non-finite value in {','.join(cells)!r}")
        if any(abs(v) > MAX_COORDINATE for v in values[1:]):
            raise TrajectoryError(f"{path}:{number}: a position beyond {MAX_COORDINATE:g} m in {','.join(cells)!r}")
        if rows and values[0] <= rows[-1][0]:
            raise TrajectoryError(f"{path}:{number}: t = {values[0]:g} s does not increase "
                                  f"(previous {rows[-1][0]:g} s)")
        rows.append(values)
    if not rows:
        raise TrajectoryError(f"{path}: no waypoints (expected rows t,x,y,z)")
    table = np.array(rows, dtype=np.float64)
    times, points = table[:, 0].copy(), table[:, 1:].copy()

    def at(t: float) -> np.ndarray:
        return np.array([np.interp(t, times, points[:, i]) for i in range(3)])

    return at
