"""PCD point clouds (PCL's format): reading (ascii, binary, binary_compressed) and writing.

Ascii and binary data are read by our own numpy code, as PLY is: the header is parsed, a structured dtype
is built from it, and the points are read in one ``np.fromfile``. Open3d is not imported on the read path
(its import alone costs 0.7 s); it is only the fallback for ``binary_compressed`` (LZF), after our header
checks passed. What the header claims is checked against the file before anything is allocated
(``cloudtable``).

Sensor origins: a PCD ``VIEWPOINT tx ty tz qw qx qy qz`` becomes the cloud's single sensor origin
``(tx, ty, tz)``, read as the sensor's position in the points' own frame (as PCL's range-image code and
octomap use ``sensor_origin_``; the rotation does not move an origin and is not kept). The format's
default ``VIEWPOINT 0 0 0 1 0 0 0`` is what every writer puts there when it knows nothing, so it is read
as "no viewpoint" (None), not as a sensor at the origin; a sensor that is at the origin is written with the
quaternion's w = -1 (the same rotation) so that it reads back.

PCL's ``vp_x vp_y vp_z`` fields (``pcl::PointWithViewpoint``) are each point's sensor origin, in the points'
frame and units: they become per-point sensor origins, (n, 3). A file with those fields and a non-default
VIEWPOINT says two things about where its sensors stood, and is refused rather than one of them picked.
Per-point origins are not written to PCD (``save_cloud`` refuses them; .npz keeps them).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from estimation.cloud import PointCloud, is_single_origin
from estimation.cloudtable import (
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
from estimation.contracts import unit_quaternion
from estimation.errors import CloudError, CloudFileError

log = logging.getLogger(__name__)

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
#: PCL's normal fields (pcl::Normal) and per-point viewpoint fields (pcl::PointWithViewpoint), x y z order.
_NORMAL_FIELDS = ("normal_x", "normal_y", "normal_z")
_VP_FIELDS = ("vp_x", "vp_y", "vp_z")


def read_pcd(path: Path, max_points: int) -> Columns:
    head, size = read_head(path)
    found = header_lines(head, lambda line: line.upper().startswith("DATA"))
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
        if key in header:
            # The last line won: a second VIEWPOINT moved the sensor and the estimate went on, exit 0.
            raise CloudFileError(f"{path}: the PCD header gives {key} twice")
        header[key] = words[1:]
    for key in ("FIELDS", "SIZE", "TYPE"):
        if key not in header:
            raise CloudFileError(f"{path}: the PCD header has no {key} line")
    fields = header["FIELDS"]
    sizes = [header_count(path, s, "SIZE") for s in header["SIZE"]]
    kinds = [t.upper() for t in header["TYPE"]]
    counts = [header_count(path, c, "COUNT") for c in header.get("COUNT", ["1"] * len(fields))]
    if not len(fields) == len(sizes) == len(kinds) == len(counts):
        raise CloudFileError(
            f"{path}: the PCD header lists {len(fields)} FIELDS but {len(sizes)} SIZE, {len(kinds)} TYPE and "
            f"{len(counts)} COUNT entries"
        )
    n = _pcd_points(path, header)
    check_max_points(path, n, max_points)
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
    for group, what in ((_NORMAL_FIELDS, "a normal's"), (_VP_FIELDS, "a viewpoint's")):
        for name in group:
            if name in names and counts[names.index(name)] != 1:
                raise CloudFileError(f"{path}: the PCD field {name!r} has COUNT {counts[names.index(name)]}; {what} "
                                     f"fields hold one value each")
    origins = _viewpoint(path, header.get("VIEWPOINT"))
    per_point = _has_vp_fields(path, names)
    if per_point and origins is not None:
        raise CloudFileError(f"{path}: the PCD file gives per-point vp_x vp_y vp_z fields and a VIEWPOINT "
                             f"{' '.join(header['VIEWPOINT'])[:80]}; which sensor origin holds is ambiguous")
    dtype = np.dtype([(nm, "<" + c, (k,)) if k != 1 else (nm, "<" + c) for nm, c, k in zip(names, codes, counts, strict=True)])
    data = header["DATA"][0].lower() if header["DATA"] else ""
    if data == "ascii":
        table = _read_pcd_ascii(path, size, offset, n, names, counts, len(lines) + 1)
    elif data == "binary":
        if size != offset + n * dtype.itemsize and text_body(path, offset):
            # Read as binary it was refused as a degenerate cloud, naming grid nodes and clusters, not the body.
            raise CloudFileError(f"{path}: the body looks like ASCII text but the header says DATA binary: if it is "
                                 f"text, the line is 'DATA ascii'")
        check_binary_size(path, size, offset, n, dtype.itemsize, "points")
        if size != offset + n * dtype.itemsize:
            log.warning("%s: %d bytes after the %d points the header claims; ignored", path, size - offset - n * dtype.itemsize, n)
        # A colour field is used only with COUNT 1: an unused one named rgb of 4096 values a point read whole.
        colour = tuple(f for f in ("rgb", "rgba") if f in names and counts[names.index(f)] == 1)
        table = read_binary_rows(path, dtype, n, offset, ("x", "y", "z", *_NORMAL_FIELDS, *_VP_FIELDS, *colour))
        if len(table) != n:
            raise CloudFileError(f"{path}: truncated: claims {n} points, read {len(table)}")
    elif data == "binary_compressed":
        if per_point:  # open3d reads no vp fields: the origins would be lost without a word
            raise CloudFileError(f"{path}: a binary_compressed PCD's vp_x vp_y vp_z fields are not read; save it as "
                                 f"binary or ascii")
        # open3d decompresses, and reads an 8-byte float field of a compressed PCD as 0: a valid file was all points
        # at the origin ("all points are identical").
        odd = [f"{nm} ({kinds[names.index(nm)]} {sizes[names.index(nm)]})" for nm in
               ("x", "y", "z", *_NORMAL_FIELDS) if nm in names and codes[names.index(nm)] != "f4"]
        if odd:
            raise CloudFileError(f"{path}: a binary_compressed PCD is read with 4-byte float coordinates and normals only, "
                                 f"this one has {', '.join(odd)}; save it as binary or ascii")
        partial = [nm for nm in _NORMAL_FIELDS if nm in names]
        if partial and len(partial) < len(_NORMAL_FIELDS):
            # open3d's reader then crashes the process (SIGSEGV, no error line): found by a hostile-input review.
            raise CloudFileError(f"{path}: a binary_compressed PCD with {'/'.join(partial)} but not "
                                 f"{'/'.join(nm for nm in _NORMAL_FIELDS if nm not in names)}: its normals are all three "
                                 f"or none; save it as binary or ascii")
        return _read_pcd_compressed(path, size, offset, n, dtype.itemsize, origins)
    else:
        raise CloudFileError(f"{path}: unknown PCD DATA kind {data[:40]!r}; use ascii, binary or binary_compressed")
    types = {nm: np.dtype(c) for nm, c in zip(names, codes, strict=True)}
    cols = columns_from(table, types, normals=_NORMAL_FIELDS, colors=None, sensor_origins=origins)
    if per_point:
        origins = _point_viewpoints(path, table, cols.points)
        cols = Columns(cols.points, cols.normals, cols.colors, origins)
    colour_field = next((f for f in ("rgb", "rgba") if f in names and counts[names.index(f)] == 1), None)
    if colour_field is not None:
        cols = Columns(cols.points, cols.normals, _pcd_colors(table[colour_field], types[colour_field]), cols.sensor_origins)
    return cols


def _pcd_points(path: Path, header: dict[str, list[str]]) -> int:
    width = header_count(path, header["WIDTH"][0], "WIDTH") if header.get("WIDTH") else None
    height = header_count(path, header["HEIGHT"][0], "HEIGHT") if header.get("HEIGHT") else 1
    if header.get("POINTS"):
        n = header_count(path, header["POINTS"][0], "POINTS")
        if width is not None and width * height != n:
            log.warning("%s: PCD WIDTH x HEIGHT is %d x %d but POINTS is %d; using POINTS", path, width, height, n)
        return n
    if width is None:
        raise CloudFileError(f"{path}: the PCD header has neither POINTS nor WIDTH")
    return width * height


def _has_vp_fields(path: Path, names: list[str]) -> bool:
    """Whether the fields hold PCL's per-point viewpoint, all three of vp_x vp_y vp_z.

    Raises:
        CloudFileError: some of the three but not all.
    """
    missing = [name for name in _VP_FIELDS if name not in names]
    if 0 < len(missing) < len(_VP_FIELDS):
        raise CloudFileError(f"{path}: the PCD file has per-point viewpoint fields but no {' '.join(missing)} "
                             f"(a point's sensor origin needs vp_x vp_y vp_z)")
    return not missing


def _point_viewpoints(path: Path, table: np.ndarray | dict[str, np.ndarray], points: np.ndarray) -> np.ndarray:
    """Each point's sensor origin from its vp_x vp_y vp_z: (n, 3) float64, file units, the points' frame.

    Raises:
        CloudFileError: a finite point whose viewpoint holds NaN or inf. A point that is itself NaN (an
            organised cloud's hole) is dropped with its viewpoint, whatever that holds.
    """
    vp = np.column_stack([np.asarray(table[name], dtype=np.float64) for name in _VP_FIELDS])
    bad = int((~np.isfinite(vp).all(axis=1) & np.isfinite(points).all(axis=1)).sum())
    if bad:
        raise CloudFileError(f"{path}: {bad} of {len(vp)} points have NaN or inf in vp_x vp_y vp_z; a point's "
                             f"sensor origin must be finite")
    return vp


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
    path: Path, size: int, offset: int, n: int, names: list[str], counts: list[int], first_line: int
) -> dict[str, np.ndarray]:
    """The fields of ``n`` text rows from ``offset``, the file's line ``first_line``."""
    width = sum(counts)
    check_text_size(path, size, offset, n, width, "points")
    rows, trailing = read_rows(path, offset, n, width)
    check_row_widths(path, rows, n, width, first_line, "points", "the header's FIELDS and COUNT")
    values = parse_numbers(b" ".join(rows))
    if trailing:
        log.warning("%s: text after the %d points the header claims; ignored", path, n)
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
) -> Columns:
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
    return Columns(points, normals, colors, origins)


def one_origin(origins: np.ndarray) -> np.ndarray | None:
    """The one sensor origin ((3,) metres) every row of ``origins`` ((n, 3), n > 0) holds, or None if they differ.

    A VIEWPOINT holds one origin; ``save_cloud`` asks this whether a cloud's origins fit in one.
    """
    if is_single_origin(origins) or (origins == origins[0]).all():
        return origins[0]
    return None


def write_pcd(cloud: PointCloud, path: Path, *, ascii: bool) -> None:
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
        rgb = byte_colors(cloud).astype(np.uint32)
        fields.append(("rgb", "f4"))
        columns.append(((rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]).view(np.float32)[:, None])
    viewpoint = _DEFAULT_VIEWPOINT
    origins = cloud.sensor_origins  # one origin: save_cloud refused (or dropped) origins that differ
    if origins is not None and len(origins) and (origin := one_origin(origins)) is not None:
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
    write_table(path, header, fields, columns, ascii=ascii)
