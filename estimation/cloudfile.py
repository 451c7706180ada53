"""Reading and writing point-cloud files: ``load_cloud`` and ``save_cloud`` pick the format by suffix.

One module a format, each with its reader and writer:

- ``plyfile``: PLY (ascii, binary little and big endian);
- ``pcdfile``: PCD (ascii, binary; ``binary_compressed`` through open3d), with its VIEWPOINT as the
  cloud's sensor origin;
- ``textcloud``: .xyz/.xyzn/.xyzrgb/.pts and .txt/.csv/.asc, through ``numpy.loadtxt``;
- ``numpycloud``: .npy and .npz;

and ``cloudtable`` for what they share. Open3d is not imported on the read path (its import alone costs
0.7 s); only a compressed PCD goes there, after our header checks passed.

Every reader checks what the header claims against the file before it allocates: the point count against
``max_points`` and, for binary data, the exact byte size (for text, at least one short line a point).
A file that claims more points than it holds is a :class:`CloudFileError` naming the claimed and the
present counts, never a cloud padded with points at the origin.

Writing refuses to lose data: a field the chosen format cannot keep (normals in .xyz, sensor origins in .ply)
is an error naming the formats that keep it, unless the caller names it in ``save_cloud(..., drop=...)``.
"""

from __future__ import annotations

import stat
import zipfile
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path

from estimation.cloud import PointCloud, check_is_cloud, make_cloud
from estimation.contracts import check_number
from estimation.errors import CloudError, CloudFileError, SettingsError
from estimation.numpycloud import read_numpy, write_numpy
from estimation.pcdfile import one_origin, read_pcd, write_pcd
from estimation.plyfile import read_ply, write_ply
from estimation.textcloud import read_text, write_xyz

PLY_SUFFIXES = {".ply"}
PCD_SUFFIXES = {".pcd"}
XYZ_SUFFIXES = {".xyz", ".xyzn", ".xyzrgb", ".pts"}
NUMPY_SUFFIXES = {".npy", ".npz"}
TEXT_SUFFIXES = {".txt", ".csv", ".asc"}
SUFFIXES = PLY_SUFFIXES | PCD_SUFFIXES | XYZ_SUFFIXES | NUMPY_SUFFIXES | TEXT_SUFFIXES

#: Default cap on the points a file may claim. 50 M points are 1.2 GB of float64 xyz (3.6 GB with normals
#: and colours) before any estimation work: above any one-object scan we take (a 4K depth frame is 8.3 M
#: points), and about what the few-GB machines we run on can still hold. Raise it with ``max_points``.
MAX_POINTS = 50_000_000


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
    # '5' was a TypeError from a comparison deep in a reader; -1 was taken, and refused every file.
    check_number(max_points, "max_points", low=1, whole=True, error=SettingsError)
    check_input_file(path)
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise CloudFileError(f"{path}: unknown cloud format {suffix!r}; use one of {sorted(SUFFIXES)}")
    try:
        if path.stat().st_size == 0:
            raise CloudFileError(f"{path}: the file is empty (0 bytes)")
        if suffix in PLY_SUFFIXES:
            cols = read_ply(path, max_points)
        elif suffix in PCD_SUFFIXES:
            cols = read_pcd(path, max_points)
        elif suffix in NUMPY_SUFFIXES:
            cols = read_numpy(path, max_points)
        else:
            cols = read_text(path, max_points)
    except CloudFileError:
        raise
    # NotImplementedError and RuntimeError: an .npz member zipfile cannot open (deflate64 or another method it
    # lacks; the encrypted flag).
    except (OSError, ValueError, KeyError, EOFError, OverflowError, zipfile.BadZipFile, NotImplementedError,
            RuntimeError) as exc:
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
    ``pcdfile.PCD_FLOAT32_ERROR_M`` (coordinates beyond about 16 m). .npz keeps everything, sensor origins
    included; .npy holds x y z [nx ny nz]; .xyz x y z, .xyzn x y z nx ny nz, .xyzrgb x y z r g b, .pts a count
    then x y z [r g b], all as text. ``WRITE_HOLDS`` says which fields each keeps.

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
        if suffix in NUMPY_SUFFIXES:
            write_numpy(cloud, path, suffix)
        elif suffix in PLY_SUFFIXES:
            write_ply(cloud, path, ascii=ascii)
        elif suffix in PCD_SUFFIXES:
            write_pcd(cloud, path, ascii=ascii)
        else:
            write_xyz(cloud, path, suffix)
    except OSError as exc:
        if isinstance(exc, CloudFileError):
            raise
        raise CloudFileError(f"{path}: could not write ({exc.strerror or exc})") from exc


def _contents(cloud: PointCloud) -> list[str]:
    """What ``cloud`` holds besides x y z, as ``WRITE_HOLDS`` names it, in ``DROPPABLE``'s order."""
    held = [name for name in DROPPABLE if getattr(cloud, name) is not None and len(getattr(cloud, name))]
    if "sensor_origins" in held and one_origin(cloud.sensor_origins) is None:  # type: ignore[arg-type]
        held = [("per-point sensor_origins" if name == "sensor_origins" else name) for name in held]
    return held


def _listed(items: list[str], last: str) -> str:
    """'a', 'a and b', 'a, b and c' (``last`` the word before the last item)."""
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} {last} {items[-1]}"
