"""What the operator does: end-effector targets as functions of twin time (world frame, metres)."""

from __future__ import annotations

import array
import csv
import logging
import math
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

import numpy as np

from estimation.errors import TwinError
from estimation.units import UNIT_SCALE, unit_scale
from sync.messages import MAX_COORDINATE

log = logging.getLogger(__name__)

Trajectory = Callable[[float], np.ndarray]

#: The header row a trajectory CSV may start with.
TRAJECTORY_HEADER = ("t", "x", "y", "z")

#: A trajectory file larger than this is refused before it is read (as scene meshes are,
#: :data:`scenes.scenefile.MAX_MESH_BYTES`): an hour of 1 kHz waypoints written at full precision is ~90 MiB.
MAX_TRAJECTORY_BYTES = 128 * 2**20

#: Most waypoints a trajectory may hold: more than an hour at 1 kHz. 32 bytes each in memory.
MAX_WAYPOINTS = 5_000_000

#: Longest a line may be before its ``#`` comment, characters: a row of four numbers is under 100. A 60 MB line
#: of 30 million values took 2.6 GB split into cells; a comment may run on, as it is never split.
MAX_LINE_CHARS = 64 * 2**10

#: Times that look like milliseconds: a script running this long (seconds) whose target never moves faster
#: than :data:`MS_SLOWEST_PEAK` (m/s), but would at a thousand times the speed, is warned about (a 1 m push
#: written in ms runs 2000 s at 0.5 mm/s).
MS_SPAN_S, MS_SLOWEST_PEAK = 100.0, 1e-3

#: Latest a script's first waypoint may come, seconds from the session's start. A script is seconds from the start:
#: one whose times were a logger's clock (Unix time, past 1e9 s since 2001) held the end effector at its first
#: target for the whole run, without a word. A session does not wait a year for its first target.
MAX_START_S = 365 * 86_400.0

#: Most lines a trajectory file may have: a waypoint each and as many blank or comment lines again. Each line
#: is looked at in Python where numpy does not read the file (about 2.4 us a line): a 128 MiB file of blank
#: lines took 320 s to say it held no waypoints.
MAX_LINES = 2 * MAX_WAYPOINTS

#: What a file with no waypoints is told.
_NO_WAYPOINTS = "no waypoints (expected rows t,x,y,z)"

#: Unit names as messages say them.
_UNIT_WORDS = {"m": "metres", "cm": "centimetres", "mm": "millimetres"}


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


#: How far past a target's time it is already taken, seconds: step times are float sums, so a target recorded
#: at t is found at t; half a millisecond is far below a device's command interval and above any sum's error.
HOLD_SLACK = 5e-4


@dataclass(frozen=True, eq=False)
class HeldTargets:
    """Targets taken at times, each held until the next (a zero-order hold, as a device's commands are): a
    recorded operator. Call it with a twin time to get the target, None before the first; O(log n) a call.

    Attributes:
        times: (n,) float64, seconds of twin time, ascending (n may be 0: never a target).
        points: (n, 3) float64, metres, world frame.
        source: where the targets came from (a recording), for messages.
    """

    times: np.ndarray
    points: np.ndarray
    source: str = "targets"

    def __call__(self, t: float) -> np.ndarray | None:
        """The target held at twin time ``t``, seconds: (3,) float64, metres, world frame; None before the first."""
        i = int(np.searchsorted(self.times, t + HOLD_SLACK, side="right")) - 1
        return None if i < 0 else self.points[i]

    def check_reach(self, box: tuple[np.ndarray, np.ndarray]) -> None:
        """Refuse targets outside ``box`` (:func:`check_reach`; no units hint: a recording is in metres).

        Raises:
            TrajectoryError: a target outside the box.
        """
        check_reach(self.times, self.points, box, source=self.source)


