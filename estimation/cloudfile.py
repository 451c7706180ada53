"""Reading and writing point-cloud files.

PLY (ascii, binary little and big endian) and PCD (ascii, binary) are read by our own numpy code: the
header is parsed, a structured dtype is built from it, and the vertex block is read in one
``np.fromfile``. Open3d is not imported on the read path (its import alone costs 0.7 s); it is only the
fallback for PCD ``binary_compressed`` (LZF), after our header checks passed. XYZ-family and TXT/CSV
files go through ``numpy.loadtxt`` (a header row of column names, as pandas and CloudCompare write one,
picks the columns by name), NPY/NPZ through numpy.

Every reader checks what the header claims against the file before it allocates: the point count against
``max_points`` and, for binary data, the exact byte size (for text, at least one short line a point).
A file that claims more points than it holds is a :class:`CloudFileError` naming the claimed and the
present counts, never a cloud padded with points at the origin.

Sensor origins: a PCD ``VIEWPOINT tx ty tz qw qx qy qz`` becomes the cloud's single sensor origin
``(tx, ty, tz)``, read as the sensor's position in the points' own frame (as PCL's range-image code and
octomap use ``sensor_origin_``; the rotation does not move an origin and is not kept). The format's
default ``VIEWPOINT 0 0 0 1 0 0 0`` is what every writer puts there when it knows nothing, so it is read
as "no viewpoint" (None), not as a sensor at the origin; a sensor that is at the origin is written with the
quaternion's w = -1 (the same rotation) so that it reads back.

Writing refuses to lose data: a field the chosen format cannot keep (normals in .xyz, sensor origins in .ply)
is an error naming the formats that keep it, unless the caller names it in ``save_cloud(..., drop=...)``.
"""

from __future__ import annotations

import codecs
import logging
import stat
import tokenize
import warnings
import zipfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import BinaryIO

import numpy as np

from estimation import tolerances as tol
from estimation.cloud import PointCloud, check_is_cloud, is_single_origin, make_cloud
from estimation.contracts import unit_quaternion
from estimation.errors import CloudError, CloudFileError

log = logging.getLogger(__name__)

PLY_SUFFIXES = {".ply"}
PCD_SUFFIXES = {".pcd"}
XYZ_SUFFIXES = {".xyz", ".xyzn", ".xyzrgb", ".pts"}
NUMPY_SUFFIXES = {".npy", ".npz"}
TEXT_SUFFIXES = {".txt", ".csv", ".asc"}
SUFFIXES = PLY_SUFFIXES | PCD_SUFFIXES | XYZ_SUFFIXES | NUMPY_SUFFIXES | TEXT_SUFFIXES
#: Kept for callers of the old name: the suffixes open3d used to read. Only compressed PCD still goes there.
OPEN3D_SUFFIXES = PLY_SUFFIXES | PCD_SUFFIXES | XYZ_SUFFIXES

#: Default cap on the points a file may claim. 50 M points are 1.2 GB of float64 xyz (3.6 GB with normals
#: and colours) before any estimation work: above any one-object scan we take (a 4K depth frame is 8.3 M
#: points), and about what the few-GB machines we run on can still hold. Raise it with ``max_points``.
MAX_POINTS = 50_000_000

#: Headers longer than this are not searched for their end. Real PLY/PCD headers are under 1 KB even with
#: comments; the bound keeps a large non-cloud file with a cloud suffix from being scanned whole.
MAX_HEADER_BYTES = 1 << 20

#: PLY scalar type names (both spellings the spec allows) -> numpy type codes without byte order.
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
_PLY_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}
#: PCD (TYPE, SIZE) -> numpy type code. PCD binary data is little endian (PCL writes x86 memory).
_PCD_TYPES = {
    ("I", 1): "i1", ("U", 1): "u1", ("I", 2): "i2", ("U", 2): "u2", ("I", 4): "i4", ("U", 4): "u4",
    ("I", 8): "i8", ("U", 8): "u8", ("F", 4): "f4", ("F", 8): "f8",
}  # fmt: skip
#: Most values one PCD field may hold per point (its COUNT): PCL's widest descriptor, VFH, holds 308.
MAX_PCD_COUNT = 4096

_PCD_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA")
#: A PCD's x y z are written as float32 (F 4, what PCL's point types hold) unless that moves a point by more
#: than this, metres: a micrometre, far below any depth sensor's noise. float32 keeps it within 16 m of the
#: origin; a scan in a site's frame 100 m out would lose 4 um, at 10 km 0.5 mm.
PCD_FLOAT32_ERROR_M = 1e-6
#: The PCD format's default VIEWPOINT (no translation, identity rotation w x y z): "no viewpoint known".
_DEFAULT_VIEWPOINT = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
#: The shortest text a point can take: one digit and one separator per value ("0 0 0\n").
_MIN_TEXT_BYTES_PER_VALUE = 2


@dataclass(frozen=True)
class _Columns:
    """What a reader found, in file units; make_cloud cleans and scales it."""

    points: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    sensor_origins: np.ndarray | None = None


