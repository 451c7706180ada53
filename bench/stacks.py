"""The camera feed on objects stacked on one another: each object's volume from 2 and 3 cameras.

A stack hides what a lone object shows: the top of whatever stands under another, and the base of whatever
stands on another, which is not on the table. Eight stacks written by hand (cubes on cubes, three high, a
can and a ball on a box, a box off-centre on another, a book overhanging a box, and two boxes side by side
as a control) and ``--random`` more drawn from ``--seed`` (two or three levels: boxes, the top one a box, an
upright can or a ball, each smaller than what it stands on and anywhere on it). Cameras of bench/cameras.py's
sigma 1 mm condition (1280 x 720) scan each scene once; every object is segmented (the simulator's
segmentation image separates what touches), fused, closed, sent through the wire's codec and estimated, and
its volume is compared with the true one.

    .venv/bin/python bench/stacks.py [--random 10] [--seed 7] [--cameras 2 3] [--split-weight W]
        [--out bench/results/stacks.txt]

``--split-weight`` runs with another ``estimation.carving.SPLIT_VERTICAL_WEIGHT`` (how it was chosen).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from camera_tables import CAMERA  # noqa: E402
from cameras import run_scene  # noqa: E402

TABLE_HEIGHT = 0.5
GAP = 0.0005  # metres between one object and the one on it: each settles onto what is under it

#: (id, primitive type, size as a scene file takes it, [x, y, height of the centre above the table]).
Object = tuple[str, str, list[float], list[float]]


def _box(object_id: str, size: list[float], x: float, y: float, bottom: float) -> Object:
    return object_id, "box", size, [x, y, bottom + size[2] / 2]


def written() -> Iterator[tuple[str, list[Object]]]:
    yield "cube8_on_cube8", [_box("a", [0.08, 0.08, 0.08], 0, 0, 0), _box("b", [0.08, 0.08, 0.08], 0, 0, 0.08 + GAP)]
    yield "cube6_on_cube8", [_box("a", [0.08, 0.08, 0.08], 0, 0, 0), _box("b", [0.06, 0.06, 0.06], 0, 0, 0.08 + GAP)]
    yield "book_over_box", [_box("a", [0.10, 0.10, 0.10], 0, 0, 0), _box("b", [0.20, 0.15, 0.03], 0.02, 0, 0.10 + GAP)]
    yield "three_high", [_box("a", [0.10, 0.10, 0.10], 0, 0, 0), _box("b", [0.08, 0.08, 0.08], 0, 0, 0.10 + GAP),
                         _box("c", [0.05, 0.05, 0.05], 0, 0, 0.18 + 2 * GAP)]
    yield "ball_on_box", [_box("a", [0.10, 0.10, 0.05], 0, 0, 0), ("b", "sphere", [0.03], [0, 0, 0.08 + GAP])]
    yield "can_on_box", [_box("a", [0.12, 0.12, 0.04], 0, 0, 0), ("b", "cylinder", [0.03, 0.08], [0, 0, 0.08 + GAP])]
    yield "box_off_centre", [_box("a", [0.12, 0.08, 0.06], 0, 0, 0), _box("b", [0.06, 0.06, 0.04], 0.03, 0.01, 0.06 + GAP)]
    yield "side_by_side", [_box("a", [0.08, 0.08, 0.08], -0.0405, 0, 0), _box("b", [0.08, 0.06, 0.05], 0.0405, 0, 0)]


def drawn(count: int, seed: int) -> Iterator[tuple[str, list[Object]]]:
    rng = np.random.default_rng([seed, 11])
    for k in range(count):
        objects: list[Object] = []
        size = rng.uniform([0.06, 0.06, 0.03], [0.14, 0.14, 0.10])
        centre, bottom = rng.uniform(-0.05, 0.05, 2), 0.0
        levels = int(rng.integers(2, 4))
        for level in range(levels):
            if level:
                below = size
                kind = str(rng.choice(["box", "box", "cylinder", "sphere"])) if level == levels - 1 else "box"
                half = below[:2] / 2
                if kind == "box":
                    size = np.array([*(rng.uniform(0.4, 0.95, 2) * below[:2]), rng.uniform(0.03, 0.08)])
                    centre = centre + rng.uniform(-1, 1, 2) * (half - size[:2] / 2)
                elif kind == "cylinder":
                    r, h = float(half.min() * rng.uniform(0.4, 0.9)), float(rng.uniform(0.04, 0.1))
                    centre = centre + rng.uniform(-1, 1, 2) * (half - r)
                    objects.append((f"o{level}", kind, [round(r, 4), round(h, 4)],
                                    [*np.round(centre, 4).tolist(), round(bottom + GAP + h / 2, 4)]))
                    break
                else:
                    r = float(half.min() * rng.uniform(0.3, 0.8))
                    centre = centre + rng.uniform(-0.5, 0.5, 2) * (half - r)
                    objects.append((f"o{level}", kind, [round(r, 4)],
                                    [*np.round(centre, 4).tolist(), round(bottom + GAP + r, 4)]))
                    break
                bottom += GAP
            objects.append(_box(f"o{level}", np.round(size, 4).tolist(), *np.round(centre, 4).tolist(), round(bottom, 4)))
            bottom += float(np.round(size, 4)[2])
        yield f"drawn{seed}_{k}", objects


def scene_file(folder: Path, name: str, objects: list[Object]) -> Path:
    lines = [f'name = "{name}"', "[table]", "size = [1.0, 0.6, 0.04]", f"height = {TABLE_HEIGHT}"]
    for object_id, kind, size, (x, y, z) in objects:
        lines += ["[[objects]]", f'id = "{object_id}"', f'primitive = {{ type = "{kind}", size = {size} }}',
                  'material = "wood_pine"', f"position = [{x}, {y}, {round(TABLE_HEIGHT + z, 5)}]"]
    path = folder / f"{name}.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--random", type=int, default=10, help="stacks drawn at random (default 10)")
    ap.add_argument("--seed", type=int, default=7, help="their seed (default 7)")
    ap.add_argument("--cameras", type=int, nargs="+", default=[2, 3], choices=[1, 2, 3])
    ap.add_argument("--split-weight", type=float, default=None,
                    help="estimation.carving.SPLIT_VERTICAL_WEIGHT for this run (default: the module's)")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "stacks.txt")
    args = ap.parse_args()
    import estimation.carving

    if args.split_weight is not None:
        estimation.carving.SPLIT_VERTICAL_WEIGHT = args.split_weight
    weight = estimation.carving.SPLIT_VERTICAL_WEIGHT
    console = Console(record=True, width=160)
    per = Table(title=f"stacked objects, sigma 1 mm, 1280 x 720, split weight {weight:g}: signed volume error % "
                      f"per object, bottom first")
    for col in ("set", "stack", *(f"{k} cameras" for k in args.cameras)):
        per.add_column(col, justify="right")
    pooled: dict[tuple[str, int], list[float]] = {}
    with tempfile.TemporaryDirectory(prefix="stacks-") as tmp:
        for label, source in (("written", written()), ("drawn", drawn(args.random, args.seed))):
            for name, objects in source:
                path = scene_file(Path(tmp), name, objects)
                cells = []
                for cams in args.cameras:
                    errors = run_scene(path, cams, "SIGMA_1MM", CAMERA)["errors"]
                    pooled.setdefault((label, cams), []).extend(abs(100 * e) for e in errors.values())
                    cells.append(" ".join(f"{100 * errors[o[0]]:+.1f}" if o[0] in errors else "unseen" for o in objects))
                per.add_row(label, name, *cells)
                console.print(f"{name}: {cells[-1]}")
    console.print(per)
    summary = Table(title="|volume error| % over objects")
    for col in ("set", "cameras", "objects", "median", "max"):
        summary.add_column(col, justify="right")
    for (label, cams), errs in pooled.items():
        summary.add_row(label, str(cams), str(len(errs)), f"{np.median(errs):.1f}", f"{max(errs):.1f}")
    console.print(summary)
    args.out.write_text(console.export_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
