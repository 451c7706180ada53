"""NumPy point clouds: .npy (x y z [nx ny nz] [r g b] columns) and .npz (named arrays), read and written.

An .npy is read as 3, 4 (the 4th left out), 6 or 9 columns; an .npz by its ``points``, ``normals``, ``colors`` and
``sensor_origins`` arrays. Every array's header (shape, dtype) is checked against ``max_points`` and the
bytes that follow it before any data is read, and arrays of Python objects are refused, never unpickled.
``depthimage`` reads .npy depth images through the same checked header.
"""

from __future__ import annotations

import logging
import tokenize
import warnings
import zipfile
from pathlib import Path
from typing import BinaryIO

import numpy as np

from estimation.cloud import PointCloud, is_single_origin
from estimation.cloudtable import Columns, check_max_points, split_columns
from estimation.errors import CloudFileError

#: numpy dtype kinds a cloud or depth array may hold: signed and unsigned integers and floats. Complex
#: values would lose their imaginary part (numpy only warns), booleans, strings and records are no coordinates.
REAL_KINDS = "iuf"

log = logging.getLogger(__name__)


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
    if any(type(n) is not int for n in shape):  # a bool is an int to numpy's check, and its readers then raise
        raise CloudFileError(f"{where}: the .npy header's shape must be whole numbers, got {shape}")
    if any(n < 0 for n in shape):
        raise CloudFileError(f"{where}: the .npy header declares a negative size, shape {shape}")
    return shape, dtype


def check_real(path: Path, dtype: np.dtype, what: str) -> None:
    """Raise unless ``dtype`` holds real numbers (``REAL_KINDS``)."""
    if dtype.kind not in REAL_KINDS or dtype.fields is not None:
        raise CloudFileError(f"{path}: {what} must hold real numbers (integer or float), got {dtype}")


def read_numpy(path: Path, max_points: int) -> Columns:
    if path.suffix.lower() == ".npy":
        # Everything is checked on the header before any data is read: a 1-D or 3-D array skipped the
        # row cap (an 800 MB (100000000,) file reached 1.6 GB before its shape was refused).
        shape, dtype = npy_header(path)
        check_real(path, dtype, "a cloud array")
        if len(shape) != 2 or shape[1] not in (3, 4, 6, 9):
            raise CloudFileError(f"{path}: expected an (n, 3), (n, 4), (n, 6) or (n, 9) array (xyz, an intensity, "
                                 f"normals, colours), got shape {shape}")
        check_max_points(path, shape[0], max_points)
        table = np.load(path, mmap_mode="r", allow_pickle=False)
        return Columns(*split_columns(np.array(table), path))
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
        rows = _check_npz_member(path, archive, members["points"], max_points)
        for key in ("normals", "colors", "sensor_origins"):
            if key in members:
                try:
                    _check_npz_member(path, archive, members[key], max_points, rows)
                except _TooLarge as exc:
                    if key != "colors":
                        raise
                    # Colours of the wrong shape are left out (make_cloud), not refused: these are, unread.
                    log.warning("%s; left out", exc)
                    del members[key]
        # Read from the members checked above, not through np.load's keys: a member named plain 'points' is
        # what np.load returns for 'points' first, and it went unchecked (a 2.4 MB file took 4.8 GB).
        def get(key: str) -> np.ndarray | None:
            if key not in members:
                return None
            with archive.open(members[key]) as fh:
                return np.lib.format.read_array(fh, allow_pickle=False)

        return Columns(get("points"), get("normals"), get("colors"), get("sensor_origins"))  # type: ignore[arg-type]


#: Values a point's row of ``normals``, ``colors`` or ``sensor_origins`` may hold (x y z, r g b [a]).
_PER_POINT = 4


class _TooLarge(CloudFileError):
    """An .npz member larger than :data:`_PER_POINT` values a point: refused (colours: left out) before reading."""


def _check_npz_member(path: Path, archive: zipfile.ZipFile, name: str, max_points: int,
                      rows: int | None = None) -> int:
    """Refuse a member whose header claims more rows than allowed or more bytes than it unpacks to; one given
    the ``rows`` of the points, also one larger than :data:`_PER_POINT` values a point (a 2 MB file's
    'normals' of shape (2000, 125000) unpacked 2 GB before its columns were looked at). Returns the rows."""
    with archive.open(name) as fh:
        shape, dtype = _read_npy_header(fh, f"{path}: member {name!r}")
    key = name.removesuffix(".npy")
    check_real(path, dtype, f"array {key!r}")
    if key == "points" and (len(shape) != 2 or shape[1] != 3):
        raise CloudFileError(f"{path}: array {key!r} must be (n, 3), got shape {shape}")
    if shape and shape[0] > max_points:
        check_max_points(path, shape[0], max_points)
    values = int(np.prod(shape, dtype=object))
    if rows is not None and values > _PER_POINT * max(rows, 1):
        raise _TooLarge(f"{path}: array {key!r} claims shape {shape}, {values:,} values for the {rows} points (at "
                        f"most {_PER_POINT} a point are read)")
    if values * dtype.itemsize > archive.getinfo(name).file_size:
        raise CloudFileError(f"{path}: truncated: array {key!r} claims shape {shape}, more than its data")
    return shape[0] if shape else 0


def write_numpy(cloud: PointCloud, path: Path, suffix: str) -> None:
    """.npz: every field (a sensor origin make_cloud stored from a (3,) goes back as (3,)); .npy: x y z [nx ny nz].

    ``save_cloud`` has checked that the cloud holds nothing else the format cannot keep.
    """
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
    else:
        cols = [cloud.points] + ([cloud.normals] if cloud.normals is not None else [])
        np.save(path, np.hstack(cols))
