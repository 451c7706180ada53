"""What the cloud-file formats share: a header, then a table of one row a point.

A reader hands back :class:`Columns` (x y z, normals, colours, sensor origins, in file units; ``make_cloud``
cleans and scales them). Before it allocates anything, it checks what the header claims with the checks here:
the point count against ``max_points`` (:func:`check_max_points`) and against the file's size, exactly for
binary data (:func:`check_binary_size`), at least one short line a point for text (:func:`check_text_size`).
A file that claims more points than it holds is a :class:`CloudFileError` naming the claimed and the present
counts, never a cloud padded with points at the origin.

Used by ``plyfile``, ``pcdfile``, ``textcloud`` and ``numpycloud``; ``cloudfile`` picks among them.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimation.cloud import PointCloud
from estimation.errors import CloudFileError

log = logging.getLogger(__name__)

#: Headers longer than this are not searched for their end. Real PLY/PCD headers are under 1 KB even with
#: comments; the bound keeps a large non-cloud file with a cloud suffix from being scanned whole.
MAX_HEADER_BYTES = 1 << 20

#: The shortest text a point can take: one digit and one separator per value ("0 0 0\n").
_MIN_TEXT_BYTES_PER_VALUE = 2


@dataclass(frozen=True)
class Columns:
    """What a reader found, in file units; make_cloud cleans and scales it."""

    points: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    sensor_origins: np.ndarray | None = None


# --- headers -----------------------------------------------------------------------------------------


def read_head(path: Path) -> tuple[bytes, int]:
    """The file's first bytes (up to MAX_HEADER_BYTES) and its size."""
    size = path.stat().st_size
    with path.open("rb") as fh:
        return fh.read(min(size, MAX_HEADER_BYTES)), size


def header_lines(head: bytes, is_last: Callable[[str], bool]) -> tuple[list[str], int] | None:
    """Split ``head`` into stripped text lines up to the one ``is_last`` accepts.

    Returns the lines (the last one included) and the byte offset just past it, or None when no line in
    ``head`` ends the header.
    """
    lines: list[str] = []
    pos = 0
    while pos < len(head):
        end = head.find(b"\n", pos)
        stop = len(head) if end < 0 else end + 1
        # latin-1 decodes any byte, so garbage reaches the checks below instead of a UnicodeDecodeError.
        line = head[pos:stop].decode("latin-1").strip()
        lines.append(line)
        pos = stop
        if is_last(line):
            return lines, pos
    return None


#: Largest count a header may claim: a row takes a byte at least, and no file reaches 2^53 bytes.
MAX_COUNT = 2**53


def header_count(path: Path, text: str, what: str) -> int:
    # Decimal digits only: Python's int() also takes "2_000", "+2000" and other scripts' digits, which no PLY or
    # PCD writer produces and other readers refuse.
    if not (text.isascii() and text.removeprefix("-").isdigit() and len(text) <= 20):  # 20: any int64
        raise CloudFileError(f"{path}: {what} count {text[:40]!r} is not an integer")
    value = int(text)
    if value < 0:
        raise CloudFileError(f"{path}: {what} count is negative ({value})")
    if value > MAX_COUNT:  # past int64 it was an OverflowError deep in the reading
        raise CloudFileError(f"{path}: {what} count {value} is more than any file holds")
    return value


def check_max_points(path: Path, claimed: int, max_points: int) -> None:
    if claimed > max_points:
        raise CloudFileError(
            f"{path}: the header claims {claimed} points, more than max_points={max_points} "
            "(pass a larger max_points to load_cloud if the file is real)"
        )


#: Bytes of a binary body read at once when its rows carry fields the reader does not use.
BLOCK_BYTES = 64 << 20