def load_cloud(path: str | Path, *, scale: float = 1.0, max_points: int = MAX_POINTS) -> PointCloud:
    """Read a cloud file into a :class:`PointCloud` in metres.

    Args:
        path: a .ply, .pcd, .xyz/.xyzn/.xyzrgb/.pts, .npy, .npz, or .txt/.csv/.asc file.
        scale: metres per file unit (0.001 for a file in millimetres); applied to sensor origins too.
        max_points: refuse files that claim more points than this, before allocating anything.

    Returns:
        The cloud; ``sensor_origins`` is set from a non-default PCD VIEWPOINT or an .npz
        ``sensor_origins`` array.

    Raises:
        CloudFileError: missing, a directory, empty, unreadable, unknown format, a malformed header, more
            points claimed than the file holds, or more than ``max_points``.
        CloudError: the file holds no usable points.
    """
    path = Path(path)
    check_input_file(path)
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise CloudFileError(f"{path}: unknown cloud format {suffix!r}; use one of {sorted(SUFFIXES)}")
    try:
        if path.stat().st_size == 0:
            raise CloudFileError(f"{path}: the file is empty (0 bytes)")
        if suffix in PLY_SUFFIXES:
            cols = _read_ply(path, max_points)
        elif suffix in PCD_SUFFIXES:
            cols = _read_pcd(path, max_points)
        elif suffix in NUMPY_SUFFIXES:
            cols = _read_numpy(path, max_points)
        else:
            cols = _read_text(path, max_points)
    except CloudFileError:
        raise
    except (OSError, ValueError, KeyError, EOFError, OverflowError, zipfile.BadZipFile) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise CloudFileError(f"{path}: unreadable ({reason})") from exc
    return make_cloud(
        cols.points, cols.normals, cols.colors, scale=scale, sensor_origins=cols.sensor_origins, copy=False
    )


def check_input_file(path: Path) -> None:
    """Raise unless ``path`` is an existing regular file whose metadata can be read.

    Raises:
        CloudFileError: a directory, missing, not a regular file (a FIFO, a device), or any OS error on
            the way (a name too long, a permission denied on a folder, a loop of links):
            ``cannot read PATH: reason``.
    """
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise CloudFileError(f"{path}: no such file") from None
    except OSError as exc:
        raise CloudFileError(f"cannot read {path}: {exc.strerror or exc}") from None
    if stat.S_ISDIR(mode):
        raise CloudFileError(f"{path}: is a directory, not a cloud file")
    if not stat.S_ISREG(mode):
        raise CloudFileError(f"{path}: not a regular file")


#: What each format :func:`save_cloud` writes keeps besides x y z: PointCloud fields, and "per-point
#: sensor_origins" for origins that differ from point to point (a PCD's VIEWPOINT is one origin). No format keeps
#: ``dropped_nonfinite``: it counts rows that are already gone, not data the cloud holds.
WRITE_HOLDS: dict[str, frozenset[str]] = {
    ".npz": frozenset({"normals", "colors", "sensor_origins", "per-point sensor_origins"}),
    ".pcd": frozenset({"normals", "colors", "sensor_origins"}),
    ".ply": frozenset({"normals", "colors"}),
    ".npy": frozenset({"normals"}),
    ".xyzn": frozenset({"normals"}),
    ".xyzrgb": frozenset({"colors"}),
    ".pts": frozenset({"colors"}),
    ".xyz": frozenset(),
}
#: The fields ``save_cloud(..., drop=...)`` may leave out, in the order messages name them.
DROPPABLE = ("normals", "colors", "sensor_origins")


def save_cloud(cloud: PointCloud, path: str | Path, *, ascii: bool = False,
               drop: str | Iterable[str] = ()) -> None:
    """Write ``cloud`` (metres) to a file; the suffix picks the format.

    .ply: binary little endian (x y z nx ny nz as double, red green blue as uchar). .pcd: binary, x y z
    normal_x.. as F 4 and packed ``rgb`` (what PCL's point types hold), with VIEWPOINT when the cloud has a
    single sensor origin; x y z as F 8 instead when float32 would move a point by more than
    ``PCD_FLOAT32_ERROR_M`` (coordinates beyond about 16 m). .npz keeps everything, sensor origins included;
    .npy holds x y z [nx ny nz]; .xyz x y z, .xyzn x y z nx ny nz, .xyzrgb x y z r g b, .pts a count then x y z
    [r g b], all as text. ``WRITE_HOLDS`` says which fields each keeps.

    A cloud holding what the format cannot keep is refused, naming what would be lost and the formats that keep
    it, unless ``drop`` names those fields: leaving data out is the caller's decision, never a silent one.

    Args:
        cloud: the cloud to write.
        path: the file to create or overwrite.
        ascii: write .ply or .pcd as text instead of binary.
        drop: fields to leave out of the file, one name or several of ``DROPPABLE`` ("normals", "colors",
            "sensor_origins"); whatever the format could keep, a named field is not written.

    Raises:
        TypeError: ``cloud`` is not a PointCloud.
        CloudError: ``drop`` names something that is not one of ``DROPPABLE``.
        CloudFileError: an unwritable path, a format we do not write, .xyzn/.xyzrgb without the normals or
            colours they hold, or fields the format cannot keep that ``drop`` does not name.
    """
    check_is_cloud(cloud, "save_cloud")
    names = {drop} if isinstance(drop, str) else set(drop)
    unknown = sorted(names - set(DROPPABLE))
    if unknown:
        raise CloudError(f"drop: {unknown[0]!r} is not a field a file can leave out; name some of "
                         f"{', '.join(sorted(DROPPABLE))}")
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in WRITE_HOLDS:
        raise CloudFileError(f"{path}: cannot write format {suffix!r}")
    dropped = {name: None for name in names if getattr(cloud, name) is not None}
    if dropped:
        cloud = replace(cloud, **dropped)
    contents = _contents(cloud)
    lost = [what for what in contents if what not in WRITE_HOLDS[suffix]]
    if lost:
        keep = sorted(fmt for fmt, holds in WRITE_HOLDS.items() if holds.issuperset(contents))
        fields = sorted({what.removeprefix("per-point ") for what in lost})
        raise CloudFileError(f"{path}: a {suffix} file cannot hold the cloud's {_listed(lost, 'and')} "
                             f"({_listed(keep, 'or')} can; pass drop={{{', '.join(map(repr, fields))}}} to write it "
                             f"without them)")
    try:
        if suffix == ".npz":
            arrays = {"points": cloud.points}
            if cloud.normals is not None:
                arrays["normals"] = cloud.normals
            if cloud.colors is not None:
                arrays["colors"] = cloud.colors
            if cloud.sensor_origins is not None:
                origins = cloud.sensor_origins
                arrays["sensor_origins"] = origins[0] if is_single_origin(origins) else origins
            np.savez(path, **arrays)
        elif suffix == ".npy":
            cols = [cloud.points] + ([cloud.normals] if cloud.normals is not None else [])
            np.save(path, np.hstack(cols))
        elif suffix in PLY_SUFFIXES:
            _write_ply(cloud, path, ascii=ascii)
        elif suffix in PCD_SUFFIXES:
            _write_pcd(cloud, path, ascii=ascii)
        else:
            _write_xyz(cloud, path, suffix)
    except OSError as exc:
        if isinstance(exc, CloudFileError):
            raise
        raise CloudFileError(f"{path}: could not write ({exc.strerror or exc})") from exc


