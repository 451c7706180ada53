"""PLY point clouds: reading (ascii, binary little and big endian) and writing.

Read by our own numpy code: the header is parsed, a structured dtype is built from it, and the vertex block
is read in one ``np.fromfile`` (open3d is not imported: its import alone costs 0.7 s). Any scalar vertex
properties are accepted; x y z are required, nx ny nz and red green blue (or diffuse_red ..) are used.
Elements before the vertices are skipped (in a binary file, only those whose rows have a fixed size). What
the header claims is checked against the file before anything is allocated (``cloudtable``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimation import tolerances as tol
from estimation.cloud import PointCloud
from estimation.cloudtable import (
    MAX_HEADER_BYTES,
    Columns,
    byte_colors,
    check_binary_size,
    check_max_points,
    check_row_widths,
    check_text_size,
    columns_from,
    header_count,
    header_lines,
    parse_numbers,
    read_binary_rows,
    read_head,
    read_rows,
    text_body,
    write_table,
)
from estimation.errors import CloudFileError

log = logging.getLogger(__name__)

#: PLY scalar type names (both spellings the spec allows) -> numpy type codes without byte order.
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
_PLY_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}
#: Colour properties are ``red green blue``, or the same with one of these prefixes (:func:`_ply_color_names`).
_COLOR_PREFIXES = ("", "diffuse_")
#: The vertex properties read; a binary body's others are skipped as it is read.
_USED = ("x", "y", "z", "nx", "ny", "nz", *(f"{p}{c}" for p in _COLOR_PREFIXES for c in ("red", "green", "blue")))


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
    found = header_lines(head, lambda line: line == "end_header")
    if found is None:
        where = "the file" if len(head) < MAX_HEADER_BYTES else f"the first {MAX_HEADER_BYTES} bytes"
        raise CloudFileError(f"{path}: the PLY header has no end_header line in {where}")
    lines, offset = found
    fmt = None
    elements: list[_PlyElement] = []
    # Names seen, as sets: a 1 MB header of 75,000 element (or property) lines, each compared with every one
    # before it, kept the parser busy for minutes.
    element_names: set[str] = set()
    prop_names: set[str] = set()
    for line in lines[1:-1]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        key = words[0]
        if key == "format" and len(words) >= 2:
            if fmt is not None:  # the last line won: "ascii" then "binary_little_endian" read text as floats
                raise CloudFileError(f"{path}: the PLY header has a format line twice")
            if words[1] not in _PLY_FORMATS:
                raise CloudFileError(f"{path}: unknown PLY format {words[1][:40]!r}; use one of {list(_PLY_FORMATS)}")
            fmt = words[1]
        elif key == "element" and len(words) == 3:
            if words[1] in element_names:  # the second block of vertices was skipped in silence
                raise CloudFileError(f"{path}: the PLY header declares element {words[1][:40]!r} twice")
            element_names.add(words[1])
            prop_names = set()
            elements.append(_PlyElement(words[1], header_count(path, words[2], f"element {words[1][:40]!r}"), [], {}))
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
            if name in prop_names:
                raise CloudFileError(f"{path}: PLY element {element.name!r} has property {name!r} twice")
            prop_names.add(name)
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


def read_ply(path: Path, max_points: int) -> Columns:
    head, size = read_head(path)
    fmt, elements, offset = _parse_ply_header(path, head)
    index = next((i for i, e in enumerate(elements) if e.name == "vertex"), None)
    if index is None:
        raise CloudFileError(f"{path}: the PLY header has no vertex element")
    vertex = elements[index]
    names = [name for name, _ in vertex.props]
    listed = [axis for axis in "xyz" if axis in vertex.lists]
    if listed:  # it was "has no x property (has ['x', 'y', 'z'])"
        raise CloudFileError(f"{path}: the PLY vertex property {'/'.join(listed)} is a list property, not a number "
                             f"(x, y and z are scalar properties, e.g. 'property float x')")
    missing = [axis for axis in "xyz" if axis not in names]
    if missing:
        raise CloudFileError(f"{path}: the PLY vertex element has no {'/'.join(missing)} property (has {names})")
    check_max_points(path, vertex.count, max_points)
    order = _PLY_FORMATS[fmt]
    if order is None:
        table, types = _read_ply_ascii(path, size, offset, elements, index, head[:offset].count(b"\n") + 1)
    else:
        _check_binary_body(path, size, offset, elements, fmt)
        table, types = _read_ply_binary(path, size, offset, elements, index, order)
    faces = sum(e.count for e in elements if e.name == "face")
    if faces and vertex.count < tol.MIN_POINTS:
        # A CAD or modelling export: its few corners are no scan of the surface.
        raise CloudFileError(f"{path}: a mesh of {vertex.count} vertices and {faces} faces, not a point cloud (need at "
                             f"least {tol.MIN_POINTS} points): sample its surface, e.g. trimesh.sample.sample_surface")
    if faces:
        # A scan exported as a mesh has its vertices spread over the surface; a modelled one has them where its
        # corners and curves are, none on its flat faces (a mug of 1,338 vertices came out -79 %, told only that
        # its cloud was in three parts). Which one this is, the vertices alone do not say.
        log.warning("%s: a mesh of %d vertices and %d faces: its faces are ignored and its vertices taken as the "
                    "points, which sample a modelled mesh's surface unevenly (none on its flat faces); sample its "
                    "surface instead (e.g. trimesh.sample.sample_surface) unless it is a dense scan", path,
                    vertex.count, faces)
    return columns_from(table, types, normals=("nx", "ny", "nz"), colors=_ply_color_names(names))


def _ply_color_names(names: list[str]) -> tuple[str, str, str]:
    for prefix in _COLOR_PREFIXES:
        triple = (f"{prefix}red", f"{prefix}green", f"{prefix}blue")
        if all(name in names for name in triple):
            return triple
    return ("red", "green", "blue")


def _check_binary_body(path: Path, size: int, offset: int, elements: list[_PlyElement], fmt: str) -> None:
    """Refuse a body of text under a binary ``fmt``: its size is not the one the header's elements give (or they
    do not give one: list properties) and its first bytes are numbers, spaces and line ends. Read as binary, such
    a file was "coordinates reach 5.47e+22 m ... 1 far point(s)".

    Raises:
        CloudFileError: naming the format the header says.
    """
    dtypes = [e.dtype("<") for e in elements]
    if all(d is not None for d in dtypes):
        if size == offset + sum(e.count * d.itemsize for e, d in zip(elements, dtypes, strict=True)):  # type: ignore[union-attr]
            return
    if text_body(path, offset):
        raise CloudFileError(f"{path}: the body looks like ASCII text but the header says {fmt}: if it is text, the "
                             f"format line is 'format ascii 1.0'")


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
    check_binary_size(path, size, offset, vertex.count, dtype.itemsize, "vertices")
    end = offset + vertex.count * dtype.itemsize
    after = [e.dtype(order) for e in elements[index + 1 :]]
    if all(d is not None for d in after):
        expected = end + sum(e.count * d.itemsize for e, d in zip(elements[index + 1 :], after, strict=True))  # type: ignore[union-attr]
        if size != expected:
            log.warning(
                "%s: the header accounts for %d bytes but the file has %d; read the %d vertices only",
                path, expected, size, vertex.count,
            )  # fmt: skip
    table = read_binary_rows(path, dtype, vertex.count, offset, _USED)
    if len(table) != vertex.count:  # the file shrank since we measured it
        raise CloudFileError(f"{path}: truncated: claims {vertex.count} vertices, read {len(table)}")
    return table, {name: table.dtype.fields[name][0] for name in table.dtype.names}  # type: ignore[index]


def _read_ply_ascii(
    path: Path, size: int, offset: int, elements: list[_PlyElement], index: int, first_line: int
) -> tuple[dict[str, np.ndarray], dict[str, np.dtype]]:
    """The vertex element ``elements[index]`` of the text from ``offset``, the file's line ``first_line``."""
    vertex = elements[index]
    if vertex.lists:
        raise CloudFileError(f"{path}: the PLY vertex element has list properties {sorted(vertex.lists)}; not supported")
    nprops = len(vertex.props)
    skip = sum(e.count for e in elements[:index])
    check_text_size(path, size, offset, vertex.count, nprops, "vertices")
    rows, trailing = read_rows(path, offset, skip + vertex.count, nprops)
    present = len(rows) - (bool(rows) and not rows[-1])  # the lines after the header; not the empty one past the end
    seen = 0
    for before in elements[:index]:
        seen += before.count
        if seen > present:  # else it was "claims 3000 vertices but the file holds 0" for a face count of 1e15
            raise CloudFileError(f"{path}: truncated: PLY element {before.name!r} ({before.count} rows) before the "
                                 f"vertices runs past the end of the file ({present} lines after the header)")
    lines = rows[skip : skip + vertex.count]
    check_row_widths(path, lines, vertex.count, nprops, first_line + skip, "vertices",
                     "the vertex element's properties")
    values = parse_numbers(b" ".join(lines))
    if len(elements) == index + 1 and trailing:
        log.warning("%s: text after the %d vertices the header claims; ignored", path, vertex.count)
    table = values.reshape(vertex.count, nprops)
    _check_integers(path, table, vertex.props, lines, first_line + skip)
    structured = {name: table[:, i] for i, (name, _) in enumerate(vertex.props)}
    types = {name: np.dtype(code) for name, code in vertex.props}  # type: ignore[arg-type]
    return structured, types


