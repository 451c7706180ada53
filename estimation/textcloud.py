"""Text point clouds: .xyz/.xyzn/.xyzrgb/.pts and .txt/.csv/.asc, read and written.

Read through ``numpy.loadtxt``, one row a point, values separated by white space, commas or semicolons. A header
row of column names, as pandas, spreadsheets and CloudCompare (``//X,Y,Z``) write one, picks the columns by name;
without one, the suffix says what the columns are (.txt/.csv/.asc/.xyz: 3, 4 (the 4th left out), 6 or 9 columns). A Leica .pts starts
with its point count. Before the file is read whole its line lengths and count are checked in blocks, so a
huge or binary file under a text suffix is refused in bounded memory.
"""

from __future__ import annotations

import codecs
import logging
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimation.cloud import PointCloud
from estimation.cloudtable import MAX_TEXT_LINE, Columns, byte_colors, split_columns
from estimation.errors import CloudFileError

log = logging.getLogger(__name__)



#: Bytes of a text file scanned at a time for its line lengths, before it is read whole.
TEXT_SCAN_BLOCK = 1 << 24


def _scan_text(path: Path, max_points: int) -> None:
    """Refuse a text file with a line longer than ``MAX_TEXT_LINE`` or far more than ``max_points`` lines, read
    in blocks: read whole first, a sparse 1 GB file of NUL bytes took 2.1 GB before its first line was found
    too long, and one larger than the memory would have been killed rather than refused. It stops at the first
    block that shows a line too long: a sparse 10 GB file without a line end was scanned to its end (37 s) to
    say how long its one line was.

    Raises:
        CloudFileError: the line too long (its length, or that it has no end in the bytes read), or the count.
    """
    longest, run, lines = 0, 0, 0
    with path.open("rb") as fh:
        while block := fh.read(TEXT_SCAN_BLOCK):
            raw = np.frombuffer(block, np.uint8)
            ends = np.flatnonzero((raw == 10) | (raw == 13))  # '\r' ends lines too (old Mac files)
            if not len(ends):
                run += len(raw)
            else:
                longest = max(longest, run + int(ends[0]), int(np.diff(ends).max(initial=1)) - 1)
                run = len(raw) - int(ends[-1]) - 1
                lines += len(ends)
                if lines > 2 * (max_points + 1):  # '\r\n' counts twice here; the exact count follows the read
                    raise CloudFileError(f"{path}: more than max_points={max_points} lines (pass a larger max_points "
                                         f"if real)")
            # The reader keeps every line as a Python string, several times over: one 256 MB line of NUL bytes
            # took 3 GB before it was found not to be numbers.
            if longest > MAX_TEXT_LINE:
                raise CloudFileError(f"{path}: a line of {longest:,} bytes, more than a row of numbers holds "
                                     f"(at most {MAX_TEXT_LINE:,}): not a text point cloud")
            if run > MAX_TEXT_LINE:  # a line not ended yet: what follows is not read
                raise CloudFileError(f"{path}: a line longer than {MAX_TEXT_LINE:,} bytes (no line end in {run:,} "
                                     f"bytes), more than a row of numbers holds: not a text point cloud")


#: Byte-order marks of the wide Unicode encodings, UTF-32's first: its little-endian mark starts with UTF-16's.
_WIDE_MARKS = ((codecs.BOM_UTF32_LE, "UTF-32"), (codecs.BOM_UTF32_BE, "UTF-32"),
               (codecs.BOM_UTF16_LE, "UTF-16"), (codecs.BOM_UTF16_BE, "UTF-16"))
#: Bytes ASCII text is made of: tab, line ends, the printable characters.
_ASCII_TEXT = np.array([9, 10, 13, *range(32, 127)], dtype=np.uint8)
#: Bytes from a file's start :func:`wide_encoding` looks at.
ENCODING_SAMPLE = 4096


