"""Issue 12's speed target: a 1M-point binary PLY (x y z nx ny nz float32, 24 MB) read and estimated in-process.

    .venv/bin/python bench/estimate_speed.py > bench/results/estimate_speed.txt

For a few shapes of ``scenes/shapes.py`` (smooth, low-poly, concave with a handle, thin-walled), 1,000,000
area-weighted surface points with their face normals are written to a temporary PLY, then each is read
(``load_cloud``) and estimated (``estimate``, method 'auto', given normals) REPEATS times; the table gives
the median. CPU is the process's CPU time (``time.process_time``: all threads, so it can exceed wall time
where the k-d tree queries run on both cores); wall is ``time.perf_counter``. Stage columns are the
estimate's own ``timings`` (wall). The baseline is Open3D's screened Poisson (depth 8, the baseline of
bench/shapes.py) on the same file, read by Open3D, in the same process. Imports are paid before timing
(a warm-up estimate on 10k points), and reported on their own.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages, not an installed copy

N = 1_000_000
REPEATS = 3
SHAPES = ("smooth-blob-19", "crease-prism-07", "concave-mug-11", "thin-tube-02")
RHO = 1000.0


def write_ply(path: Path, points: np.ndarray, normals: np.ndarray) -> Path:
    """Binary little-endian PLY with x y z nx ny nz as float32 (24 bytes a point)."""
    table = np.empty(len(points), np.dtype([(a, "<f4") for a in ("x", "y", "z", "nx", "ny", "nz")]))
    for i, a in enumerate("xyz"):
        table[a] = points[:, i]
        table["n" + a] = normals[:, i]
    props = "".join(f"property float {a}\n" for a in ("x", "y", "z", "nx", "ny", "nz"))
    header = f"ply\nformat binary_little_endian 1.0\nelement vertex {len(points)}\n{props}end_header\n"
    with path.open("wb") as fh:
        fh.write(header.encode())
        fh.write(table.tobytes())
    return path


def timed(run) -> tuple[float, float, object]:  # type: ignore[no-untyped-def]
    """(CPU seconds, wall seconds, result) of ``run()``."""
    cpu, wall = time.process_time(), time.perf_counter()
    result = run()
    return time.process_time() - cpu, time.perf_counter() - wall, result


def main() -> int:
    cpu, wall, _ = timed(lambda: __import__("estimation.estimate"))
    from scipy.spatial import cKDTree  # noqa: F401  (paid here, inside the warm-up below otherwise)

    from estimation import estimate, load_cloud
    from scenes.sampling import sample_surface
    from scenes.shapes import make_shapes

    shapes = {s.name: s for s in make_shapes(44, 0)}
    import_cpu, import_wall, _ = timed(lambda: estimate(sample_surface(shapes[SHAPES[0]].mesh, 10_000), RHO))
    o3d_cpu, o3d_wall, o3d = timed(lambda: __import__("open3d"))

    header = (f"{'shape':16s} {'used':>7s} {'cell mm':>7s} {'vol %':>7s} | {'read':>5s} {'down':>5s} {'norm':>5s} "
              f"{'recon':>5s} {'mass':>5s} | {'CPU s':>6s} {'wall s':>6s} | {'Poisson CPU':>11s} {'wall':>5s} "
              f"{'vol %':>7s} | {'CPU ratio':>9s}")
    lines = [f"bench/estimate_speed.py: read + estimate a {N:,}-point binary PLY (x y z nx ny nz float32), "
             f"median of {REPEATS}; stage columns: wall seconds", "", header, "-" * len(header)]
    with tempfile.TemporaryDirectory() as tmp:
        for name in SHAPES:
            shape = shapes[name]
            cloud = sample_surface(shape.mesh, N, seed=1)
            path = write_ply(Path(tmp) / f"{name}.ply", cloud.points, cloud.normals)
            path.read_bytes()  # page cache warm, as for every repeat after the first
            runs = []
            for _ in range(REPEATS):
                def read_and_estimate(path: Path = path):  # type: ignore[no-untyped-def]
                    start = time.perf_counter()
                    loaded = load_cloud(path)
                    return estimate(loaded, RHO, read_seconds=time.perf_counter() - start)
                runs.append(timed(read_and_estimate))
            cpu_s = statistics.median(r[0] for r in runs)
            wall_s = statistics.median(r[1] for r in runs)
            est = runs[0][2]
            t = est.timings

            def poisson(path: Path = path) -> float:
                from estimation.inertia import mass_properties

                pcd = o3d.io.read_point_cloud(str(path))
                mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pcd, depth=8)
                return mass_properties(np.asarray(mesh.vertices), np.asarray(mesh.triangles), RHO).volume

            p_cpu, p_wall, p_volume = timed(poisson)
            lines.append(
                f"{name:16s} {est.points_used:7d} {1000 * est.cell:7.3f} {100 * (est.volume / shape.volume - 1):+7.3f} | "
                f"{t.read:5.2f} {t.downsample:5.2f} {t.normals:5.2f} {t.reconstruct:5.2f} {t.mass_properties:5.2f} | "
                f"{cpu_s:6.2f} {wall_s:6.2f} | {p_cpu:11.2f} {p_wall:5.2f} {100 * (p_volume / shape.volume - 1):+7.3f} | "
                f"{p_cpu / cpu_s:8.1f}x")
            print(f"{name} done", file=sys.stderr, flush=True)
    lines += ["", f"imports before the first estimate: estimation {cpu + import_cpu:.2f} s CPU "
              f"({wall + import_wall:.2f} s wall, a 10k-point warm-up estimate included); "
              f"open3d {o3d_cpu:.2f} s CPU ({o3d_wall:.2f} s wall)"]
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