def read_binary_rows(path: Path, dtype: np.dtype, count: int, offset: int, keep: tuple[str, ...]) -> np.ndarray:
    """``count`` records of ``dtype`` from ``offset``, with only the fields named in ``keep`` (packed).

    Rows are capped (``max_points``), their width is not: a PCD of 200,000 points with an unused 32 KiB field a
    point (a 6.5 GB sparse file, a few KB on disk) was read whole into memory. Where fields are dropped the body
    is read in blocks of :data:`BLOCK_BYTES`, so memory follows what is kept. Fewer rows come back if the file
    is shorter (the caller checks).
    """
    names = [name for name in dtype.names or () if name in keep]
    if len(names) == len(dtype.names or ()):
        return np.fromfile(path, dtype=dtype, count=count, offset=offset)
    out = np.empty(count, np.dtype([(name, dtype.fields[name][0]) for name in names]))  # type: ignore[index]
    rows, done = max(1, BLOCK_BYTES // max(dtype.itemsize, 1)), 0
    with path.open("rb") as fh:
        fh.seek(offset)
        while done < count:
            want = min(rows, count - done)
            block = np.fromfile(fh, dtype=dtype, count=want)
            for name in names:
                out[name][done:done + len(block)] = block[name]
            done += len(block)
            if len(block) < want:
                return out[:done]
    return out


#: Bytes a text body of numbers is made of; and how many of a binary body's first bytes are looked at.
_NUMBER_TEXT, _BODY_SAMPLE = frozenset(b"0123456789+-.eE \t\r\n"), 64


def text_body(path: Path, offset: int) -> bool:
    """Whether the body from ``offset`` starts as a text of numbers would (digits, spaces, line ends): a binary
    format's header over a text body (read as binary: "coordinates reach 5.47e+22 m")."""
    with path.open("rb") as fh:
        fh.seek(offset)
        body = fh.read(_BODY_SAMPLE)
    return bool(body) and set(body) <= _NUMBER_TEXT and any(chr(b).isdigit() for b in body) and any(
        b in b" \t\n" for b in body)


def check_binary_size(path: Path, size: int, offset: int, claimed: int, itemsize: int, what: str) -> None:
    """Raise unless ``claimed`` records of ``itemsize`` bytes fit between ``offset`` and the end."""
    available = max(0, size - offset)
    if claimed * itemsize > available:
        raise CloudFileError(
            f"{path}: truncated: the header claims {claimed} {what} but the file holds "
            f"{available // itemsize} ({available} bytes after the header, {itemsize} bytes each)"
        )


def check_text_size(path: Path, size: int, offset: int, claimed: int, values: int, what: str) -> None:
    """Raise when fewer bytes follow the header than the shortest text ``claimed`` rows could take."""
    available = max(0, size - offset)
    least = claimed * values * _MIN_TEXT_BYTES_PER_VALUE
    if least > available:
        raise CloudFileError(
            f"{path}: truncated: the header claims {claimed} {what} of {values} values, which need at least "
            f"{least} bytes, but {available} follow the header"
        )


#: Longest line a text cloud may have, bytes: a row of nine numbers written at full precision is under 250.
MAX_TEXT_LINE = 4096

#: Bytes of a text body read at a time by :func:`read_rows`.
ROWS_BLOCK = 1 << 20


def read_rows(path: Path, offset: int, rows: int, values: int) -> tuple[list[bytes], bool]:
    """The first ``rows`` lines after ``offset`` (fewer if the file ends first) and whether anything but
    whitespace follows them, read a block at a time: a PLY whose header claims 200 vertices, followed by a
    1 GB hole of NUL bytes (8 KB on disk), took 2 GB read whole.

    ``values``: the numbers a row holds; a line longer than that many can take (or ``MAX_TEXT_LINE``) is
    refused.

    Raises:
        CloudFileError: a line too long to be a row of numbers.
    """
    longest = max(MAX_TEXT_LINE, 40 * values)
    chunks: list[bytes] = []
    found, run = 0, 0  # lines ended so far; bytes of the line not yet ended
    trailing = False
    with path.open("rb") as fh:
        fh.seek(offset)
        while found < rows and (block := fh.read(ROWS_BLOCK)):
            ends = np.flatnonzero(np.frombuffer(block, np.uint8) == 10)[: rows - found]
            take = int(ends[-1]) + 1 if found + len(ends) == rows else len(block)
            lengths = ends - np.concatenate([[-run], ends[:-1] + 1])  # each line ended here, bytes
            run = take - (int(ends[-1]) + 1) if len(ends) else run + take
            if max(int(lengths.max(initial=0)), run) > longest:
                raise CloudFileError(f"{path}: a line of more than {longest:,} bytes where a row of {values} numbers "
                                     f"was expected: not a text point table")
            chunks.append(block[:take])
            found += len(ends)
            if found == rows:
                trailing = bool((block[take:] or fh.read(ROWS_BLOCK)).strip())
    return b"".join(chunks).split(b"\n")[:rows], trailing


def check_row_widths(path: Path, rows: list[bytes], claimed: int, values: int, first_line: int, what: str,
                     width: str) -> None:
    """Raise unless ``claimed`` ``rows`` (from :func:`read_rows`) each hold ``values`` whitespace-separated values.

    Only the total was checked: two points a line with blank lines between them loaded, and a line with one
    value too many next to one with one too few moved a point's coordinates along. ``first_line``: the file's
    line number of ``rows[0]``; ``what``: the rows' name ("points"); ``width``: where ``values`` comes from.

    Raises:
        CloudFileError: the first row holding another number of values, by its line, or "truncated" when the
            file ends there (no row after it holds anything).
    """
    counts = np.zeros(claimed, dtype=np.int64)
    counts[: len(rows)] = [len(row.split()) for row in rows[:claimed]]  # 0.2 s a million rows; numpy's took 0.9
    bad = np.flatnonzero(counts != values)
    if not len(bad):
        return
    first = int(bad[0])
    if counts[first] < values and not counts[first + 1 :].any():
        raise CloudFileError(f"{path}: truncated: the header claims {claimed} {what} but the file holds {first}")
    raise CloudFileError(f"{path}: line {first_line + first} holds {counts[first]} values where {width} give {values}")


# --- the table ---------------------------------------------------------------------------------------


def parse_numbers(text: bytes) -> np.ndarray:
    """Whitespace-separated numbers (nan and inf included) -> float64, or ValueError on anything else."""
    with warnings.catch_warnings():
        # numpy < 2.3 only warns on trailing garbage; make it the error newer numpy raises.
        warnings.simplefilter("error", DeprecationWarning)
        try:
            return np.fromstring(text, dtype=np.float64, sep=" ")
        except (DeprecationWarning, ValueError):
            raise ValueError("text that is not a number among the values") from None


def _unit_colors(values: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Colour channels to [0, 1] by their declared type: integers span the type, floats already do."""
    if dtype.kind in "ui":
        return values / float(np.iinfo(dtype).max)
    return values


def columns_from(
    table: np.ndarray | dict[str, np.ndarray],
    types: dict[str, np.dtype],
    *,
    normals: tuple[str, str, str],
    colors: tuple[str, str, str] | None,
    sensor_origins: np.ndarray | None = None,
) -> Columns:
    """Pick x y z, the normals and the colours out of a structured array (or a dict of columns)."""
    n = len(table["x"])

    def stack(names: tuple[str, str, str]) -> np.ndarray:
        if isinstance(table, np.ndarray) and table.flags.c_contiguous:
            (t0, o0), (t1, o1), (t2, o2) = (table.dtype.fields[name][:2] for name in names)  # type: ignore[index]
            if t0 == t1 == t2 and o1 - o0 == o2 - o1 == t0.itemsize:
                # Three adjacent fields of one type: one strided (n, 3) view, converted in one pass.
                view = np.ndarray((n, 3), t0, table, o0, (table.dtype.itemsize, t0.itemsize))
                return view.astype(np.float64)
        out = np.empty((n, 3), dtype=np.float64)
        for i, name in enumerate(names):
            out[:, i] = table[name]  # converts any type and byte order to native float64
        return out

    points = stack(("x", "y", "z"))
    nrm = stack(normals) if all(name in types for name in normals) else None
    col = None
    if colors is not None and all(name in types for name in colors):
        col = stack(colors)
        for i, name in enumerate(colors):
            col[:, i] = _unit_colors(col[:, i], types[name])
    return Columns(points, nrm, col, sensor_origins)


def split_columns(table: np.ndarray, where: object = "the table") -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """x y z, x y z nx ny nz, x y z r g b, x y z nx ny nz r g b, or x y z and one value more (a lidar's
    intensity, as KITTI and many scanners write it, or a homogeneous w), which is left out with a warning
    naming ``where``: refusing it turned away a common file, and dropping it in silence hid a w that is not 1."""
    if table.ndim != 2 or table.shape[1] not in (3, 4, 6, 9):
        raise CloudFileError(f"expected 3, 4, 6 or 9 columns (xyz, an intensity, normals, colours), got shape {table.shape}")
    points = table[:, :3]
    if table.shape[1] == 4:
        log.warning("%s: 4 columns: read as x y z, the 4th left out (an intensity? if it is a homogeneous w, divide "
                    "by it first)", where)
    if table.shape[1] in (3, 4):
        return points, None, None
    if table.shape[1] == 9:
        return points, table[:, 3:6], table[:, 6:9]
    # Six columns: normals are unit length, colours are not.
    rest = table[:, 3:6]
    is_normals = np.allclose(np.linalg.norm(rest[: min(len(rest), 1000)], axis=1), 1.0, atol=1e-3)
    return (points, rest, None) if is_normals else (points, None, rest)


# --- writing -----------------------------------------------------------------------------------------


def byte_colors(cloud: PointCloud) -> np.ndarray:
    assert cloud.colors is not None
    return np.clip(np.rint(cloud.colors * 255.0), 0, 255).astype(np.uint8)


def write_table(
    path: Path, header: list[str], fields: list[tuple[str, str]], columns: list[np.ndarray], *, ascii: bool
) -> None:
    """Write ``header`` lines then one record a point, as text or little-endian binary."""
    n = len(columns[0])
    table = np.empty(n, dtype=np.dtype([(name, "<" + code) for name, code in fields]))
    names = iter(name for name, _ in fields)
    for column in columns:
        for j in range(column.shape[1]):
            table[next(names)] = column[:, j]
    with path.open("wb") as fh:
        fh.write(("\n".join(header) + "\n").encode("ascii"))
        if ascii:
            # 17 digits round-trip a double, 9 a float32 (the bits of a packed PCD colour included).
            fmt = {"f8": "%.17g", "f4": "%.9g", "u1": "%d"}
            np.savetxt(fh, table, fmt=[fmt[code] for _, code in fields])
        else:
            table.tofile(fh)