def _check_integers(path: Path, table: np.ndarray, props: list[tuple[str, str | None]], lines: list[bytes],
                    first_line: int) -> None:
    """Raise on the first value of ``table`` ((n, properties) float64, as read from ``lines``, the file's from
    ``first_line``) that its integer property's type cannot hold: a uchar x of -250 and an int x of 0.0068 were
    taken as written.

    Raises:
        CloudFileError: the value, its line and its property's type.
    """
    bad_row, bad_col = len(table), 0
    for col, (_, code) in enumerate(props):
        dtype = np.dtype(code)
        if dtype.kind in "iu":
            info = np.iinfo(dtype)
            values = table[:bad_row, col]
            with np.errstate(invalid="ignore"):  # NaN fits no integer: refused as not whole
                fits = (values == np.round(values)) & (values >= info.min) & (values <= info.max)
            if not fits.all():
                bad_row, bad_col = int(np.argmin(fits)), col
    if bad_row < len(table):
        name, dtype = props[bad_col][0], np.dtype(props[bad_col][1])
        token = lines[bad_row].split()[bad_col].decode("latin-1")[:40]
        raise CloudFileError(f"{path}: line {first_line + bad_row}: {token!r} does not fit the vertex property {name!r} "
                             f"({dtype.name}: whole numbers {np.iinfo(dtype).min} to {np.iinfo(dtype).max})")


def write_ply(cloud: PointCloud, path: Path, *, ascii: bool) -> None:
    fields = [("x", "f8"), ("y", "f8"), ("z", "f8")]
    columns = [cloud.points]
    if cloud.normals is not None:
        fields += [("nx", "f8"), ("ny", "f8"), ("nz", "f8")]
        columns.append(cloud.normals)
    if cloud.colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        columns.append(byte_colors(cloud))
    ply_names = {"f8": "double", "u1": "uchar"}
    header = [
        "ply",
        f"format {'ascii' if ascii else 'binary_little_endian'} 1.0",
        "comment written by tactile-twin",
        f"element vertex {len(cloud)}",
        *(f"property {ply_names[code]} {name}" for name, code in fields),
        "end_header",
    ]
    write_table(path, header, fields, columns, ascii=ascii)
