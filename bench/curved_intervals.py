"""Facets on a curved surface: how often the interval holds the truth on clean clouds, and long thin parts.

    .venv/bin/python bench/curved_intervals.py            # output in bench/results/curved_intervals.txt
    .venv/bin/python bench/curved_intervals.py --without  # CHORDAL_DOUBT 0: the interval and refining as before

Clean clouds (100,000 surface points) of the 44 shapes of ``scenes.shapes`` (seed 0), with their normals and
without, and of long thin parts (wires 2 and 3 mm across, 0.1 to 1 m long). ``estimate`` adds back the slivers
between its flat facets and the curved surface (``estimation.curvature``); the interval widens by their size
(``tolerances.CHORDAL_DOUBT``), and by the slivers it could not add where the surface turns faster than the
cells resolve, which also call for a finer pass. Per condition: the truth inside ``volume_bounds_m3``, the
median interval half-width, the median and largest error; then each long part's error, interval, points used,
seconds and the process's peak memory so far.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from estimation import estimate, make_cloud
from estimation import tolerances as tol
from scenes.shapes import make_shapes

POINTS = 100_000
WIRES = ((0.001, 0.1), (0.001, 0.3), (0.001, 1.0), (0.0015, 1.0))  # radius, length: metres


def _cloud(mesh: trimesh.Trimesh, seed: int, normals: bool):  # type: ignore[no-untyped-def]
    points, face = trimesh.sample.sample_surface(mesh, POINTS, seed=seed)
    return make_cloud(points, np.asarray(mesh.face_normals)[face] if normals else None)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--without", action="store_true", help="CHORDAL_DOUBT set to 0 (before session 41)")
    args = ap.parse_args(argv)
    if args.without:
        tol.CHORDAL_DOUBT = 0.0  # read at each estimate
    shapes = make_shapes(44, 0)
    print(f"bench/curved_intervals.py{' --without' if args.without else ''}: {POINTS:,} clean points, 'auto'\n")
    for normals in (True, False):
        inside, widths, errors, outside = 0, [], [], []
        for k, shape in enumerate(shapes):
            print(f"[{'normals' if normals else 'no normals'} {k + 1}/{len(shapes)}] {shape.name}", file=sys.stderr, flush=True)
            est = estimate(_cloud(shape.mesh, k, normals), 1000.0)
            low, high = est.volume_bounds_m3
            truth = shape.mesh.volume
            held = low <= truth <= high
            inside += held
            widths.append((high - low) / 2 / truth)
            errors.append(abs(est.volume / truth - 1))
            if not held:
                outside.append(f"{shape.name} {100 * (est.volume / truth - 1):+.3f} % in "
                               f"{100 * (low / truth - 1):+.3f}..{100 * (high / truth - 1):+.3f}")
        print(f"{'given normals' if normals else 'no normals'}: the truth inside the interval for {inside} of "
              f"{len(shapes)}; median half-width {100 * np.median(widths):.3f} %; error median "
              f"{100 * np.median(errors):.3f} %, max {100 * max(errors):.3f} %")
        print("  outside: " + ("; ".join(outside) if outside else "none") + "\n", flush=True)
    print(f"{'wire':>14s} {'normals':>8s} {'error %':>8s} {'interval %':>18s} {'points':>7s} {'s':>6s} {'peak MB':>8s}")
    for radius, length in WIRES:
        mesh = trimesh.creation.cylinder(radius=radius, height=length, sections=64)
        for normals in (True, False):
            t0 = time.perf_counter()
            est = estimate(_cloud(mesh, 3, normals), 1000.0)
            seconds = time.perf_counter() - t0
            low, high = est.volume_bounds_m3
            truth = mesh.volume
            peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
            print(f"{f'{2000 * radius:g} x {1000 * length:g} mm':>14s} {'yes' if normals else 'no':>8s} "
                  f"{100 * (est.volume / truth - 1):+8.3f} {f'{100 * (low / truth - 1):+.2f}..{100 * (high / truth - 1):+.2f}':>18s} "
                  f"{est.points_used:>7d} {seconds:6.1f} {peak:8.0f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
