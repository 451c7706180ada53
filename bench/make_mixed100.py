"""Generate ``scenes/data/mixed100.toml``: 100 objects on one table, for timing ``twin build`` at scale.

    .venv/bin/python bench/make_mixed100.py          # rewrites the TOML and scenes/data/mixed100/*.pcd

The mix (seeded, so a re-run rewrites identical files): 40 primitive boxes and 32 cylinders (3-20 cm,
some lying down), the paper's 8 objects (20 cm to 1.2 m), all sampled at 20k points (the scene's
``points``, fewer than clutter20's 30k: bench/build.py prints every object's concavity, and the boxes'
and cylinders' stay under the near-convex tolerance), and 20 scanned shapes: :mod:`scenes.shapes` (every family but the 1-3 mm thin shells, which
3000 points cannot resolve), scaled to 5-20 cm, sampled at 3000 points with 0.5 mm Gaussian noise and no
normals, and stored as binary PCD (float32, 12 bytes a point: the 20 files are about 0.7 MB). Small
objects sit on a grid, the paper's on rows beside it; the generator checks that no two footprints
(the circle around each object's extent in x and y) overlap.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages, not an installed copy

from estimation.cloudfile import save_cloud
from scenes.paper_objects import NAMES, paper_object
from scenes.sampling import sample_surface
from scenes.shapes import make_shapes

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "data" / "mixed100.toml"
CLOUDS = "mixed100"  # folder beside the scene file
BOXES, CYLINDERS, SCANS = 40, 32, 20
PRIMITIVE_POINTS, SCAN_POINTS, SCAN_NOISE_M = 20_000, 3_000, 0.0005
PITCH_M, GAP_M, TABLE_HEIGHT_M = 0.32, 0.05, 0.75
BOX_MATERIALS = ("cardboard", "wood_pine", "abs_plastic", "polypropylene", "cork", "brick")
CYLINDER_MATERIALS = ("steel", "aluminium", "glass", "ceramic", "water", "polyethylene_hd")
SCAN_MATERIALS = ("pla_plastic", "abs_plastic", "wood_oak", "ceramic", "rubber")
PAPER_MATERIALS = ("wood_pine", "aluminium", "abs_plastic", "rubber", "granite", "ceramic", "concrete", "mdf")


def _footprint_radius(extents_xy: tuple[float, float]) -> float:
    """Radius (m) of the circle around a footprint's rectangle: it holds the footprint at any yaw."""
    return 0.5 * math.hypot(*extents_xy)


def _primitives(rng: np.random.Generator) -> list[tuple[dict, float]]:
    """(object fields, footprint radius) for the boxes and cylinders."""
    out = []
    for i in range(BOXES):
        size = [round(float(x), 3) for x in rng.uniform(0.03, 0.2, 3)]
        lying = rng.random() < 0.2
        rot = [round(float(rng.uniform(-90, 90)), 1), 90.0 if lying else 0.0, 0.0]
        # lying: local X turns y into z; the footprint is x by z
        ext = (size[0], size[2]) if lying else (size[0], size[1])
        out.append(({"id": f"box_{i:02d}", "primitive": {"type": "box", "size": size},
                     "material": BOX_MATERIALS[i % len(BOX_MATERIALS)], "rotation_deg": rot,
                     "points": PRIMITIVE_POINTS}, _footprint_radius(ext)))
    for i in range(CYLINDERS):
        radius, height = round(float(rng.uniform(0.015, 0.06)), 3), round(float(rng.uniform(0.04, 0.2)), 3)
        lying = rng.random() < 0.25
        rot = [round(float(rng.uniform(-90, 90)), 1), 90.0 if lying else 0.0, 0.0]
        ext = (2 * radius, height) if lying else (2 * radius, 2 * radius)
        out.append(({"id": f"cylinder_{i:02d}", "primitive": {"type": "cylinder", "size": [radius, height]},
                     "material": CYLINDER_MATERIALS[i % len(CYLINDER_MATERIALS)], "rotation_deg": rot,
                     "points": PRIMITIVE_POINTS}, _footprint_radius(ext)))
    return out


