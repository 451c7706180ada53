"""How far from convex are reconstructed objects? The measurement behind ``CoacdSettings.convex_tolerance``.

    .venv/bin/python bench/convexity.py            # about a minute of CPU; writes bench/results/convexity.txt

For each object, the twin's visual mesh (estimated from a sampled cloud, then decimated, as ``twin build``
does) is measured with :func:`twin.decompose.concavity` (widest gap between its convex hull and it, over its
largest extent) and,
for comparison, the hull's volume ratio (hull volume / mesh volume - 1). The truth is the same measure on
the true mesh. Two sets that the threshold was not chosen on together: the shapes of ``scenes/shapes.py``
at seed 1 (not the seed-0 shapes the mixed100 scene scans), 30k clean points and 3k points with 0.5 mm
noise; and boxes, cylinders, spheres and capsules of 2-25 cm at 8k and 30k points (seeded).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages, not an installed copy

from estimation import estimate
from estimation.inertia import signed_volumes
from scenes.sampling import sample_surface
from scenes.shapes import make_shapes
from twin.decompose import DEFAULT_SETTINGS, concavity
from twin.objects import visual_mesh

RESULTS = Path(__file__).parent / "results" / "convexity.txt"
#: A true mesh is convex when its hull adds less than this to its volume (faceting and rounding only).
CONVEX_TRUTH = 1e-6


def volume_excess(v: np.ndarray, f: np.ndarray) -> float:
    from estimation.hull import convex_hull

    hv, hf = convex_hull(v)
    return float(signed_volumes(hv[hf]).sum() / signed_volumes(v[f]).sum() - 1)


def primitives(rng: np.random.Generator, count: int) -> list[tuple[str, trimesh.Trimesh]]:
    out = []
    for i in range(count):
        kind = ("box", "cylinder", "sphere", "capsule")[i % 4]
        a, b, c = rng.uniform(0.02, 0.25, 3)
        mesh = {"box": lambda: trimesh.creation.box(extents=(a, b, c)),  # noqa: B023
                "cylinder": lambda: trimesh.creation.cylinder(radius=a / 2, height=b, sections=64),  # noqa: B023
                "sphere": lambda: trimesh.creation.icosphere(subdivisions=3, radius=a / 2),  # noqa: B023
                "capsule": lambda: trimesh.creation.capsule(height=b, radius=a / 4, count=[32, 32])}[kind]()  # noqa: B023
        out.append((f"{kind}-{i:02d}", mesh))
    return out


def measure(name: str, mesh: trimesh.Trimesh, points: int, noise: float, seed: int) -> dict:
    cloud = sample_surface(mesh, points, seed=seed, noise_sigma=noise, with_normals=noise == 0)
    est = estimate(cloud, 1000.0)
    v, f = visual_mesh(est)
    return {"name": name, "points": points, "noise": noise, "true": concavity(mesh.vertices, mesh.faces),
            "true_excess": volume_excess(mesh.vertices, mesh.faces), "est": concavity(v, f),
            "est_excess": volume_excess(v, f)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--shapes", type=int, default=44)
    p.add_argument("--primitives", type=int, default=24)
    args = p.parse_args(argv)
    rows = []
    for i, s in enumerate(make_shapes(args.shapes, seed=1)):
        if s.family == "thin":  # 1-3 mm walls: below what these clouds resolve (bench/shapes.py)
            continue
        mesh = s.mesh.copy()
        mesh.apply_translation(-mesh.bounds.mean(axis=0))
        size = 0.05 + 0.15 * ((i * 0.618) % 1)  # 5-20 cm, spread evenly
        mesh.apply_scale(size / float(mesh.extents.max()))
        rows.append(measure(s.name, mesh, 30_000, 0.0, i))
        rows.append(measure(s.name, mesh, 3_000, 0.0005, i))
    for k, (name, mesh) in enumerate(primitives(np.random.default_rng(7), args.primitives)):
        rows.append(measure(name, mesh, (8_000, 30_000)[k // 4 % 2], 0.0, k))  # each kind at both counts
    lines = [f"{'object':26s} {'points':>7s} {'noise mm':>8s} {'true':>8s} {'est':>8s} {'true vol+':>9s} "
             f"{'est vol+':>9s}  (concavity = widest hull-to-mesh gap / largest extent; vol+ = hull volume / volume - 1)"]
    for r in sorted(rows, key=lambda r: (r["true"] > CONVEX_TRUTH, r["est"])):
        lines.append(f"{r['name']:26s} {r['points']:7d} {r['noise'] * 1000:8.1f} {r['true']:8.4f} {r['est']:8.4f} "
                     f"{r['true_excess']:9.3f} {r['est_excess']:9.3f}")
    convex = [r for r in rows if r["true_excess"] < CONVEX_TRUTH]
    concave = [r for r in rows if r["true_excess"] >= CONVEX_TRUTH]
    tol = DEFAULT_SETTINGS.convex_tolerance
    lines += [
        "",
        f"truly convex objects: {len(convex)}; estimated concavity max {max(r['est'] for r in convex):.4f}, "
        f"estimated volume excess max {max(r['est_excess'] for r in convex):.3f}",
        f"truly concave objects: {len(concave)}; estimated concavity min {min(r['est'] for r in concave):.4f}",
        f"convex_tolerance {tol}: convex objects skipping CoACD {sum(r['est'] <= tol for r in convex)}/{len(convex)}; "
        f"concave objects skipping it {sum(r['est'] <= tol for r in concave)}/{len(concave)} "
        f"(their true concavity: {', '.join(format(r['true'], '.4f') for r in concave if r['est'] <= tol) or '-'})",
    ]
    text = "\n".join(lines) + "\n"
    sys.stdout.write(text)
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(f"# .venv/bin/python bench/convexity.py --shapes {args.shapes} --primitives {args.primitives}\n"
                       + text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