@dataclass(frozen=True, eq=False)
class Waypoints:
    """A trajectory read from a file: targets at times, linear between them, held before the first and after
    the last. Call it with a twin time to get the target; O(log n) a call.

    Attributes:
        times: (n,) float64, seconds, strictly increasing.
        points: (n, 3) float64, metres, world frame, C-contiguous.
        source: where the waypoints came from (a file name), for messages.
        units: the units the file was read in (``--units``), for the hint of :meth:`check_reach`.
    """

    times: np.ndarray
    points: np.ndarray
    source: str = "trajectory"
    units: str = "m"

    def __call__(self, t: float) -> np.ndarray:
        """The target at twin time ``t``, seconds: (3,) float64, metres, world frame (a new array)."""
        times, points = self.times, self.points
        i = int(np.searchsorted(times, t, side="right"))
        if i == 0:
            return points[0].copy()
        if i == len(times):
            return points[-1].copy()
        t0, t1 = float(times[i - 1]), float(times[i])
        s = (t - t0) / (t1 - t0)
        if not 0.0 <= s <= 1.0:  # a span past the float range (t from -1e308 to 1e308) made it inf or nan
            s = 1.0 if s > 1.0 else 0.0
        return points[i - 1] + s * (points[i] - points[i - 1])

    def check_reach(self, box: tuple[np.ndarray, np.ndarray]) -> None:
        """Refuse waypoints outside ``box`` (:func:`check_reach`), hinting at ``--units`` when they fit in it
        scaled.

        Raises:
            TrajectoryError: a waypoint outside the box.
        """
        check_reach(self.times, self.points, box, source=self.source, units=self.units)


def check_reach(times: np.ndarray, points: np.ndarray, box: tuple[np.ndarray, np.ndarray], *, source: str,
                units: str | None = None) -> None:
    """Refuse operator targets outside ``box``: the twin's operator workspace
    (:func:`twin.model.reach_corners` with :attr:`twin.runtime.OperatorSettings.reach`), the box live device
    targets are dropped outside of. A script or recording that leaves it sends the end effector through the
    floor (25 kN at z = -5 m) or to 560 m (a file in millimetres).

    Args:
        times: (n,) float64, seconds: when each target applies, for the message.
        points: (n, 3) float64, metres, world frame.
        box: (low, high) corners, (3,) float64 each, metres, world frame.
        source: the file the targets came from, for the message.
        units: the units the file was read in; the message then says when the targets would fit read in
            smaller ones (None: the source has no units option, as a recording).

    Raises:
        TrajectoryError: the first target outside the box, and the box.
    """
    low, high = (np.asarray(c, dtype=np.float64) for c in box)
    inside = _within(points, low, high)
    if inside.all():
        _warn_if_shrunk(points, low, high, source=source, units=units)
        return
    i = int(np.argmin(inside))
    x, y, z = points[i]
    hint = ""
    if units is not None and not inside.any():  # all outside: read in the wrong units, not a stray target
        fits = [name for name, scale in UNIT_SCALE.items() if scale < UNIT_SCALE[units]
                and _within(points * (scale / UNIT_SCALE[units]), low, high).all()]
        if fits:
            hint = (f": looks like {' or '.join(_UNIT_WORDS[f] for f in fits)}: pass "
                    f"{' or '.join(f'--units {f}' for f in fits)}")
    raise TrajectoryError(f"{source}: the target at t = {float(times[i]):g} s, ({x:g}, {y:g}, {z:g}) m, is outside the "
                          f"operator's reach (x {low[0]:g} to {high[0]:g}, y {low[1]:g} to {high[1]:g}, z {low[2]:g} to "
                          f"{high[2]:g} m){hint}")


