"""Clouds sampled unevenly: one half of the surface at a fraction of the other's density.

    .venv/bin/python bench/uneven_spacing.py      # output in bench/results/uneven_spacing.txt

A side a scanner saw from afar, or views of unequal resolution, leave part of a surface far sparser than the
rest. For a 10 cm ball and an 8 x 6 x 4 cm box, 50,000 area-weighted surface points (no normals) of which those
on the lower half are kept with probability 1, 1/3, 1/10, 1/15, 1/30 and 1/60, estimated with 'auto'
(``estimate._at_sparse_spacing`` reconstructs again at the sparse parts' spacing when a pass leaves much of the
surface unmeasured). The table gives the volume error, the cell, the interval relative to the truth, whether the
true volume lies in it, and the warnings' gist; ``sparse / typical`` is ``spacing.sparse_spacing`` (the sparsest
tenth of the area) over ``spacing.point_spacing``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import trimesh
from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

THINNING = (1.0, 1 / 3, 1 / 10, 1 / 15, 1 / 30, 1 / 60)
N = 50_000


def uneven(mesh: trimesh.Trimesh, thinning: float, seed: int = 3) -> np.ndarray:
    points = np.asarray(trimesh.sample.sample_surface(mesh, N, seed=seed)[0])
    keep = (points[:, 2] > mesh.centroid[2]) | (np.random.default_rng([seed, 1]).random(N) < thinning)
    return points[keep]


def gist(warning: str) -> str:
    return warning.split(":")[0].split("(")[0].strip()[:48]


def main() -> None:
    from estimation import estimate, make_cloud
    from estimation.spacing import point_spacing, sparse_spacing

    console = Console(width=220, record=True)
    table = Table(title=f"'auto' on unevenly sampled clouds ({N:,} points before thinning the lower half, no normals)")
    for col in ("shape", "lower half kept", "points", "sparse / typical", "volume error %", "cell mm",
                "interval / truth", "truth in it", "s", "warnings"):
        table.add_column(col, justify="right")
    shapes = {"ball 10 cm": trimesh.creation.icosphere(subdivisions=5, radius=0.05),
              "box 8x6x4 cm": trimesh.creation.box((0.08, 0.06, 0.04))}
    for name, mesh in shapes.items():
        for thinning in THINNING:
            points = uneven(mesh, thinning)
            t0 = time.perf_counter()
            est = estimate(make_cloud(points), 1000.0)
            seconds = time.perf_counter() - t0
            low, high = est.volume_bounds_m3 or (est.volume, est.volume)
            table.add_row(name, f"1/{1 / thinning:.0f}", f"{len(points):,}",
                          f"{sparse_spacing(points, 0.1) / point_spacing(points):.1f}",
                          f"{100 * (est.volume / mesh.volume - 1):+.2f}", f"{1000 * est.cell:.2f}",
                          f"{low / mesh.volume:.4f}..{high / mesh.volume:.4f}",
                          "yes" if low <= mesh.volume <= high else "NO", f"{seconds:.1f}",
                          "; ".join(gist(w) for w in est.warnings) or "-")
            console.print(f"{name} 1/{1 / thinning:.0f} done", style="dim")
    console.print(table)
    out = ROOT / "bench" / "results" / "uneven_spacing.txt"
    out.write_text(console.export_text(), encoding="utf-8")
    print(f"written to {out.relative_to(ROOT)}", file=sys.stderr)


if __name__ == "__main__":
    main()
