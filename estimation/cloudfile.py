"""Reading and writing point-cloud files.

PLY, PCD and XYZ-family files are read by open3d; NPY/NPZ by numpy; TXT/CSV by ``numpy.loadtxt``
(columns x y z [nx ny nz] [r g b]). Open3d loads lazily so ``import estimation`` stays light.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from estimation.cloud import PointCloud, make_cloud
from estimation.errors import CloudFileError

OPEN3D_SUFFIXES = {".ply", ".pcd", ".xyz", ".xyzn", ".xyzrgb", ".pts"}
NUMPY_SUFFIXES = {".npy", ".npz"}
TEXT_SUFFIXES = {".txt", ".csv", ".asc"}
SUFFIXES = OPEN3D_SUFFIXES | NUMPY_SUFFIXES | TEXT_SUFFIXES


def load_cloud(path: str | Path, *, scale: float = 1.0) -> PointCloud:
    """Read a cloud file into a :class:`PointCloud` in metres.

    Args:
        path: a .ply, .pcd, .xyz/.xyzn/.xyzrgb/.pts, .npy, .npz, or .txt/.csv/.asc file.
        scale: metres per file unit (0.001 for a file in millimetres).

    Raises:
        CloudFileError: missing, unreadable, or unknown format.
        CloudError: the file holds no usable points.
    """
    path = Path(path)
    if not path.is_file():
        raise CloudFileError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise CloudFileError(f"{path}: unknown cloud format {suffix!r}; use one of {sorted(SUFFIXES)}")
    try:
        if suffix in OPEN3D_SUFFIXES:
            points, normals, colors = _read_open3d(path)
        elif suffix in NUMPY_SUFFIXES:
            points, normals, colors = _read_numpy(path)
        else:
            points, normals, colors = _split_columns(np.loadtxt(path, delimiter=_delimiter(path), ndmin=2))
    except CloudFileError:
        raise
    except (OSError, ValueError, KeyError, EOFError) as exc:
        raise CloudFileError(f"{path}: unreadable ({exc})") from exc
    return make_cloud(points, normals, colors, scale=scale)


def save_cloud(cloud: PointCloud, path: str | Path) -> None:
    """Write ``cloud`` (metres) to .ply/.pcd/.xyz via open3d or .npy/.npz via numpy."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npz":
        arrays = {"points": cloud.points}
        if cloud.normals is not None:
            arrays["normals"] = cloud.normals
        if cloud.colors is not None:
            arrays["colors"] = cloud.colors
        np.savez(path, **arrays)
    elif suffix == ".npy":
        cols = [cloud.points] + ([cloud.normals] if cloud.normals is not None else [])
        np.save(path, np.hstack(cols))
    elif suffix in OPEN3D_SUFFIXES:
        import open3d as o3d

        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud.points))
        if cloud.normals is not None:
            pcd.normals = o3d.utility.Vector3dVector(cloud.normals)
        if cloud.colors is not None:
            pcd.colors = o3d.utility.Vector3dVector(cloud.colors)
        if not o3d.io.write_point_cloud(str(path), pcd):
            raise CloudFileError(f"{path}: could not write")
    else:
        raise CloudFileError(f"{path}: cannot write format {suffix!r}")


def _read_open3d(path: Path) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    import open3d as o3d

    if path.stat().st_size == 0:
        raise CloudFileError(f"{path}: the file is empty")
    # open3d prints a warning and returns an empty cloud on garbage; we turn that into an error.
    pcd = o3d.io.read_point_cloud(str(path), remove_nan_points=False, remove_infinite_points=False)
    points = np.asarray(pcd.points)
    if len(points) == 0:
        raise CloudFileError(f"{path}: no points could be read (empty or not a {path.suffix} file)")
    normals = np.asarray(pcd.normals) if pcd.has_normals() else None
    colors = np.asarray(pcd.colors) if pcd.has_colors() else None
    return points, normals, colors


def _read_numpy(path: Path) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    data = np.load(path, allow_pickle=False)
    if isinstance(data, np.lib.npyio.NpzFile):
        with data:
            if "points" not in data:
                raise CloudFileError(f"{path}: an .npz cloud needs a 'points' array (has {list(data)})")
            get = lambda k: data[k] if k in data else None  # noqa: E731
            return data["points"], get("normals"), get("colors")
    return _split_columns(data)


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


def _delimiter(path: Path) -> str | None:
    with path.open() as fh:
        head = fh.readline()
    return "," if "," in head else None