def wide_encoding(head: bytes) -> str | None:
    """The encoding, "UTF-16" or "UTF-32", when ``head`` (a file's first bytes) starts with its byte-order mark or
    is ASCII text in it without one (each character next to one NUL byte, or three); else None.

    Notepad and PowerShell's ``>`` write UTF-16: read byte by byte, its rows were "not numbers" quoted as garbage.
    """
    for mark, name in _WIDE_MARKS:
        if head.startswith(mark):
            return name
    sample = head[:ENCODING_SAMPLE]
    for width in (4, 2):
        units = np.frombuffer(sample[: len(sample) // width * width], np.uint8).reshape(-1, width)
        nul = (units == 0).all(axis=0)  # the byte positions of a character that are NUL throughout
        if len(units) > 1 and nul.sum() == width - 1 and np.isin(units[:, ~nul], _ASCII_TEXT).all():
            return f"UTF-{8 * width}"
    return None


def read_text(path: Path, max_points: int) -> Columns:
    suffix = path.suffix.lower()
    _scan_text(path, max_points)
    # A spreadsheet's CSV starts with a UTF-8 byte-order mark: "could not convert string 'ï»¿0.1'".
    text = path.read_bytes().removeprefix(codecs.BOM_UTF8)
    if (encoding := wide_encoding(text)) is not None:
        raise CloudFileError(f"{path}: the file is {encoding} encoded; save it as UTF-8 or ASCII")
    if text.count(b"\n") > max_points + 1:
        raise CloudFileError(f"{path}: more than max_points={max_points} lines (pass a larger max_points if real)")
    claimed = None
    if suffix == ".pts":
        first, _, rest = text.partition(b"\n")
        if first.strip().isdigit():  # a Leica .pts starts with its point count
            claimed, text = int(first), rest
    if not text.strip():
        raise CloudFileError(f"{path}: holds no numbers, only whitespace")
    lines = text.decode("latin-1").splitlines()
    if len(lines) > max_points + 1:  # '\r' (old Mac) ends lines too, which the count of '\n' above missed
        raise CloudFileError(f"{path}: more than max_points={max_points} lines (pass a larger max_points if real)")
    first_line = 1 if claimed is None else 2  # the file's line number of lines[0]
    named = _header_row(path, lines, first_line=first_line)
    if named is not None:
        lines = lines[named.line + 1:]
        first_line += named.line + 1
        if not any(line.split("#", 1)[0].strip() for line in lines):
            raise CloudFileError(f"{path}: a header row and no rows of numbers after it")
    first = _first_content(lines)
    delimiter = None if first is None else _delimiter(lines[first])
    values = "" if first is None else lines[first].split("#", 1)[0]
    if _decimal_commas(values):
        # A spreadsheet set to a decimal comma writes '0,12;0,05;0,3' (a ';' may end the line) or tabs between
        # them: numpy named '0,12' (or '12\t0') as not a number.
        raise CloudFileError(f"{path}: line {first + first_line} has decimal commas ({lines[first].strip()[:60]!r}): "
                             f"write the numbers with '.' decimals")
    if delimiter == ";" and "," in values:
        # A line whose values already have '.' decimals ('0.1,0.2;0.3') mixes two separators.
        raise CloudFileError(f"{path}: line {first + first_line} separates its values with both ',' and ';' "
                             f"({lines[first].strip()[:60]!r}): use one separator")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # loadtxt warns (to stderr) on a file of comments only; make it an error
        try:
            table = np.loadtxt(lines, delimiter=delimiter, ndmin=2)
        except UserWarning as exc:
            raise CloudFileError(f"{path}: holds no numbers ({exc})") from None
        except ValueError:
            # numpy's own words ("the number of columns changed from 3 to 2 at row 3; use `usecols`...") count
            # rows its way and speak of its arguments: name the file's line instead.
            bad = _ragged_row(lines, delimiter)
            if bad is None:
                raise
            raise CloudFileError(f"{path}: line {bad[0] + first_line} {bad[1]}") from None
    if claimed is not None and claimed != len(table):
        if claimed > len(table):
            raise CloudFileError(f"{path}: truncated: the first line claims {claimed} points but the file holds {len(table)}")
        log.warning("%s: the first line claims %d points but the file holds %d; reading all", path, claimed, len(table))
    if named is not None:
        if table.shape[1] != named.width:
            raise CloudFileError(f"{path}: the header row names {named.width} columns, the rows hold {table.shape[1]}")
        return named.columns(table)
    if suffix in (".txt", ".csv", ".asc") or (suffix == ".xyz" and table.shape[1] in (4, 6, 9)):
        # An .xyz holds whatever its writer put after x y z (CloudCompare: normals, colours or both; a lidar:
        # an intensity): read as a .txt is, where its 6 columns were once left out in silence.
        return Columns(*split_columns(table, path))
    need = {".xyz": 3, ".xyzn": 6, ".xyzrgb": 6, ".pts": 3}[suffix]
    if table.shape[1] < need:
        raise CloudFileError(f"{path}: a {suffix} file needs at least {need} columns, got {table.shape[1]}")
    if suffix == ".xyz" and table.shape[1] > 3:
        log.warning("%s: %d columns: read as x y z, the other %d left out", path, table.shape[1], table.shape[1] - 3)
    points = table[:, :3]
    if suffix == ".xyzn":
        return Columns(points, table[:, 3:6])
    if suffix == ".xyzrgb":
        return Columns(points, None, table[:, 3:6])
    if suffix == ".pts" and table.shape[1] in (6, 7):  # x y z [intensity] r g b, colours 0-255
        return Columns(points, None, table[:, -3:] / 255.0)
    return Columns(points)


#: Column names a text file's header row may use (case and surrounding quotes ignored), by what they hold.
_HEADER_NAMES = {
    "points": (("x",), ("y",), ("z",)),
    "normals": (("nx", "normal_x", "normalx"), ("ny", "normal_y", "normaly"), ("nz", "normal_z", "normalz")),
    "colors": (("r", "red", "rf"), ("g", "green", "gf"), ("b", "blue", "bf")),  # rf gf bf: CloudCompare's 0-1 floats
}


@dataclass(frozen=True)
class _HeaderRow:
    """A text file's row of column names: its line index, how many columns it names, and where each of
    ``_HEADER_NAMES``' triples is (None: not all three named)."""

    line: int
    width: int
    found: dict[str, tuple[int, int, int] | None]

    def columns(self, table: np.ndarray) -> Columns:
        """The named columns of ``table`` (colours as written: ``make_cloud`` rescales 0-255)."""
        picked = {kind: None if at is None else table[:, list(at)] for kind, at in self.found.items()}
        return Columns(picked["points"], picked["normals"], picked["colors"])  # type: ignore[arg-type]


def _header_row(path: Path, lines: list[str], first_line: int = 1) -> _HeaderRow | None:
    """The row of column names a spreadsheet, pandas or CloudCompare (``//X,Y,Z``) writes before the numbers, or
    None when the first line that is not a ``#`` comment holds a number (it is data, good or bad, for
    ``numpy.loadtxt`` to read or name). Columns are then taken by name, and the others (an index, intensity,
    scalar fields) are left out. ``first_line``: the file's line number of ``lines[0]``, for messages.

    Raises:
        CloudFileError: a header row without x, y and z, or naming one of them twice.
    """
    index = _first_content(lines)
    if index is None:
        return None
    line = lines[index]
    stripped = line.split("#", 1)[0].strip().removeprefix("//")  # '#' starts a comment, as numpy.loadtxt reads it
    tokens = [t.strip().strip("'\"").lower() for t in stripped.split(_delimiter(stripped))]
    if any(_is_number(t) for t in tokens) or _decimal_commas(stripped):
        return None  # data; decimal commas too, which the caller names (not "not a header row")
    found: dict[str, tuple[int, int, int] | None] = {}
    for kind, triple in _HEADER_NAMES.items():
        at = []
        for names in triple:
            hits = [i for i, t in enumerate(tokens) if t in names]
            if len(hits) > 1:
                raise CloudFileError(f"{path}: the header row names column {names[0]!r} {len(hits)} times")
            at.append(hits[0] if hits else None)
        found[kind] = None if None in at else (at[0], at[1], at[2])  # type: ignore[assignment]
    if found["points"] is None:
        shown = line.strip()[:80]
        raise CloudFileError(f"{path}: line {index + first_line} is not numbers and not a header row naming x, y and z "
                             f"columns: {shown!r}")
    used = {i for at in found.values() if at is not None for i in at}
    if len(used) < len(tokens):
        log.info("%s: columns left out (not x y z, nx ny nz or r g b): %s", path,
                 ", ".join(repr(t) for i, t in enumerate(tokens) if i not in used))
    return _HeaderRow(index, len(tokens), found)


def _delimiter(line: str) -> str | None:
    """What separates the values of ``line``: ';' (a spreadsheet set to decimal commas), ',' or white space (None)."""
    text = line.split("#", 1)[0]
    return ";" if ";" in text else "," if "," in text else None


#: A number written with a decimal comma ('0,12', '-1,5e-3'): digits on both sides, so that '1,' of '1, 2, 3'
#: (commas and spaces between values) is not one.
_DECIMAL_COMMA = re.compile(r"[-+]?\d*,\d+(?:[eE][-+]?\d+)?")


def _decimal_commas(values: str) -> bool:
    """Whether ``values`` (a line without its comment) are numbers with decimal commas, separated by ';' or white
    space ('0,12;0,05;0,3', '0,12\t0,05\t0,3'): each a number, at least one with a decimal comma."""
    fields = [f.strip() for f in (values.split(";") if ";" in values else values.split()) if f.strip()]
    return (any("," in f for f in fields)
            and all(_DECIMAL_COMMA.fullmatch(f) if "," in f else _is_number(f) for f in fields))


def _ragged_row(lines: list[str], delimiter: str | None) -> tuple[int, str] | None:
    """The index in ``lines`` of the first row with a number of values other than the rows' before it, and what
    it holds; None when a value that is not a number comes first (numpy's message names it and its column).

    A loop over the lines, for the failure path only (numpy has refused the file already).
    """
    width = None
    for index, line in enumerate(lines):
        text = line.split("#", 1)[0].strip()  # '#' starts a comment, as numpy.loadtxt reads it
        if not text:
            continue
        values = text.split(delimiter)
        if width is None:
            width = len(values)
        elif len(values) != width:
            return index, f"holds {len(values)} values where the rows before hold {width}"
        if not all(_is_number(v) for v in values):
            return None
    return None


def _first_content(lines: list[str]) -> int | None:
    """The index of the first line that is neither blank nor a ``#`` comment (None: there is none)."""
    return next((i for i, line in enumerate(lines) if line.strip() and not line.lstrip().startswith("#")), None)


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def write_xyz(cloud: PointCloud, path: Path, suffix: str) -> None:
    columns = [cloud.points]
    header = ""
    if suffix == ".xyzn":
        if cloud.normals is None:
            raise CloudFileError(f"{path}: the cloud has no normals for an .xyzn file")
        columns.append(cloud.normals)
    elif suffix == ".xyzrgb":
        if cloud.colors is None:
            raise CloudFileError(f"{path}: the cloud has no colours for an .xyzrgb file")
        columns.append(cloud.colors)
    elif suffix == ".pts":
        header = str(len(cloud))
        if cloud.colors is not None:
            columns.append(byte_colors(cloud).astype(np.float64))
    np.savetxt(path, np.hstack(columns), fmt="%.17g", header=header, comments="")
