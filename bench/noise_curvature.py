"""Noise on a curved surface: the estimate's error against the interval it gives for it.

    .venv/bin/python bench/noise_curvature.py      # output in bench/results/noise_curvature.txt
    .venv/bin/python bench/noise_curvature.py --without   # the same with the widening off (the "before")

Isotropic Gaussian noise (sigma 0.5 and 1 mm) on 100,000 surface points, no normals, of every shape of
``scenes.shapes`` (seeds 0 and 1) whose walls are at least 3 mm, and of spheres of 5, 8 and 15 mm radius, cubes
of 20 and 60 mm and a 4 mm-radius rod. Isotropic noise lifts the points' mean off a curved surface by about
sigma^2 times its mean curvature H and the peak of their density inward by twice that, so ``estimate`` widens
``volume_bounds_m3`` by 2 sigma^2 times the integral of H (``tolerances.NOISE_CURVATURE_BIAS``) and warns
past ``NOISE_CURVATURE_WARN`` of the volume. Per condition: how often the true volume lies inside the interval,
the median interval half-width, and every shape that is outside it or warned.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from estimation import estimate
from scenes.sampling import sample_surface
from scenes.shapes import make_shapes

SIGMAS = (0.0005, 0.001)
POINTS = 100_000
NOISY_MIN_WALL = 0.003


def cases() -> list[tuple[str, trimesh.Trimesh]]:
    out = [(f"{seed}:{s.name}", s.mesh) for seed in (0, 1) for s in make_shapes(44, seed) if s.min_wall >= NOISY_MIN_WALL]
    out += [(f"sphere r {1000 * r:.0f} mm", trimesh.creation.icosphere(5, radius=r)) for r in (0.005, 0.008, 0.015)]
    out += [(f"cube {1000 * a:.0f} mm", trimesh.creation.box(extents=[a] * 3)) for a in (0.02, 0.06)]
    out.append(("rod r 4 mm x 50", trimesh.creation.cylinder(radius=0.004, height=0.05, sections=64)))
    return out


def main(argv: list[str] | None = None) -> int:
    import argparse

    from estimation import tolerances as tol

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--without", action="store_true", help="NOISE_CURVATURE_BIAS set to 0: the interval as before")
    args = ap.parse_args(argv)
    if args.without:
        tol.NOISE_CURVATURE_BIAS = 0.0  # read at each estimate (estimation.estimate._noise_on_curvature)
    shapes = cases()
    print(f"bench/noise_curvature.py{' --without' if args.without else ''}: {POINTS:,} points, isotropic Gaussian "
          f"noise, 'auto' without normals, {len(shapes)} shapes\n")
    for sigma in SIGMAS:
        inside, widths, rows = 0, [], []
        for k, (name, mesh) in enumerate(shapes):
            print(f"[sigma {1000 * sigma:g} mm {k + 1}/{len(shapes)}] {name}", file=sys.stderr, flush=True)
            est = estimate(sample_surface(mesh, POINTS, seed=[7, k, round(sigma * 1e4)], noise_sigma=sigma), 1000.0)
            low, high = est.volume_bounds_m3
            truth = mesh.volume
            held = low <= truth <= high
            inside += held
            widths.append((high - low) / 2 / truth)
            warned = any("radius of curvature" in w for w in est.warnings)
            if warned or not held:
                rows.append(f"  {name:26s} error {100 * (est.volume / truth - 1):+7.2f} %   interval "
                            f"{100 * (low / truth - 1):+7.2f} .. {100 * (high / truth - 1):+7.2f} %   "
                            f"{'inside' if held else 'OUTSIDE'}{'   warned' if warned else ''}")
        print(f"sigma {1000 * sigma:g} mm: the truth inside the interval for {inside} of {len(shapes)}; "
              f"median half-width {100 * np.median(widths):.2f} %; outside or warned:")
        print("\n".join(rows) + "\n", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