def _contents(cloud: PointCloud) -> list[str]:
    """What ``cloud`` holds besides x y z, as ``WRITE_HOLDS`` names it, in ``DROPPABLE``'s order."""
    held = [name for name in DROPPABLE if getattr(cloud, name) is not None and len(getattr(cloud, name))]
    if "sensor_origins" in held and _one_origin(cloud.sensor_origins) is None:  # type: ignore[arg-type]
        held = [("per-point sensor_origins" if name == "sensor_origins" else name) for name in held]
    return held


def _one_origin(origins: np.ndarray) -> np.ndarray | None:
    """The one sensor origin ((3,) metres) every row of ``origins`` ((n, 3), n > 0) holds, or None if they differ."""
    if is_single_origin(origins) or (origins == origins[0]).all():
        return origins[0]
    return None


def _listed(items: list[str], last: str) -> str:
    """'a', 'a and b', 'a, b and c' (``last`` the word before the last item)."""
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} {last} {items[-1]}"


# --- headers -----------------------------------------------------------------------------------------


def _read_head(path: Path) -> tuple[bytes, int]:
    """The file's first bytes (up to MAX_HEADER_BYTES) and its size."""
    size = path.stat().st_size
    with path.open("rb") as fh:
        return fh.read(min(size, MAX_HEADER_BYTES)), size


def _header_lines(head: bytes, is_last: Callable[[str], bool]) -> tuple[list[str], int] | None:
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


def _count(path: Path, text: str, what: str) -> int:
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


def _check_max(path: Path, claimed: int, max_points: int) -> None:
    if claimed > max_points:
        raise CloudFileError(
            f"{path}: the header claims {claimed} points, more than max_points={max_points} "
            "(pass a larger max_points to load_cloud if the file is real)"
        )


def _check_binary_size(path: Path, size: int, offset: int, claimed: int, itemsize: int, what: str) -> None:
    """Raise unless ``claimed`` records of ``itemsize`` bytes fit between ``offset`` and the end."""
    available = max(0, size - offset)
    if claimed * itemsize > available:
        raise CloudFileError(
            f"{path}: truncated: the header claims {claimed} {what} but the file holds "
            f"{available // itemsize} ({available} bytes after the header, {itemsize} bytes each)"
        )


def _check_text_size(path: Path, size: int, offset: int, claimed: int, values: int, what: str) -> None:
    """Raise when fewer bytes follow the header than the shortest text ``claimed`` rows could take."""
    available = max(0, size - offset)
    least = claimed * values * _MIN_TEXT_BYTES_PER_VALUE
    if least > available:
        raise CloudFileError(
            f"{path}: truncated: the header claims {claimed} {what} of {values} values, which need at least "
            f"{least} bytes, but {available} follow the header"
        )


def _parse_numbers(text: bytes) -> np.ndarray:
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


# --- PLY ---------------------------------------------------------------------------------------------


@dataclass
class _PlyElement:
    name: str
    count: int
    #: (name, type code) for scalars; (name, None) for list properties.
    props: list[tuple[str, str | None]]
    #: (count type, item type) of each list property, by name; a list's size per element is only known
    #: when reading it.
    lists: dict[str, tuple[str, str]]

    def dtype(self, order: str) -> np.dtype | None:
        """The record dtype, or None when a list property makes the size vary."""
        if self.lists:
            return None
        return np.dtype([(name, order + code) for name, code in self.props])  # type: ignore[operator]


def _parse_ply_header(path: Path, head: bytes) -> tuple[str, list[_PlyElement], int]:
    if head.startswith(b"ply\r") and not head.startswith(b"ply\r\n"):
        raise CloudFileError(f"{path}: the PLY header's lines end in a carriage return alone (an old Mac "
                             f"convention); PLY lines end in a line feed")
    if not (head.startswith(b"ply\n") or head.startswith(b"ply\r\n")):
        raise CloudFileError(f"{path}: not a PLY file (it starts with {head[:16]!r}, not 'ply')")
    found = _header_lines(head, lambda line: line == "end_header")
    if found is None:
        where = "the file" if len(head) < MAX_HEADER_BYTES else f"the first {MAX_HEADER_BYTES} bytes"
        raise CloudFileError(f"{path}: the PLY header has no end_header line in {where}")
    lines, offset = found
    fmt = None
    elements: list[_PlyElement] = []
    for line in lines[1:-1]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        key = words[0]
        if key == "format" and len(words) >= 2:
            if words[1] not in _PLY_FORMATS:
                raise CloudFileError(f"{path}: unknown PLY format {words[1][:40]!r}; use one of {list(_PLY_FORMATS)}")
            fmt = words[1]
        elif key == "element" and len(words) == 3:
            elements.append(_PlyElement(words[1], _count(path, words[2], f"element {words[1][:40]!r}"), [], {}))
        elif key == "property" and len(words) >= 3:
            if not elements:
                raise CloudFileError(f"{path}: PLY property before any element: {line[:60]!r}")
            element = elements[-1]
            if words[1] == "list" and len(words) == 5:
                types = [_ply_type(path, t) for t in words[2:4]]
                name = words[4]
                element.lists[name] = (types[0], types[1])
                code = None
            elif words[1] != "list" and len(words) == 3:
                code, name = _ply_type(path, words[1]), words[2]
            else:
                raise CloudFileError(f"{path}: malformed PLY property line {line[:60]!r}")
            if any(name == other for other, _ in element.props):
                raise CloudFileError(f"{path}: PLY element {element.name!r} has property {name!r} twice")
            element.props.append((name, code))
        else:
            raise CloudFileError(f"{path}: unexpected PLY header line {line[:60]!r}")
    if fmt is None:
        raise CloudFileError(f"{path}: the PLY header has no format line")
    return fmt, elements, offset


