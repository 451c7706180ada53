"""Parts near the noise limit: wires, fins, teeth and slots 3-6 mm across, clean and at sigma 0.5 mm.

    .venv/bin/python bench/thin_parts.py                  # 16 parts x 2 conditions, 100k points each
    .venv/bin/python bench/thin_parts.py --count 8

The parts come from ``scenes.shapes.make_parts`` (coils, combs, heatsinks, slotted blocks, pipes, wire
rings, nuts, stools; seeded sizes and poses), none of them in ``bench/shapes.py``'s set. At sigma 0.5 mm
their thinnest features are six to twelve sigmas across, inside the noisy target's "walls >= 3 mm". No
normals in either condition. Columns: signed volume error %, whether the truth lies in the estimate's
``volume_bounds_m3``, centre of mass error mm, the share of the estimate's normals pointing into the part (against
the nearest true face's), seconds. Writes bench/results/thin_parts.txt.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages, not an installed copy

from shapes import publish  # bench/shapes.py: this script's folder is on sys.path

from estimation import estimate, make_cloud
from scenes.sampling import sample_surface
from scenes.shapes import inside_out, make_parts

CONDITIONS = {"clean, no normals": 0.0, "noise 0.5 mm, no normals": 0.0005}
RESULTS = Path(__file__).parent / "results" / "thin_parts.txt"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--count", type=int, default=16)
    parser.add_argument("--points", type=int, default=100_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    lines = [f"bench/thin_parts.py: {args.count} parts (scenes.shapes.make_parts, seed {args.seed}), "
             f"{args.points:,} points each, no normals", ""]
    summary = []
    for condition, sigma in CONDITIONS.items():
        lines.append(f"  {condition}")
        errors, held, coms = [], 0, []
        for i, part in enumerate(make_parts(args.count, args.seed)):
            cloud = sample_surface(part.mesh, args.points, seed=[args.seed, i], noise_sigma=sigma, with_normals=False)
            t0 = time.perf_counter()
            est = estimate(make_cloud(cloud.points), 1000.0)
            seconds = time.perf_counter() - t0
            error = 100 * (est.volume / part.volume - 1)
            low, high = est.volume_bounds_m3 or (est.volume, est.volume)
            inside = low <= part.volume <= high
            com = 1000 * float(np.linalg.norm(est.mass.center_of_mass - part.center_of_mass))
            flipped = 100 * inside_out(part.mesh, est.points, est.normals)
            errors.append(error)
            coms.append(com)
            held += inside
            lines.append(f"    {part.name:22s} thinnest {1000 * part.min_wall:4.1f} mm  volume {error:+8.3f} %  "
                         f"truth in interval {'yes' if inside else 'no ':3s}  com {com:6.3f} mm  "
                         f"normals inside out {flipped:5.1f} %  {seconds:5.1f} s")
            print(f"[{condition}] {lines[-1].strip()}", file=sys.stderr, flush=True)
        a = np.abs(errors)
        summary.append(f"{condition:26s} {len(a):3d} | {np.median(a):7.3f} {np.percentile(a, 90):7.3f} {a.max():8.3f} | "
                       f"{held:3d}/{len(a):<3d} | {max(coms):6.3f}")
    header = f"{'condition':26s} {'n':>3s} | volume % median  p90      max | in interval | COM mm max"
    text = "\n".join([*lines[:2], header, "-" * len(header), *summary, "", "per part:", *lines[2:]])
    publish(text, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
