"""Reading a 1M-point binary PLY: our numpy reader (load_cloud) vs open3d's, in one process.

    .venv/bin/python bench/read_cloud.py > bench/results/read_cloud.txt

Each file is written to a temporary directory, read once to warm the page cache, then timed as the median
of REPEATS reads. Both readers return numpy arrays (open3d's are copied out with ``np.asarray``, as the old
load_cloud did); load_cloud also does make_cloud's work (finite check, unit normals, colours to [0, 1]).
Open3d's import is timed on its own: a command that reads one cloud pays it once, and load_cloud no longer
does.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages, not an installed copy

from estimation import load_cloud

N = 1_000_000
REPEATS = 7


def write_ply(path: Path, dtype: str, *, normals: bool, colours: bool, seed: int = 0) -> Path:
    rng = np.random.default_rng(seed)
    xyz = rng.normal(size=(N, 3)) * 0.1
    fields = [(a, dtype) for a in "xyz"]
    if normals:
        fields += [(a, dtype) for a in ("nx", "ny", "nz")]
    if colours:
        fields += [(c, "u1") for c in ("red", "green", "blue")]
    table = np.empty(N, np.dtype([(name, "<" + code) for name, code in fields]))
    for i, a in enumerate("xyz"):
        table[a] = xyz[:, i]
    if normals:
        unit = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
        for i, a in enumerate(("nx", "ny", "nz")):
            table[a] = unit[:, i]
    if colours:
        for c in ("red", "green", "blue"):
            table[c] = rng.integers(0, 256, N)
    names = {"f4": "float", "f8": "double", "u1": "uchar"}
    props = "".join(f"property {names[code]} {name}\n" for name, code in fields)
    header = f"ply\nformat binary_little_endian 1.0\nelement vertex {N}\n{props}end_header\n"
    with path.open("wb") as fh:
        fh.write(header.encode())
        fh.write(table.tobytes())
    return path


def median_seconds(read) -> float:
    read()  # page cache and first-call costs out of the timing
    times = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        read()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> int:
    assert "open3d" not in sys.modules
    start = time.perf_counter()
    import open3d as o3d

    import_s = time.perf_counter() - start

    def read_open3d(path: Path) -> None:
        pcd = o3d.io.read_point_cloud(str(path))
        np.asarray(pcd.points).copy()
        if pcd.has_normals():
            np.asarray(pcd.normals).copy()
        if pcd.has_colors():
            np.asarray(pcd.colors).copy()

    cases = [
        ("x y z float32 + normals", "f4", True, False),
        ("x y z float64", "f8", False, False),
        ("x y z float32 + normals + rgb uchar", "f4", True, True),
        ("x y z float64 + normals + rgb uchar", "f8", True, True),
    ]
    table = Table(title=f"read a {N:,}-point binary little-endian PLY (median of {REPEATS}, warm cache)")
    for column in ("properties", "MB", "load_cloud ms", "open3d ms", "open3d / ours"):
        table.add_column(column, justify="left" if column == "properties" else "right")
    with tempfile.TemporaryDirectory() as tmp:
        for i, (label, dtype, normals, colours) in enumerate(cases):
            path = write_ply(Path(tmp) / f"c{i}.ply", dtype, normals=normals, colours=colours)
            ours = median_seconds(lambda path=path: load_cloud(path))
            theirs = median_seconds(lambda path=path: read_open3d(path))
            size_mb = path.stat().st_size / 1e6
            table.add_row(label, f"{size_mb:.0f}", f"{ours * 1e3:.0f}", f"{theirs * 1e3:.0f}", f"{theirs / ours:.1f}x")
    console = Console(width=110)
    console.print(table)
    console.print(f"import open3d (once per process, no longer on load_cloud's path): {import_s * 1e3:.0f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
