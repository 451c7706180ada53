"""CoACD's cost against its fit, for settings that trade one for the other, on shapes it was not tuned on.

    .venv/bin/python bench/coacd_settings.py [--seeds 11,23] [--variants default,it25] | tee bench/results/coacd_settings.txt

The shapes: scenes/shapes.py at the given seeds (44 each), as the twin sees them (centred on the centre of
mass, decimated to the visual mesh's 3000 faces); only those :func:`twin.decompose.skips_coacd` sends to
CoACD. Per shape and variant: CoACD's CPU seconds, hull count, and two fits, p99 over size: "uncovered",
how far samples of the surface lie outside every hull (contact missed); "bloat", how far hull vertices lie
from the surface (contact too early). The footer sums CPU and gives the medians and worst cases.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

VARIANTS = {
    "default": {},
    "it50": {"mcts_iterations": 50},
    "it25": {"mcts_iterations": 25},
    "depth2": {"mcts_max_depth": 2},
    "res500": {"resolution": 500},
}


def fit(vertices: np.ndarray, faces: np.ndarray, parts: list) -> tuple[float, float]:  # type: ignore[type-arg]
    """(uncovered, bloat): p99 distances, metres, of surface samples outside every hull and of hull vertices
    from the surface."""
    import trimesh
    from scipy.spatial import cKDTree

    mesh = trimesh.Trimesh(vertices, faces)
    points = mesh.sample(20000, seed=0)
    surface = cKDTree(mesh.sample(200000, seed=1))
    hulls = [trimesh.Trimesh(np.asarray(v), np.asarray(f)).convex_hull for v, f in parts]
    outside = np.full(len(points), np.inf)
    for h in hulls:
        offsets = (h.face_normals * h.triangles[:, 0]).sum(axis=1)
        outside = np.minimum(outside, np.maximum((points @ h.face_normals.T - offsets).max(axis=1), 0.0))
    bloat = surface.query(np.vstack([h.vertices for h in hulls]))[0]
    return float(np.percentile(outside, 99)), float(np.percentile(bloat, 99))


def main(argv: list[str] | None = None) -> int:
    import coacd

    from scenes.shapes import make_shapes
    from twin.decompose import DEFAULT_SETTINGS, concavity, skips_coacd
    from twin.objects import decimate

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", default="11,23")
    p.add_argument("--variants", default="default,it50", help=f"of {', '.join(VARIANTS)} (default: the current settings)")
    args = p.parse_args(argv)
    names = args.variants.split(",")
    coacd.set_log_level("error")
    rows: dict[str, list[tuple[float, int, float, float]]] = {n: [] for n in names}
    print(f"settings now: {DEFAULT_SETTINGS}")
    for seed in (int(s) for s in args.seeds.split(",")):
        for shape in make_shapes(44, seed=seed):
            m = shape.mesh
            v, f = decimate(np.asarray(m.vertices) - m.center_mass, np.asarray(m.faces))
            if skips_coacd(concavity(v, f), DEFAULT_SETTINGS):
                continue
            size = float(np.ptp(v, axis=0).max())
            line = f"seed {seed} {shape.name:22s} {len(f):5d} faces {1e3 * size:5.0f} mm"
            for name in names:
                params = asdict(replace(DEFAULT_SETTINGS, **VARIANTS[name]))
                del params["convex_tolerance"]
                t = time.process_time()
                parts = coacd.run_coacd(coacd.Mesh(v, f.astype(np.int32)), **params)
                cpu = time.process_time() - t
                uncovered, bloat = fit(v, f, parts)
                rows[name].append((cpu, len(parts), uncovered / size, bloat / size))
                line += f" | {name} {cpu:5.2f} s {len(parts):2d} hulls unc {100 * uncovered / size:.2f} % bloat {100 * bloat / size:.2f} %"
            print(line, flush=True)
    print()
    for name in names:
        a = np.array(rows[name])
        print(f"{name:8s} {len(a)} shapes: CoACD CPU {a[:, 0].sum():7.1f} s, hulls {a[:, 1].mean():.1f} on average, "
              f"uncovered p99/size median {100 * np.median(a[:, 2]):.3f} % max {100 * a[:, 2].max():.3f} %, "
              f"bloat p99/size median {100 * np.median(a[:, 3]):.3f} % max {100 * a[:, 3].max():.3f} %")
    base = np.array(rows[names[0]])[:, 0].sum()
    for name in names[1:]:
        print(f"{name} / {names[0]} CPU: {np.array(rows[name])[:, 0].sum() / base:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