def _ply_type(path: Path, name: str) -> str:
    try:
        return _PLY_TYPES[name]
    except KeyError:
        raise CloudFileError(
            f"{path}: unknown PLY property type {name[:40]!r}; use one of {sorted(set(_PLY_TYPES))}"
        ) from None


def _read_ply(path: Path, max_points: int) -> _Columns:
    head, size = _read_head(path)
    fmt, elements, offset = _parse_ply_header(path, head)
    index = next((i for i, e in enumerate(elements) if e.name == "vertex"), None)
    if index is None:
        raise CloudFileError(f"{path}: the PLY header has no vertex element")
    vertex = elements[index]
    names = [name for name, _ in vertex.props]
    missing = [axis for axis in "xyz" if axis not in names or axis in vertex.lists]
    if missing:
        raise CloudFileError(f"{path}: the PLY vertex element has no {'/'.join(missing)} property (has {names})")
    _check_max(path, vertex.count, max_points)
    order = _PLY_FORMATS[fmt]
    if order is None:
        table, types = _read_ply_ascii(path, size, offset, elements, index)
    else:
        table, types = _read_ply_binary(path, size, offset, elements, index, order)
    faces = sum(e.count for e in elements if e.name == "face")
    if faces and vertex.count < tol.MIN_POINTS:
        # A CAD or modelling export: its few corners are no scan of the surface.
        raise CloudFileError(f"{path}: a mesh of {vertex.count} vertices and {faces} faces, not a point cloud (need at "
                             f"least {tol.MIN_POINTS} points): sample its surface, e.g. trimesh.sample.sample_surface")
    return _columns_from(table, types, normals=("nx", "ny", "nz"), colors=_ply_color_names(names))


def _ply_color_names(names: list[str]) -> tuple[str, str, str]:
    for prefix in ("", "diffuse_"):
        triple = (f"{prefix}red", f"{prefix}green", f"{prefix}blue")
        if all(name in names for name in triple):
            return triple
    return ("red", "green", "blue")


def _read_ply_binary(
    path: Path, size: int, offset: int, elements: list[_PlyElement], index: int, order: str
) -> tuple[np.ndarray, dict[str, np.dtype]]:
    for before in elements[:index]:
        dtype = before.dtype(order)
        if dtype is None:
            raise CloudFileError(
                f"{path}: cannot skip PLY element {before.name!r} (list properties) before the vertex element"
            )
        offset += before.count * dtype.itemsize
        if offset > size:  # checked here: past the file, the offset is no position a read can take
            raise CloudFileError(f"{path}: truncated: PLY element {before.name!r} ({before.count} rows) before the "
                                 f"vertices claims more bytes than the file's {size}")
    vertex = elements[index]
    dtype = vertex.dtype(order)
    if dtype is None:
        raise CloudFileError(f"{path}: the PLY vertex element has list properties {sorted(vertex.lists)}; not supported")
    _check_binary_size(path, size, offset, vertex.count, dtype.itemsize, "vertices")
    end = offset + vertex.count * dtype.itemsize
    after = [e.dtype(order) for e in elements[index + 1 :]]
    if all(d is not None for d in after):
        expected = end + sum(e.count * d.itemsize for e, d in zip(elements[index + 1 :], after, strict=True))  # type: ignore[union-attr]
        if size != expected:
            log.warning(
                "%s: the header accounts for %d bytes but the file has %d; read the %d vertices only",
                path, expected, size, vertex.count,
            )  # fmt: skip
    table = np.fromfile(path, dtype=dtype, count=vertex.count, offset=offset)
    if len(table) != vertex.count:  # the file shrank since we measured it
        raise CloudFileError(f"{path}: truncated: claims {vertex.count} vertices, read {len(table)}")
    return table, {name: dtype.fields[name][0] for name in dtype.names}  # type: ignore[index]


def _read_ply_ascii(
    path: Path, size: int, offset: int, elements: list[_PlyElement], index: int
) -> tuple[dict[str, np.ndarray], dict[str, np.dtype]]:
    vertex = elements[index]
    if vertex.lists:
        raise CloudFileError(f"{path}: the PLY vertex element has list properties {sorted(vertex.lists)}; not supported")
    nprops = len(vertex.props)
    skip = sum(e.count for e in elements[:index])
    _check_text_size(path, size, offset, vertex.count, nprops, "vertices")
    with path.open("rb") as fh:
        fh.seek(offset)
        body = fh.read()
    rows = body.split(b"\n", skip + vertex.count)
    lines = rows[skip : skip + vertex.count]
    if len(lines) < vertex.count or (lines and not lines[-1].strip()):
        present = sum(1 for line in lines if line.strip())
        raise CloudFileError(f"{path}: truncated: the header claims {vertex.count} vertices but the file holds {present}")
    values = _parse_numbers(b" ".join(lines))
    if values.size != vertex.count * nprops:
        raise CloudFileError(
            f"{path}: the {vertex.count} vertex lines hold {values.size} values, not {vertex.count} x {nprops} "
            "properties (truncated or malformed)"
        )
    if len(elements) == index + 1 and len(rows) > skip + vertex.count and rows[-1].strip():
        log.warning("%s: text after the %d vertices the header claims; ignored", path, vertex.count)
    table = values.reshape(vertex.count, nprops)
    structured = {name: table[:, i] for i, (name, _) in enumerate(vertex.props)}
    types = {name: np.dtype(code) for name, code in vertex.props}  # type: ignore[arg-type]
    return structured, types