def _warn_if_shrunk(points: np.ndarray, low: np.ndarray, high: np.ndarray, *, source: str, units: str | None) -> None:
    """Warn of a script that may be in metres read in cm or mm: every target then lies within a hundredth of the
    reach of the world origin (a push over the table read in mm reached for the floor under it and pressed the end
    effector onto the table's top with 97 N, a review's probe), and read in metres all of them fit the reach. A
    warning, not a refusal: a small scene without a table, its end effector near the origin, has real scripts in
    cm that small."""
    if units is None or UNIT_SCALE[units] > UNIT_SCALE["m"] / 100:
        return
    grown = points * (UNIT_SCALE["m"] / UNIT_SCALE[units])
    if _within(grown, low, high).all():
        log.warning("%s: read in %s (--units %s) every target lies within %.3g m of the world origin, and read in "
                    "metres they fit the operator's reach: if the script is in metres, pass --units m", source,
                    _UNIT_WORDS[units], units, float(np.abs(points).max()))


def _within(points: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """(n,) bool: which of the (n, 3) ``points`` lie in the box ``low``..``high``."""
    return np.all((points >= low) & (points <= high), axis=1)


def load_trajectory(path: str | Path, *, units: str = "m") -> Waypoints:
    """An end-effector trajectory from a CSV file.

    Format: one row per waypoint, ``t,x,y,z``: time in seconds (strictly increasing) and the target
    position in ``units`` (metres by default), world frame. An optional first row ``t,x,y,z`` names the
    columns; blank lines and ``#`` comments are skipped. Between waypoints the target moves linearly; before
    the first it is the first, after the last it stays at the last. Example::

        t,x,y,z
        0.0,0.30,0.00,0.12
        2.0,0.45,0.00,0.12

    A script whose times look like milliseconds (over :data:`MS_SPAN_S` s long, never faster than
    :data:`MS_SLOWEST_PEAK` m/s) is read, with a warning.

    Args:
        path: the CSV file, at most :data:`MAX_TRAJECTORY_BYTES` and :data:`MAX_WAYPOINTS` rows.
        units: the positions' units: ``m``, ``cm`` or ``mm`` (:data:`estimation.units.UNIT_SCALE`). The
            targets' reach is the caller's, once it knows the scene: :meth:`Waypoints.check_reach`.

    Returns:
        ``trajectory(t) -> (3,) float64``, metres, world frame: a :class:`Waypoints`.

    Raises:
        TrajectoryError: the file is not a regular file, is too large, or cannot be read, a line is longer than
            :data:`MAX_LINE_CHARS` before its comment, a row has other than four columns or a value that is not a
            finite number, a position beyond :data:`sync.messages.MAX_COORDINATE` (what the wire carries), there
            are no waypoints or too many, the times do not increase.
        UnitsError: ``units`` is not one of m, cm, mm.
    """
    path = Path(path)
    scale = unit_scale(units)
    if path.exists() and not path.is_file() and not path.is_dir():  # a FIFO or device: reading blocks forever
        raise TrajectoryError(f"{path}: not a regular file")
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise _cannot_read(path, exc) from None
    if path.is_file() and size > MAX_TRAJECTORY_BYTES:
        raise TrajectoryError(f"{path}: trajectory file is {size / 2**20:,.0f} MiB, more than the "
                              f"{MAX_TRAJECTORY_BYTES / 2**20:,.0f} MiB a trajectory may take (thin its waypoints)")
    _check_encoding(path)
    _check_line_count(path)
    table = _read_fast(path, scale)
    if table is None:  # numpy refused the file, or it holds a bad value: find which line, and say why
        table = _read_checked(path, scale)
    if len(table) > MAX_WAYPOINTS:
        raise TrajectoryError(f"{path}: more than {MAX_WAYPOINTS:,} waypoints (thin them)")
    times, points = np.ascontiguousarray(table[:, 0]), np.ascontiguousarray(table[:, 1:])
    if times[0] > MAX_START_S:
        raise TrajectoryError(f"{path}: the first waypoint is at t = {times[0]:.10g} s, {times[0] / 86_400:,.0f} days "
                              f"after the session starts: t is in seconds from the start (clock times? subtract "
                              f"the first from each)")
    _warn_if_milliseconds(path, times, points)
    return Waypoints(times, points, source=str(path), units=units)


def _check_line_count(path: Path) -> None:
    """Refuse a file of more than :data:`MAX_LINES` lines (``\\n``, ``\\r\\n`` or ``\\r`` ended), counted in C a
    quarter MiB at a time (held no longer), before any line is looked at in Python."""
    lines = crs = 0
    try:
        with path.open("rb") as fh:
            while chunk := fh.read(2**18):
                # A "\r\n" split across two chunks counts two lines here: a bound, not a count.
                lines += chunk.count(b"\n")
                crs += chunk.count(b"\r") - chunk.count(b"\r\n")
    except OSError as exc:
        raise _cannot_read(path, exc) from None
    if lines + crs > MAX_LINES:
        raise TrajectoryError(f"{path}: {lines + crs:,} lines, more than the {MAX_LINES:,} a trajectory of at most "
                              f"{MAX_WAYPOINTS:,} waypoints may take (blank lines?)")


def _check_encoding(path: Path) -> None:
    """Refuse a UTF-16 or UTF-32 file (Notepad's): without a byte-order mark it decodes as UTF-8 text with a NUL
    after each character, "not a number in 't\\x00,\\x00x...'"."""
    from estimation.textcloud import ENCODING_SAMPLE, wide_encoding

    try:
        with path.open("rb") as fh:
            encoding = wide_encoding(fh.read(ENCODING_SAMPLE))
    except OSError as exc:
        raise _cannot_read(path, exc) from None
    if encoding is not None:
        raise TrajectoryError(f"{path}: the file is {encoding} encoded; save it as UTF-8 or ASCII")


def _cannot_read(path: Path, exc: BaseException) -> TrajectoryError:
    """The one-line error for a trajectory file that cannot be read (an OSError) or decoded (a UnicodeDecodeError):
    Python's own text repeated the path and named the exception ("FileNotFoundError: [Errno 2] ...")."""
    if isinstance(exc, UnicodeDecodeError):
        return TrajectoryError(f"{path}: not UTF-8 text (byte 0x{exc.object[exc.start]:02x} at offset {exc.start})")
    if isinstance(exc, OSError) and exc.strerror:
        return TrajectoryError(f"{path}: cannot read trajectory: {exc.strerror}")
    return TrajectoryError(f"{path}: cannot read trajectory ({exc.__class__.__name__}: {exc})")


def _rows(path: Path) -> Iterator[tuple[int, list[str]]]:
    """(line number where it starts, stripped cells) of each row that is not blank, a ``#`` comment or the
    header row; a ``#`` outside quotes ends a row (as ``numpy.loadtxt`` reads it, so both readers see the same
    rows), and the comment after it never reaches the CSV parser (:func:`_uncommented_lines`).

    Raises:
        TrajectoryError: the file cannot be read or decoded, has a line longer than :data:`MAX_LINE_CHARS`
            before its comment, or is not CSV (a stray quote).
    """
    try:
        # utf-8-sig: a spreadsheet's CSV starts with a byte-order mark, which made the header "not a number".
        with path.open(encoding="utf-8-sig", newline="") as fh:
            reader = csv.reader(_uncommented_lines(path, fh))
            first = True
            try:
                while True:
                    # Where the row starts: a stray quote makes one row of many lines, and line_num is its end
                    # (the fast reader skipped every line before it and read one waypoint of a thousand).
                    start = reader.line_num + 1
                    row = next(reader, None)
                    if row is None:
                        break
                    if any("\n" in c or "\r" in c for c in row):
                        raise TrajectoryError(f"{path}:{start}: not CSV (a stray quote runs this row on to line "
                                              f"{reader.line_num})")
                    cells = [c.strip() for c in row]
                    if not cells or cells == [""]:
                        continue
                    if first:
                        first = False
                        if tuple(c.lower() for c in cells) == TRAJECTORY_HEADER:
                            continue
                    yield start, cells
            except csv.Error as exc:  # a stray quote makes one field of the rest of the file, past csv's limit
                raise TrajectoryError(f"{path}:{reader.line_num}: not CSV ({exc})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise _cannot_read(path, exc) from None


def _uncommented_lines(path: Path, fh: TextIO) -> Iterator[str]:
    """Each line of ``fh`` up to its comment (:func:`_before_comment`), one a line so the CSV parser counts
    lines as the file does. A comment's text went through the parser before: a quote in one before the data
    opened a field that ran on ("not CSV"), and one over 128 KiB passed csv's field limit.

    Raises:
        TrajectoryError: a line longer than :data:`MAX_LINE_CHARS` before its comment, refused before it is
            split into cells (a 60 MB line of values took 2.6 GB) or read whole.
    """
    for number, line in enumerate(_bounded_lines(fh, MAX_LINE_CHARS), 1):
        content = _before_comment(line)
        if len(content.rstrip("\r\n")) > MAX_LINE_CHARS:
            raise TrajectoryError(f"{path}:{number}: a line of more than {MAX_LINE_CHARS:,} characters where a row "
                                  f"t,x,y,z was expected")
        yield content


def _bounded_lines(fh: TextIO, most: int) -> Iterator[str]:
    """Each line of ``fh``, its end kept; of a line longer than ``most`` characters only the first ``most`` + 1,
    without its end: the rest is read ``most`` + 1 characters at a time and dropped, never held whole."""
    size = most + 1
    split_crlf = False  # the last piece was cut at "\r" by the size limit: its "\n" comes next, alone
    within = False  # the last piece did not end its line
    while piece := fh.readline(size):
        if split_crlf and piece == "\n":  # not a blank line: the end of the one before
            split_crlf = False
            continue
        split_crlf = len(piece) == size and piece.endswith("\r")
        if not within:
            yield piece
        within = not piece.endswith(("\n", "\r"))


def _before_comment(line: str) -> str:
    """``line`` up to its first ``#`` outside quotes, then ended anew; ``line`` itself when it has none. As in
    ``numpy.loadtxt``, a ``"`` opens or closes a quote wherever it stands, and a quoted ``#`` is text."""
    if "#" not in line:
        return line
    parts = line.split('"')
    for k in range(0, len(parts), 2):  # the even parts are outside quotes ('""' in a quote closes and reopens)
        if "#" in parts[k]:
            return '"'.join([*parts[:k], parts[k].split("#", 1)[0]]) + "\n"
    return line


def _read_fast(path: Path, scale: float) -> np.ndarray | None:
    """The (n, 4) table of a well-formed file (positions in metres) read by ``numpy.loadtxt``, or None for any
    file :func:`_read_checked` must look at: one numpy refuses or with a value the checks refuse.

    Python's csv module and a float per cell took 4.8 s and 700 MB for a million rows; this is ~0.7 s and the
    table. Only the header is found line by line.
    """
    rows = _rows(path)
    try:  # the first row of numbers; the lines before it are comments or the header, for numpy to skip
        first = next(rows, None)
    finally:
        rows.close()  # closes the file now, not when the generator is collected
    if first is None:  # said here: the line-by-line reader would look at every line again to say it
        raise TrajectoryError(f"{path}: {_NO_WAYPOINTS}")
    if len(first[1]) != len(TRAJECTORY_HEADER):
        # numpy allocates max_rows times the first row's columns before it reads on: a 2 KB file of one
        # 1000-value row asked for 40 GB ("out of memory").
        return None
    skip = first[0] - 1
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "input contained no data": no waypoints, said below
            table = np.loadtxt(path, dtype=np.float64, delimiter=",", comments="#", quotechar='"', skiprows=skip,
                               ndmin=2, encoding="utf-8-sig", max_rows=MAX_WAYPOINTS + 1)
    except (OSError, UnicodeDecodeError) as exc:
        raise _cannot_read(path, exc) from None
    except ValueError:
        return None
    if table.shape[0] == 0 or table.shape[1] != 4:
        return None
    table[:, 1:] *= scale
    with np.errstate(over="ignore"):  # t from -1e308 to 1e308 increases, by more than a double holds
        increasing = bool((np.diff(table[:, 0]) > 0).all())
    if not (increasing and np.isfinite(table).all() and np.abs(table[:, 1:]).max() <= MAX_COORDINATE):
        return None
    return table


def _read_checked(path: Path, scale: float) -> np.ndarray:
    """Every row checked in turn, so the first bad one is named by its line; the (n, 4) table (positions in
    metres) when none is bad (a value numpy does not read but Python does, as ``1_000``).

    Raises:
        TrajectoryError: the first bad row, or no rows.
    """
    values = array.array("d")
    previous = -math.inf
    for number, cells in _rows(path):
        if len(cells) != 4:
            raise TrajectoryError(f"{path}:{number}: expected 4 columns t,x,y,z, got {len(cells)}{_separator(cells)}")
        try:
            row = [float(c) for c in cells]
        except ValueError:
            raise TrajectoryError(f"{path}:{number}: not a number in {_shown(cells)}") from None
        row[1:] = [v * scale for v in row[1:]]
        if not all(math.isfinite(v) for v in row):
            raise TrajectoryError(f"{path}:{number}: non-finite value in {_shown(cells)}")
        if any(abs(v) > MAX_COORDINATE for v in row[1:]):
            raise TrajectoryError(f"{path}:{number}: a position beyond {MAX_COORDINATE:g} m in {_shown(cells)}")
        if row[0] <= previous:
            raise TrajectoryError(f"{path}:{number}: t = {row[0]:g} s does not increase (previous {previous:g} s)")
        previous = row[0]
        values.extend(row)
        if len(values) > 4 * MAX_WAYPOINTS:
            raise TrajectoryError(f"{path}: more than {MAX_WAYPOINTS:,} waypoints (thin them)")
    if not values:
        raise TrajectoryError(f"{path}: {_NO_WAYPOINTS}")
    return np.frombuffer(values, dtype=np.float64).reshape(-1, 4)


def _separator(cells: list[str]) -> str:
    """What a refused row of one cell says when it holds four values split by ';' or white space: 'got 1' alone
    left the reason to be guessed."""
    if len(cells) == 1:
        for separator, name in ((";", "';'"), (None, "white space")):
            if len(cells[0].split(separator)) == 4:
                return f" (separated by {name}; the separator must be a comma)"
    return ""


def _shown(cells: list[str], most: int = 80) -> str:
    """A row as a message quotes it: a 5,000-digit number made a 5 kB "one-line" error."""
    text = ",".join(cells)
    return repr(text if len(text) <= most else text[:most] + "...")


def _warn_if_milliseconds(path: Path, times: np.ndarray, points: np.ndarray) -> None:
    """Warn about times that look like milliseconds: long, and never faster than a crawl."""
    if len(times) < 2:
        return
    with np.errstate(over="ignore"):  # times from -1e308 to 1e308: an infinite gap, so no speed at all
        span = float(times[-1] - times[0])
        if not span > MS_SPAN_S:
            return
        moves = np.diff(points, axis=0)
        peak = float((np.sqrt(np.einsum("ij,ij->i", moves, moves)) / np.diff(times)).max())
    if MS_SLOWEST_PEAK / 1000 <= peak < MS_SLOWEST_PEAK:
        log.warning("%s: the script runs %g s and the target moves at most %.3g mm/s: if its times are in "
                    "milliseconds, divide them by 1000 (t is in seconds)", path, span, peak * 1e3)
