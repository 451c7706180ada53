"""The camera feed on tabletops it was never run on: seeded random scenes of generated shapes.

bench/cameras.py measures two hand-written scenes; this one draws new ones. Each scene puts 10 shapes of
:mod:`scenes.shapes` (every family but the 1-3 mm thin shells, which a 1 mm sensor cannot resolve: crease,
concave, smooth, elongated), rescaled to 4-15 cm on their longest side (those whose thinnest wall or plate
then falls under 3 mm are drawn again) and turned at random, on a 1.2 x
0.8 m table, as far apart as a seeded rejection sampler puts them (footprints at least 2 cm apart); the
remote lets each settle where it falls. Then, as in bench/cameras.py, 1, 2 and 3 cameras of the issue's
sigma 1 mm condition scan it once, every object is segmented, fused, closed, sent through the wire's
codec and estimated, and its volume is compared with the true mesh's. The 1-camera target holds for
convex or mirror-symmetric objects only; the "convex" column takes those whose volume fills at least 0.9
of their convex hull (mirror symmetry is not judged here).

    .venv/bin/python bench/camera_tables.py [--scenes 3] [--seed 0] [--out bench/results/camera_tables.txt]

The tables go to ``--out`` as well as to the terminal. Seeds 0-3 are the set the camera feed was looked at
with; seeds 4-7 (``--seed 4 --scenes 4 --out bench/results/camera_tables_seed4.txt``) were first run after
the last change to it, as a check on what that set taught.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from cameras import run_scene  # noqa: E402

TABLE = (1.2, 0.8, 0.04)
OBJECTS = 10
SIZE = (0.04, 0.15)  # longest side, metres
GAP = 0.02  # metres between footprints
MIN_WALL = 0.003  # metres: thinnest wall or plate, as issue 12's noisy condition (sigma 0.5 mm) asks
MATERIALS = ("wood_pine", "abs_plastic", "rubber", "aluminium", "cardboard", "glass")
CAMERA = {"width": 1280, "height": 720, "fov_y_deg": 42.0}  # bench/cameras.py's sigma 1 mm condition


def write_scene(folder: Path, seed: int) -> tuple[Path, dict[str, float]]:
    """A random tabletop scene file in ``folder`` (its meshes beside it); returns it and each object's
    convex fill (volume over its hull's)."""
    from scenes.shapes import make_shapes

    rng = np.random.default_rng([seed, 7])
    pool = [s for s in make_shapes(count=66, seed=1000 + seed) if s.family != "thin"]
    picked, sizes = [], []
    for i in rng.permutation(len(pool)):
        shape = pool[i]
        size = float(np.exp(rng.uniform(*np.log(SIZE))))
        if shape.min_wall * size / float(shape.mesh.extents.max()) >= MIN_WALL:
            picked.append(shape)
            sizes.append(size)
        if len(picked) == OBJECTS:
            break
    lines = [f'name = "table{seed}"', "", "[table]", f"size = [{TABLE[0]}, {TABLE[1]}, {TABLE[2]}]",
             "height = 0.75", 'material = "wood_oak"', "", "[end_effector]", "radius = 0.015",
             f"position = [{-TABLE[0] / 2 - 0.05}, 0.0, 0.82]"]
    placed: list[tuple[np.ndarray, float]] = []
    fills = {}
    for k, (shape, size) in enumerate(zip(picked, sizes, strict=True)):
        mesh = shape.mesh.copy()
        mesh.apply_translation(-mesh.centroid)
        mesh.apply_scale(size / float(mesh.extents.max()))
        name = f"{shape.name.replace('-', '_')}_{k}"
        mesh.export(folder / f"{name}.stl")
        fills[name] = float(mesh.volume / mesh.convex_hull.volume)
        radius = float(np.linalg.norm(mesh.vertices, axis=1).max())  # any way it topples, it stays inside
        for _ in range(10_000):
            xy = rng.uniform([-TABLE[0] / 2 + radius + 0.02, -TABLE[1] / 2 + radius + 0.02],
                             [TABLE[0] / 2 - radius - 0.02, TABLE[1] / 2 - radius - 0.02])
            if all(np.linalg.norm(xy - c) > radius + r + GAP for c, r in placed):
                break
        else:
            raise RuntimeError(f"table{seed}: no room for {name}")
        placed.append((xy, radius))
        lines += ["", "[[objects]]", f'id = "{name}"', f'mesh = "{name}.stl"',
                  f'material = "{MATERIALS[k % len(MATERIALS)]}"', f"position = [{xy[0]:.4f}, {xy[1]:.4f}]",
                  "points = 30000"]
    path = folder / f"table{seed}.toml"
    path.write_text("\n".join(lines) + "\n")
    return path, fills


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=int, default=3, help="random scenes (default 3)")
    ap.add_argument("--seed", type=int, default=0, help="first scene's seed (default 0)")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "camera_tables.txt",
                    help="where the tables are written (default bench/results/camera_tables.txt)")
    args = ap.parse_args()
    console = Console(record=True, width=200)
    summary = Table(title="camera feed on random tabletops (sigma 1 mm, 1280 x 720): volume error over objects")
    for col in ("scene", "cams", "objects", "median |err| %", "max |err| %", "convex: median / max %",
                "truth in interval", "unseen", "segments found / merged / split / missed"):
        summary.add_column(col, justify="right")
    per = Table(title="signed volume error % per object (fill: volume over convex hull volume)")
    for col in ("scene", "object", "fill", "1 cam", "2 cam", "3 cam"):
        per.add_column(col, justify="right")
    pooled: dict[int, list[float]] = {1: [], 2: [], 3: []}
    held: list[bool] = []
    with tempfile.TemporaryDirectory(prefix="camera-tables-") as tmp:
        for seed in range(args.seed, args.seed + args.scenes):
            folder = Path(tmp) / f"table{seed}"
            folder.mkdir()
            path, fills = write_scene(folder, seed)
            runs = {}
            for k in (1, 2, 3):
                r = runs[k] = run_scene(path, k, "SIGMA_1MM", CAMERA)
                err = np.abs(np.array(list(r["errors"].values()))) * 100
                convex = np.abs(np.array([e for o, e in r["errors"].items() if fills[o] >= 0.9])) * 100
                pooled[k] += err.tolist()
                held += list(r["held"].values())
                c = r["check"]
                summary.add_row(f"table{seed}", str(k), str(len(err)), f"{np.median(err):.1f}", f"{err.max():.1f}",
                                f"{np.median(convex):.1f} / {convex.max():.1f}" if convex.size else "-",
                                f"{sum(r['held'].values())}/{len(r['held'])}", str(len(r["unseen"])),
                                f"{len(c.found)} / {len(c.merged)} / {len(c.split)} / {len(c.missed)}")
                console.print(f"table{seed} x{k}: {r['stats']}" + (f" unseen: {r['unseen']}" if r["unseen"] else ""))
            for obj, fill in fills.items():
                per.add_row(f"table{seed}", obj, f"{fill:.2f}",
                            *(f"{100 * runs[k]['errors'][obj]:+.1f}" if obj in runs[k]["errors"] else "unseen"
                              for k in (1, 2, 3)))
    console.print(summary)
    console.print(per)
    for k, errs in pooled.items():
        e = np.array(errs)
        console.print(f"{k} camera(s), all scenes: {len(e)} objects, median {np.median(e):.1f} %, max {e.max():.1f} %")
    console.print(f"true volume inside the reported interval: {sum(held)} of {len(held)} ({100 * np.mean(held):.0f} %)")
    args.out.write_text(console.export_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