def _columns_from(
    table: np.ndarray | dict[str, np.ndarray],
    types: dict[str, np.dtype],
    *,
    normals: tuple[str, str, str],
    colors: tuple[str, str, str] | None,
    sensor_origins: np.ndarray | None = None,
) -> _Columns:
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
    return _Columns(points, nrm, col, sensor_origins)


# --- PCD ---------------------------------------------------------------------------------------------


def _read_pcd(path: Path, max_points: int) -> _Columns:
    head, size = _read_head(path)
    found = _header_lines(head, lambda line: line.upper().startswith("DATA"))
    if found is None:
        raise CloudFileError(f"{path}: not a PCD file (no DATA line in its header)")
    lines, offset = found
    header: dict[str, list[str]] = {}
    for line in lines:
        if not line or line.startswith("#"):
            continue
        words = line.split()
        key = words[0].upper()
        if key not in _PCD_KEYS:
            raise CloudFileError(f"{path}: not a PCD file (unexpected header line {line[:60]!r})")
        header[key] = words[1:]
    for key in ("FIELDS", "SIZE", "TYPE"):
        if key not in header:
            raise CloudFileError(f"{path}: the PCD header has no {key} line")
    fields = header["FIELDS"]
    sizes = [_count(path, s, "SIZE") for s in header["SIZE"]]
    kinds = [t.upper() for t in header["TYPE"]]
    counts = [_count(path, c, "COUNT") for c in header.get("COUNT", ["1"] * len(fields))]
    if not len(fields) == len(sizes) == len(kinds) == len(counts):
        raise CloudFileError(
            f"{path}: the PCD header lists {len(fields)} FIELDS but {len(sizes)} SIZE, {len(kinds)} TYPE and "
            f"{len(counts)} COUNT entries"
        )
    n = _pcd_points(path, header)
    _check_max(path, n, max_points)
    names, codes = [], []
    for i, (name, kind, nbytes) in enumerate(zip(fields, kinds, sizes, strict=True)):
        code = _PCD_TYPES.get((kind, nbytes))
        if code is None:
            raise CloudFileError(f"{path}: unknown PCD field type {kind} of size {nbytes} for field {name!r}")
        names.append(f"_pad{i}" if name == "_" else name)  # PCL names padding "_", possibly many times
        codes.append(code)
    if len(set(names)) != len(names):
        raise CloudFileError(f"{path}: the PCD header names a field twice ({fields})")
    for name, k in zip(names, counts, strict=True):
        if k > MAX_PCD_COUNT:  # a COUNT of 1e19 was numpy's "invalid shape in fixed-type tuple"
            raise CloudFileError(f"{path}: the PCD field {name!r} has COUNT {k}, more than the {MAX_PCD_COUNT} values "
                                 f"a point's field may hold")
    for axis in "xyz":
        if axis not in names or counts[names.index(axis)] != 1:
            raise CloudFileError(f"{path}: the PCD file has no scalar {axis} field (has {fields})")
    for name in ("normal_x", "normal_y", "normal_z"):
        if name in names and counts[names.index(name)] != 1:
            raise CloudFileError(f"{path}: the PCD field {name!r} has COUNT {counts[names.index(name)]}; a normal's "
                                 f"fields hold one value each")
    origins = _viewpoint(path, header.get("VIEWPOINT"))
    dtype = np.dtype([(nm, "<" + c, (k,)) if k != 1 else (nm, "<" + c) for nm, c, k in zip(names, codes, counts, strict=True)])
    data = header["DATA"][0].lower() if header["DATA"] else ""
    if data == "ascii":
        table = _read_pcd_ascii(path, size, offset, n, names, counts)
    elif data == "binary":
        _check_binary_size(path, size, offset, n, dtype.itemsize, "points")
        if size != offset + n * dtype.itemsize:
            log.warning("%s: %d bytes after the %d points the header claims; ignored", path, size - offset - n * dtype.itemsize, n)
        table = np.fromfile(path, dtype=dtype, count=n, offset=offset)
        if len(table) != n:
            raise CloudFileError(f"{path}: truncated: claims {n} points, read {len(table)}")
    elif data == "binary_compressed":
        return _read_pcd_compressed(path, size, offset, n, dtype.itemsize, origins)
    else:
        raise CloudFileError(f"{path}: unknown PCD DATA kind {data[:40]!r}; use ascii, binary or binary_compressed")
    types = {nm: np.dtype(c) for nm, c in zip(names, codes, strict=True)}
    cols = _columns_from(table, types, normals=("normal_x", "normal_y", "normal_z"), colors=None, sensor_origins=origins)
    colour_field = next((f for f in ("rgb", "rgba") if f in names and counts[names.index(f)] == 1), None)
    if colour_field is not None:
        cols = _Columns(cols.points, cols.normals, _pcd_colors(table[colour_field], types[colour_field]), origins)
    return cols


def _pcd_points(path: Path, header: dict[str, list[str]]) -> int:
    width = _count(path, header["WIDTH"][0], "WIDTH") if header.get("WIDTH") else None
    height = _count(path, header["HEIGHT"][0], "HEIGHT") if header.get("HEIGHT") else 1
    if header.get("POINTS"):
        n = _count(path, header["POINTS"][0], "POINTS")
        if width is not None and width * height != n:
            log.warning("%s: PCD WIDTH x HEIGHT is %d x %d but POINTS is %d; using POINTS", path, width, height, n)
        return n
    if width is None:
        raise CloudFileError(f"{path}: the PCD header has neither POINTS nor WIDTH")
    return width * height