def _scans(rng: np.random.Generator, folder: Path) -> list[tuple[dict, float]]:
    """Write the scanned shapes' clouds into ``folder``; (object fields, footprint radius) for each."""
    shapes = [s for s in make_shapes(60, seed=0) if s.family != "thin"][:SCANS]
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for i, shape in enumerate(shapes):
        mesh = shape.mesh.copy()
        mesh.apply_translation(-mesh.bounds.mean(axis=0))  # the scanner's frame: centred on the object
        mesh.apply_scale(float(rng.uniform(0.05, 0.2)) / float(mesh.extents.max()))
        cloud = sample_surface(mesh, SCAN_POINTS, seed=rng, noise_sigma=SCAN_NOISE_M, with_normals=False)
        name = f"scan_{i:02d}_{shape.name.split('-')[1]}.pcd"
        save_cloud(cloud, folder / name)
        out.append(({"id": f"scan_{i:02d}", "cloud": f"{CLOUDS}/{name}",
                     "material": SCAN_MATERIALS[i % len(SCAN_MATERIALS)]},
                    _footprint_radius(tuple(mesh.extents[:2]))))
    return out


def _paper() -> list[tuple[dict, float]]:
    return [({"id": f"paper_{name}", "paper": name, "material": PAPER_MATERIALS[i], "points": PRIMITIVE_POINTS},
             _footprint_radius(tuple(paper_object(name).extents[:2]))) for i, name in enumerate(NAMES)]


def layout(small: list[tuple[dict, float]], large: list[tuple[dict, float]]) -> tuple[list[dict], tuple[float, float]]:
    """Small objects on a square grid, large ones in rows below it; returns the objects and the table's (x, y) m.

    Raises:
        ValueError: two footprints overlap (a generator bug, not a layout to accept).
    """
    cols = math.ceil(math.sqrt(len(small)))
    if max(r for _, r in small) * 2 + GAP_M > PITCH_M:
        raise ValueError("a small object is wider than the grid pitch")
    width = cols * PITCH_M
    placed: list[tuple[dict, float, float, float]] = []
    for k, (obj, r) in enumerate(small):
        placed.append((obj, (k % cols + 0.5) * PITCH_M, (k // cols + 0.5) * PITCH_M, r))
    y = math.ceil(len(small) / cols) * PITCH_M
    x, row_depth = 0.0, 0.0
    for obj, r in large:
        if x + 2 * r > width and x > 0:
            x, y, row_depth = 0.0, y + row_depth + GAP_M, 0.0
        placed.append((obj, x + r, y + r, r))
        x += 2 * r + GAP_M
        row_depth = max(row_depth, 2 * r)
    depth = y + row_depth
    for i, (_, xi, yi, ri) in enumerate(placed):
        for _, xj, yj, rj in placed[:i]:
            if math.hypot(xi - xj, yi - yj) < ri + rj:
                raise ValueError("footprints overlap")
    objects = []
    for obj, xi, yi, _ in placed:  # centre the layout on the table
        objects.append({**obj, "position": [round(xi - width / 2, 3), round(yi - depth / 2, 3)]})
    return objects, (round(width + 2 * GAP_M, 2), round(depth + 2 * GAP_M, 2))


def _toml_value(value: object) -> str:
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, str):
        return f'"{value}"'
    return repr(value)


def write_scene(path: Path = SCENE, seed: int = 15) -> Path:
    """Write the scene file and its clouds (beside it, in ``mixed100/``); the same seed, the same files."""
    rng = np.random.default_rng(seed)
    small = _primitives(rng) + _scans(rng, path.parent / CLOUDS)
    small = [small[i] for i in rng.permutation(len(small))]  # mixed kinds side by side, and in build order
    objects, (tx, ty) = layout(small, _paper())
    lines = [
        f"# Generated by bench/make_mixed100.py (seed {seed}); do not edit by hand, re-run it.",
        f"# {BOXES} boxes and {CYLINDERS} cylinders (sampled at {PRIMITIVE_POINTS} points), the paper's "
        f"{len(NAMES)} objects, {SCANS} scanned shapes",
        f"# ({SCAN_POINTS}-point clouds with {SCAN_NOISE_M * 1000:g} mm noise in {CLOUDS}/): `twin build` at scale "
        "(bench/build.py).",
        'name = "mixed100"',
        "",
        "[table]",
        f"size = [{tx}, {ty}, 0.05]",
        f"height = {TABLE_HEIGHT_M}",
        'material = "wood_oak"',
        "",
        "[end_effector]",
        "radius = 0.02",
        f"position = [{-tx / 2 + 0.05:.2f}, {-ty / 2 + 0.05:.2f}, {TABLE_HEIGHT_M + 0.1:.2f}]",
    ]
    for obj in objects:
        lines += ["", "[[objects]]", *(f"{k} = {_toml_value(v)}" for k, v in obj.items())]
    path.write_text("\n".join(lines) + "\n")
    return path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=SCENE, help="scene file to write (clouds go beside it)")
    p.add_argument("--seed", type=int, default=15)
    args = p.parse_args(argv)
    path = write_scene(args.out, args.seed)
    print(f"wrote {path} and {path.parent / CLOUDS}/")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
