"""Hollow objects: air that the flood fill's closing shell encloses, with and without normals and noise.

    .venv/bin/python bench/hollows.py          # 6 objects x 3 conditions, 100k points each, ~2 min

A bottle whose 20 mm mouth the closing shell seals, a closed box and a closed ball (2-3 mm walls), an open
600 mm pipe with 3 mm walls, a bookshelf with 18 mm boards and a 4 mm back, and a solid control of the
bottle's outline. Random poses (seeded). Columns: signed volume error %, whether the truth lies in
``volume_bounds_m3``, the warnings' first words. The noisy condition's walls are at most six sigmas:
the issue's "walls >= 3 mm" at its edge. Writes bench/results/hollows.txt.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages, not an installed copy

from estimation import estimate, make_cloud
from scenes.sampling import sample_surface
from scenes.shapes import bottle, closed_box, hollow_ball, open_pipe

RESULTS = Path(__file__).parent / "results" / "hollows.txt"
CONDITIONS = {"given normals": (True, 0.0), "no normals": (False, 0.0), "noise 0.5 mm, no normals": (False, 0.0005)}
def _shelf() -> trimesh.Trimesh:
    width, height, depth, board = 0.6, 0.8, 0.25, 0.018
    parts = [trimesh.creation.box((board, depth, height)).apply_translation((x, 0, height / 2))
             for x in (-width / 2 + board / 2, width / 2 - board / 2)]
    parts += [trimesh.creation.box((width, depth, board)).apply_translation((0, 0, z))
              for z in (board / 2, height / 3, 2 * height / 3, height - board / 2)]
    parts.append(trimesh.creation.box((width, 0.004, height)).apply_translation((0, depth / 2 - 0.002, height / 2)))
    return trimesh.boolean.union(parts, engine="manifold")


def objects() -> dict[str, trimesh.Trimesh]:
    """The bench's objects by name, in their own frames (metres)."""
    solid_outline = np.array([(0, 0), (35, 0), (35, 160), (13, 200), (13, 220), (0, 220)], float) * 1e-3
    return {
        "bottle, mouth sealed": bottle(),
        "closed box, 3 mm": closed_box(0.003),
        "closed ball, 2 mm": hollow_ball(0.04, 0.002),
        "open pipe 600 mm, 3 mm": open_pipe(),
        "bookshelf": _shelf(),
        "solid bottle (control)": trimesh.creation.revolve(solid_outline, sections=64),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--points", type=int, default=100_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    lines = [f"bench/hollows.py: {args.points:,} points each, seed {args.seed}, random poses, density 1000", "",
             f"{'object':24s} {'condition':26s} {'volume %':>9s}  in interval  {'seconds':>7s}  warnings"]
    for name, mesh in objects().items():
        pose = trimesh.transformations.random_rotation_matrix(rng.random(3))
        pose[:3, 3] = rng.uniform(-1, 1, 3)
        posed = mesh.copy().apply_transform(pose)
        for condition, (normals, sigma) in CONDITIONS.items():
            cloud = sample_surface(posed, args.points, seed=args.seed, noise_sigma=sigma, with_normals=normals)
            t0 = time.perf_counter()
            est = estimate(make_cloud(cloud.points, cloud.normals if normals else None), 1000.0)
            seconds = time.perf_counter() - t0
            low, high = est.volume_bounds_m3
            said = "; ".join(w.split(":")[0].split(" (")[0] for w in est.warnings) or "-"
            lines.append(f"{name:24s} {condition:26s} {100 * (est.volume / mesh.volume - 1):+9.2f}  "
                         f"{'yes' if low <= mesh.volume <= high else 'no':11s}  {seconds:7.2f}  {said}")
            print(lines[-1], file=sys.stderr, flush=True)
    text = "\n".join(lines) + "\n"
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