def _viewpoint(path: Path, words: list[str] | None) -> np.ndarray | None:
    """The sensor origin from ``VIEWPOINT tx ty tz qw qx qy qz``; None for the format's default."""
    if words is None:
        return None
    try:
        values = tuple(float(w) for w in words)
    except ValueError:
        values = ()
    if len(values) != 7 or not np.isfinite(values).all():
        raise CloudFileError(f"{path}: VIEWPOINT needs 7 finite numbers (tx ty tz qw qx qy qz), got {' '.join(words)[:80]!r}")
    if values == _DEFAULT_VIEWPOINT:
        return None
    # The rotation is not used (an origin does not turn), but a quaternion that is no rotation (zero, or
    # of norm 2: 5 5 5 5) says the header is damaged, and so may be its translation. The rule is
    # --viewpoint-pose's.
    try:
        unit_quaternion(values[3:], "VIEWPOINT's quaternion qw qx qy qz")
    except CloudError as exc:
        raise CloudFileError(f"{path}: {exc}") from None
    return np.array(values[:3])


def _read_pcd_ascii(
    path: Path, size: int, offset: int, n: int, names: list[str], counts: list[int]
) -> dict[str, np.ndarray]:
    width = sum(counts)
    _check_text_size(path, size, offset, n, width, "points")
    with path.open("rb") as fh:
        fh.seek(offset)
        values = _parse_numbers(fh.read())
    if values.size < n * width:
        raise CloudFileError(
            f"{path}: truncated: the header claims {n} points but the file holds {values.size // width}"
        )
    if values.size > n * width:
        log.warning("%s: %d values after the %d points the header claims; ignored", path, values.size - n * width, n)
    table = values[: n * width].reshape(n, width)
    starts = np.cumsum([0, *counts])
    return {name: table[:, starts[i]] for i, name in enumerate(names) if counts[i] == 1}


