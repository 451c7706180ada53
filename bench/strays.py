"""Strays (``estimation.strays``): what they cost an estimate, what the split drops that it should not, its time.

    .venv/bin/python bench/strays.py | tee bench/results/strays.txt

1. Harm and cure: a 10 cm ball (20,000 points), and the benchmark's first shapes (20,000 points, no normals:
   the thin shells' walls are thinner than that spacing resolves), each with 30 single points scattered in a
   metre cube around it and two 8-point clumps 2-3 cm off: volume error without the strays, with them kept
   (``keep_strays=True``) and dropped (the default), and the warnings' word on an open surface.
2. False alarms: every shape of ``scenes.shapes.make_shapes(44, 11)`` and part of ``make_parts(16, 7)``, clean
   and noisy, at 1,000 to 200,000 points: clouds that lost a point or were called several parts (should be 0).
3. Time of the split on a million points, clean and with 50 strays, against the point spacing it needs
   (which the estimate computes anyway): best of three, this process.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from estimation import estimate, make_cloud
from estimation.spacing import point_spacing
from estimation.strays import islands
from scenes.sampling import sample_surface
from scenes.shapes import make_parts, make_shapes

CONDITIONS = ((200_000, 0.0), (200_000, 0.0005), (30_000, 0.0), (5_000, 0.0005), (1_000, 0.0))


def _strays(rng: np.random.Generator, center: np.ndarray, reach: float) -> np.ndarray:
    single = rng.uniform(-0.5, 0.5, size=(400, 3)) + center
    single = single[np.linalg.norm(single - center, axis=1) > reach + 0.02][:30]
    clumps = [center + d * (reach + 0.025) + rng.normal(scale=0.002, size=(8, 3))
              for d in (np.array([0.0, 0.0, 1.0]), np.array([0.6, -0.8, 0.0]))]
    return np.vstack([single, *clumps])


def harm(console: Console) -> None:
    table = Table(title="strays kept against dropped: volume error %")
    for col in ("cloud", "true volume cm3", "no strays %", "kept %", "dropped %", "kept: 'open' warning",
                "dropped: warning"):
        table.add_column(col, justify="right" if "%" in col or "cm3" in col else "left")
    v = np.random.default_rng(0).normal(size=(20_000, 3))
    ball = 0.05 * v / np.linalg.norm(v, axis=1, keepdims=True)
    clouds = [("ball 10 cm", ball, 4 / 3 * np.pi * 0.05**3)]
    for shape in make_shapes(8, 11):
        clouds.append((shape.name, sample_surface(shape.mesh, 20_000, seed=[5, len(clouds)]).points, shape.volume))
    for name, points, truth in clouds:
        rng = np.random.default_rng(len(name))
        center = points.mean(axis=0)
        reach = float(np.linalg.norm(points - center, axis=1).max())
        cloud = make_cloud(np.r_[points, _strays(rng, center, reach)])
        clean = estimate(make_cloud(points), 1000.0)
        kept = estimate(cloud, 1000.0, keep_strays=True)
        dropped = estimate(cloud, 1000.0)
        opened = lambda e: "yes" if any("not measured" in w or "open" in w for w in e.warnings) else "no"  # noqa: E731
        said = next((w.split(" more than")[0] for w in dropped.warnings if w.startswith("dropped")), "none")
        table.add_row(name, f"{truth * 1e6:.1f}", f"{100 * (clean.mass.volume / truth - 1):+.2f}",
                      f"{100 * (kept.mass.volume / truth - 1):+.2f}",
                      f"{100 * (dropped.mass.volume / truth - 1):+.2f}", opened(kept), said)
    console.print(table)


def false_alarms(console: Console) -> None:
    flagged, total, rows = 0, 0, []
    for label, group in (("shape", make_shapes(44, 11)), ("part", make_parts(16, 7))):
        for i, shape in enumerate(group):
            for c, (n, sigma) in enumerate(CONDITIONS):
                p = sample_surface(shape.mesh, n, seed=[11, i, c], noise_sigma=sigma).points
                found = islands(p, point_spacing(p))
                total += 1
                if found.strays or found.parts != 1:
                    flagged += 1
                    rows.append(f"{label} {shape.name} n={n} sigma={sigma}: {found.strays} strays, {found.parts} parts")
    console.print(f"false alarms: {flagged} of {total} clouds lost a point or were called several parts "
                  f"(44 shapes + 16 parts x {len(CONDITIONS)} conditions)")
    for row in rows:
        console.print("  " + row)


def timing(console: Console) -> None:
    table = Table(title="split time on a million points (best of 3, ms)")
    for col in ("cloud", "point spacing ms", "islands ms", "strays found"):
        table.add_column(col, justify="right")
    v = np.random.default_rng(1).normal(size=(1_000_000, 3))
    ball = 0.1 * v / np.linalg.norm(v, axis=1, keepdims=True)
    with_strays = np.r_[ball, np.random.default_rng(2).uniform(-0.5, 0.5, (50, 3))]
    for name, p in (("clean ball", ball), ("ball + 50 strays", with_strays)):
        best = [np.inf, np.inf]
        for _ in range(3):
            t0 = time.perf_counter()
            spacing = point_spacing(p)
            t1 = time.perf_counter()
            found = islands(p, spacing)
            t2 = time.perf_counter()
            best = [min(best[0], t1 - t0), min(best[1], t2 - t1)]
        table.add_row(name, f"{1e3 * best[0]:.0f}", f"{1e3 * best[1]:.0f}", str(found.strays))
    console.print(table)


def main() -> int:
    console = Console(width=160)
    harm(console)
    false_alarms(console)
    timing(console)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