def _pcd_colors(packed: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """PCL packs colour as 0x00RRGGBB (or AARRGGBB) in the bits of a float32 or uint32 field."""
    if dtype.kind == "f":
        bits = np.asarray(packed, dtype=np.float32).view(np.uint32)
    else:
        # An ASCII file's integer field arrives as float64: a value no uint32 holds (NaN, negative, too large)
        # is no colour, and casting it is undefined.
        values = np.asarray(packed, dtype=np.float64)
        bits = np.where(np.isfinite(values) & (values >= 0) & (values < 2.0**32), values, 0).astype(np.uint32)
    rgb = np.stack([(bits >> shift) & 0xFF for shift in (16, 8, 0)], axis=1)
    return rgb / 255.0


def _read_pcd_compressed(
    path: Path, size: int, offset: int, n: int, itemsize: int, origins: np.ndarray | None
) -> _Columns:
    """LZF-compressed PCD: check the sizes it declares, then let open3d decompress (we carry no LZF)."""
    with path.open("rb") as fh:
        fh.seek(offset)
        sizes = np.frombuffer(fh.read(8), dtype="<u4")
    if len(sizes) != 2:
        raise CloudFileError(f"{path}: truncated: no compressed-block sizes after the PCD header")
    compressed, raw = (int(s) for s in sizes)
    if raw != n * itemsize:
        raise CloudFileError(f"{path}: the header claims {n} points ({n * itemsize} bytes) but the block unpacks to {raw}")
    if offset + 8 + compressed > size:
        raise CloudFileError(f"{path}: truncated: the compressed block is {compressed} bytes, {size - offset - 8} present")
    import open3d as o3d  # only here: its import costs 0.7 s

    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        pcd = o3d.io.read_point_cloud(str(path), format="pcd", remove_nan_points=False, remove_infinite_points=False)
    points = np.asarray(pcd.points)
    if len(points) != n:
        raise CloudFileError(f"{path}: open3d read {len(points)} of the {n} points in the compressed block")
    normals = np.asarray(pcd.normals) if pcd.has_normals() else None
    colors = np.asarray(pcd.colors) if pcd.has_colors() else None
    return _Columns(points, normals, colors, origins)


# --- numpy and text ----------------------------------------------------------------------------------


#: numpy dtype kinds a cloud or depth array may hold: signed and unsigned integers and floats. Complex
#: values would lose their imaginary part (numpy only warns), booleans, strings and records are no coordinates.
REAL_KINDS = "iuf"


def npy_header(path: Path) -> tuple[tuple[int, ...], np.dtype]:
    """The shape and dtype an .npy file's header declares, checked against the file's size; no data is read.

    Raises:
        CloudFileError: not an .npy header (or one of a format version numpy does not write), an array of
            Python objects, or fewer data bytes than the shape claims (a small file whose header claims
            (90000, 90000) would otherwise be a 60 GiB allocation).
    """
    with path.open("rb") as fh:
        shape, dtype = _read_npy_header(fh, f"{path}")
        offset = fh.tell()
    claimed = int(np.prod(shape, dtype=object)) * dtype.itemsize
    available = path.stat().st_size - offset
    if claimed > available:
        raise CloudFileError(f"{path}: truncated: the header claims shape {shape} of {dtype} ({claimed} bytes), but "
                             f"{available} bytes follow it")
    return shape, dtype


def _read_npy_header(fh: BinaryIO, where: str) -> tuple[tuple[int, ...], np.dtype]:
    """Read an .npy magic string and header from ``fh``; ``where`` names the file (and member) in errors.

    numpy's readers raise more than ValueError on a damaged header: an unknown version reached a private
    reader numpy 2 no longer has (AttributeError), and a header that is no Python literal goes through
    numpy's Python 2 fallback, which raises tokenize.TokenError or warns.
    """
    try:
        version = np.lib.format.read_magic(fh)
    except (ValueError, EOFError) as exc:
        raise CloudFileError(f"{where}: not an .npy array ({str(exc).splitlines()[0][:200]})") from None
    if version == (1, 0):
        reader = np.lib.format.read_array_header_1_0
    elif version in ((2, 0), (3, 0)):
        # 3.0 differs from 2.0 only in allowing utf-8 field names, and fields are refused anyway.
        reader = np.lib.format.read_array_header_2_0
    else:
        raise CloudFileError(f"{where}: .npy format version {version[0]}.{version[1]} is not one numpy writes "
                             "(1.0, 2.0 or 3.0)")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", UserWarning)
            shape, _, dtype = reader(fh)
    except (ValueError, EOFError, tokenize.TokenError, UserWarning) as exc:
        reason = str(exc.args[0] if exc.args else exc).splitlines()[0] or type(exc).__name__
        raise CloudFileError(f"{where}: not a readable .npy header ({reason[:200]})") from None
    if dtype.hasobject:
        raise CloudFileError(f"{where}: the array holds Python objects (pickled data), which are not read")
    if any(n < 0 for n in shape):
        raise CloudFileError(f"{where}: the .npy header declares a negative size, shape {shape}")
    return shape, dtype


def check_real(path: Path, dtype: np.dtype, what: str) -> None:
    """Raise unless ``dtype`` holds real numbers (``REAL_KINDS``)."""
    if dtype.kind not in REAL_KINDS or dtype.fields is not None:
        raise CloudFileError(f"{path}: {what} must hold real numbers (integer or float), got {dtype}")


def _read_numpy(path: Path, max_points: int) -> _Columns:
    if path.suffix.lower() == ".npy":
        # Everything is checked on the header before any data is read: a 1-D or 3-D array skipped the
        # row cap (an 800 MB (100000000,) file reached 1.6 GB before its shape was refused).
        shape, dtype = npy_header(path)
        check_real(path, dtype, "a cloud array")
        if len(shape) != 2 or shape[1] not in (3, 6, 9):
            raise CloudFileError(f"{path}: expected an (n, 3), (n, 6) or (n, 9) array (xyz, normals, colours), "
                                 f"got shape {shape}")
        _check_max(path, shape[0], max_points)
        table = np.load(path, mmap_mode="r", allow_pickle=False)
        return _Columns(*_split_columns(np.array(table)))
    with zipfile.ZipFile(path) as archive:
        names = [name for name in archive.namelist() if name.endswith(".npy")]
        if len(set(names)) != len(names):
            raise CloudFileError(f"{path}: an .npz with two members of one name (which one is read is up to the "
                                 f"zip reader)")
        # Keyed as np.load keys them (the name without '.npy', folders kept), so the member checked here is
        # the one read below: by stem, 'a/points.npy' stood for 'points' and a forged 'points.npy' went unchecked.
        members = {name.removesuffix(".npy"): name for name in names}
        if "points" not in members:
            raise CloudFileError(f"{path}: an .npz cloud needs a 'points' array (has {sorted(members)})")
        for key in ("points", "normals", "colors", "sensor_origins"):
            if key in members:
                _check_npz_member(path, archive, members[key], max_points)
        # Read from the members checked above, not through np.load's keys: a member named plain 'points' is
        # what np.load returns for 'points' first, and it went unchecked (a 2.4 MB file took 4.8 GB).
        def get(key: str) -> np.ndarray | None:
            if key not in members:
                return None
            with archive.open(members[key]) as fh:
                return np.lib.format.read_array(fh, allow_pickle=False)

        return _Columns(get("points"), get("normals"), get("colors"), get("sensor_origins"))  # type: ignore[arg-type]


def _check_npz_member(path: Path, archive: zipfile.ZipFile, name: str, max_points: int) -> None:
    """Refuse a member whose header claims more rows than allowed or more bytes than it unpacks to."""
    with archive.open(name) as fh:
        shape, dtype = _read_npy_header(fh, f"{path}: member {name!r}")
    key = name.removesuffix(".npy")
    check_real(path, dtype, f"array {key!r}")
    if key == "points" and (len(shape) != 2 or shape[1] != 3):
        raise CloudFileError(f"{path}: array {key!r} must be (n, 3), got shape {shape}")
    if shape and shape[0] > max_points:
        _check_max(path, shape[0], max_points)
    nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
    if nbytes > archive.getinfo(name).file_size:
        raise CloudFileError(f"{path}: truncated: array {key!r} claims shape {shape}, more than its data")


#: Longest line a text cloud may have, bytes: a row of nine numbers written at full precision is under 250.
MAX_TEXT_LINE = 4096


#: Bytes of a text file scanned at a time for its line lengths, before it is read whole.
TEXT_SCAN_BLOCK = 1 << 24


def _scan_text(path: Path, max_points: int) -> None:
    """Refuse a text file with a line longer than ``MAX_TEXT_LINE`` or far more than ``max_points`` lines, read
    in blocks: read whole first, a sparse 1 GB file of NUL bytes took 2.1 GB before its first line was found
    too long, and one larger than the memory would have been killed rather than refused."""
    longest, run, lines = 0, 0, 0
    with path.open("rb") as fh:
        while block := fh.read(TEXT_SCAN_BLOCK):
            raw = np.frombuffer(block, np.uint8)
            ends = np.flatnonzero((raw == 10) | (raw == 13))  # '\r' ends lines too (old Mac files)
            if not len(ends):
                run += len(raw)
                continue
            longest = max(longest, run + int(ends[0]), int(np.diff(ends).max(initial=1)) - 1)
            run = len(raw) - int(ends[-1]) - 1
            lines += len(ends)
            if lines > 2 * (max_points + 1):  # '\r\n' counts twice here; the exact count follows the read
                raise CloudFileError(f"{path}: more than max_points={max_points} lines (pass a larger max_points if real)")
    longest = max(longest, run)
    if longest > MAX_TEXT_LINE:
        # The reader keeps every line as a Python string, several times over: one 256 MB line of NUL bytes
        # took 3 GB before it was found not to be numbers.
        raise CloudFileError(f"{path}: a line of {longest:,} bytes, more than a row of numbers holds "
                             f"(at most {MAX_TEXT_LINE:,}): not a text point cloud")


def _read_text(path: Path, max_points: int) -> _Columns:
    suffix = path.suffix.lower()
    _scan_text(path, max_points)
    # A spreadsheet's CSV starts with a UTF-8 byte-order mark: "could not convert string 'ï»¿0.1'".
    text = path.read_bytes().removeprefix(codecs.BOM_UTF8)
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
    delimiter = "," if first is not None and "," in lines[first] else None
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
    if suffix in (".txt", ".csv", ".asc"):
        return _Columns(*_split_columns(table))
    need = {".xyz": 3, ".xyzn": 6, ".xyzrgb": 6, ".pts": 3}[suffix]
    if table.shape[1] < need:
        raise CloudFileError(f"{path}: a {suffix} file needs at least {need} columns, got {table.shape[1]}")
    points = table[:, :3]
    if suffix == ".xyzn":
        return _Columns(points, table[:, 3:6])
    if suffix == ".xyzrgb":
        return _Columns(points, None, table[:, 3:6])
    if suffix == ".pts" and table.shape[1] in (6, 7):  # x y z [intensity] r g b, colours 0-255
        return _Columns(points, None, table[:, -3:] / 255.0)
    return _Columns(points)


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

    def columns(self, table: np.ndarray) -> _Columns:
        """The named columns of ``table`` (colours as written: ``make_cloud`` rescales 0-255)."""
        picked = {kind: None if at is None else table[:, list(at)] for kind, at in self.found.items()}
        return _Columns(picked["points"], picked["normals"], picked["colors"])  # type: ignore[arg-type]


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
    tokens = [t.strip().strip("'\"").lower() for t in (stripped.split(",") if "," in stripped else stripped.split())]
    if any(_is_number(t) for t in tokens):
        return None
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


def _split_columns(table: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """x y z, x y z nx ny nz, x y z r g b, or x y z nx ny nz r g b."""
    if table.ndim != 2 or table.shape[1] not in (3, 6, 9):
        raise CloudFileError(f"expected 3, 6 or 9 columns (xyz, normals, colours), got shape {table.shape}")
    points = table[:, :3]
    if table.shape[1] == 3:
        return points, None, None
    if table.shape[1] == 9:
        return points, table[:, 3:6], table[:, 6:9]
    # Six columns: normals are unit length, colours are not.
    rest = table[:, 3:6]
    is_normals = np.allclose(np.linalg.norm(rest[: min(len(rest), 1000)], axis=1), 1.0, atol=1e-3)
    return (points, rest, None) if is_normals else (points, None, rest)


# --- writers -----------------------------------------------------------------------------------------


def _byte_colors(cloud: PointCloud) -> np.ndarray:
    assert cloud.colors is not None
    return np.clip(np.rint(cloud.colors * 255.0), 0, 255).astype(np.uint8)


def _write_ply(cloud: PointCloud, path: Path, *, ascii: bool) -> None:
    fields = [("x", "f8"), ("y", "f8"), ("z", "f8")]
    columns = [cloud.points]
    if cloud.normals is not None:
        fields += [("nx", "f8"), ("ny", "f8"), ("nz", "f8")]
        columns.append(cloud.normals)
    if cloud.colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        columns.append(_byte_colors(cloud))
    ply_names = {"f8": "double", "u1": "uchar"}
    header = [
        "ply",
        f"format {'ascii' if ascii else 'binary_little_endian'} 1.0",
        "comment written by tactile-twin",
        f"element vertex {len(cloud)}",
        *(f"property {ply_names[code]} {name}" for name, code in fields),
        "end_header",
    ]
    _write_table(path, header, fields, columns, ascii=ascii)


def _write_pcd(cloud: PointCloud, path: Path, *, ascii: bool) -> None:
    xyz = "f4"
    if len(cloud) and np.abs(cloud.points - cloud.points.astype(np.float32)).max() > PCD_FLOAT32_ERROR_M:
        xyz = "f8"  # PCL's PointXYZ wants F 4, but a scan's coordinates matter more than one reader's type
        log.info("%s: float32 would move points by more than %g m; x y z written as F 8", path, PCD_FLOAT32_ERROR_M)
    fields = [("x", xyz), ("y", xyz), ("z", xyz)]
    columns: list[np.ndarray] = [cloud.points]
    if cloud.normals is not None:
        fields += [("normal_x", "f4"), ("normal_y", "f4"), ("normal_z", "f4")]
        columns.append(cloud.normals)
    if cloud.colors is not None:
        rgb = _byte_colors(cloud).astype(np.uint32)
        fields.append(("rgb", "f4"))
        columns.append(((rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]).view(np.float32)[:, None])
    viewpoint = _DEFAULT_VIEWPOINT
    origins = cloud.sensor_origins  # one origin: save_cloud refused (or dropped) origins that differ
    if origins is not None and len(origins) and (origin := _one_origin(origins)) is not None:
        # w = -1 at the origin: the same (identity) rotation as w = 1, but not the default VIEWPOINT, which is
        # read as "no viewpoint": a camera-frame cloud's sensor at (0, 0, 0) was lost that way.
        w = -1.0 if not origin.any() else 1.0
        viewpoint = (*(float(v) for v in origin), w, 0.0, 0.0, 0.0)
    header = [
        "# .PCD v0.7 - Point Cloud Data file format, written by tactile-twin",
        "VERSION 0.7",
        "FIELDS " + " ".join(name for name, _ in fields),
        "SIZE " + " ".join(code[1] for _, code in fields),
        "TYPE " + " ".join("F" for _ in fields),
        "COUNT " + " ".join("1" for _ in fields),
        f"WIDTH {len(cloud)}",
        "HEIGHT 1",
        "VIEWPOINT " + " ".join(repr(v) for v in viewpoint),
        f"POINTS {len(cloud)}",
        f"DATA {'ascii' if ascii else 'binary'}",
    ]
    _write_table(path, header, fields, columns, ascii=ascii)


def _write_table(
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


def _write_xyz(cloud: PointCloud, path: Path, suffix: str) -> None:
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
            columns.append(_byte_colors(cloud).astype(np.float64))
    np.savetxt(path, np.hstack(columns), fmt="%.17g", header=header, comments="")
