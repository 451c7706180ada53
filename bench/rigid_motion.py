"""Issue 13's invariance: the same views under a rigid motion (their cameras moved along) give the same volume
within 0.5 %.

    .venv/bin/python bench/rigid_motion.py [--motions 4] [--tables 8 9] [--out bench/results/rigid_motion.txt]

Each object is put alone on the table and scanned once by 1, 2 and 3 cameras of the issue's sigma 1 mm
condition, its views cropped round it as a user would (``bench/views.py``'s ``scan_alone``): the 20 objects of
clutter20, and the 10 generated shapes of each random tabletop ``--tables`` names (``bench/camera_tables.py``'s
``write_scene``; seeds 8 and 9 were first drawn for this bench). The views are estimated as
``twin estimate VIEW ... --support-plane auto`` does (``estimation.views.estimate_views``), then again after each
of ``--motions`` seeded random rigid motions (a uniformly random rotation and a shift of up to 2 m on each axis,
applied to every point and every camera origin). The spread of an object is the largest
``|volume after / volume before - 1|`` over its motions; the table gives its median, p90 and max over objects,
and how many pass the issue's 0.5 %. Objects whose views hold no support plane (in any pose) are listed apart:
``auto`` then assumes the horizontal plane through the lowest point, world z up, which no rotation carries along
(docs/cli.md says so and asks for the plane to be given); for them the spread with the table's plane given
(``--support-plane A B C D``, moved along) is listed beside.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's packages, not an installed copy
sys.path.insert(0, str(ROOT / "bench"))

from camera_tables import write_scene  # noqa: E402
from views import scan_alone  # noqa: E402

RESULTS = ROOT / "bench" / "results" / "rigid_motion.txt"
LIMIT = 0.005  # the 0.5 %
SHIFT = 2.0  # metres, each axis
#: An object whose views hold no support plane in some pose: ``auto`` then falls back to a horizontal plane (world
#: z up, documented in docs/cli.md), which a rotation does not carry along. Listed, not counted.
FELL_BACK = "no support plane in the data (auto's fallback follows the world's z)"


def moved(views, rot: np.ndarray, shift: np.ndarray):  # type: ignore[no-untyped-def]
    """``views`` carried by the rigid motion ``x -> rot x + shift``: points and camera origins alike."""
    from estimation.views import View

    return [View(v.points @ rot.T + shift, np.asarray(v.origin, float) @ rot.T + shift) for v in views]


def _no_plane(warnings) -> bool:  # type: ignore[no-untyped-def]
    return any("no support plane in the data" in w for w in warnings)


def _worst(views, density: float, motions: int, rng: np.random.Generator,  # type: ignore[no-untyped-def]
           top: float | None = None) -> tuple[float, bool]:
    """(largest relative volume change over ``motions`` rigid motions, whether ``auto`` found no plane in any
    pose). ``top``: the support plane given instead of ``auto``, the table's top at that height (world z up),
    moved along with the views."""
    from scipy.spatial.transform import Rotation

    from estimation.views import estimate_views

    def estimate(rot: np.ndarray, shift: np.ndarray):  # type: ignore[no-untyped-def]
        support: str | tuple[float, ...] = "auto"
        if top is not None:
            normal = rot[:, 2]  # the plane's normal (0, 0, 1) turned
            support = (*normal, -float(normal @ (rot @ np.array([0.0, 0.0, top]) + shift)))
        return estimate_views(moved(views, rot, shift), density, support=support)

    first = estimate(np.eye(3), np.zeros(3))
    base, fell_back, worst = first.estimate.volume, _no_plane(first.warnings), 0.0
    for _ in range(motions):
        res = estimate(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-SHIFT, SHIFT, 3))
        worst = max(worst, abs(res.estimate.volume / base - 1))
        fell_back |= _no_plane(res.warnings)
    return worst, fell_back


def spreads(scene, cameras: int, motions: int, seed: int, label: str) -> list[tuple[str, float, str]]:  # type: ignore[no-untyped-def]
    """(object id, largest relative volume change over ``motions`` rigid motions, note) for each object."""
    from estimation.errors import TwinError

    rows = []
    for k, spec in enumerate(scene.objects):
        views, ref = scan_alone(scene, spec, cameras, crop=True)
        density = ref.mass.mass / ref.volume
        try:
            worst, fell_back = _worst(views, density, motions, np.random.default_rng([seed, cameras, k]))
            note = ""
            if fell_back:  # the CLI's remedy, --support-plane A B C D: the table's top, carried along too
                given = _worst(views, density, motions, np.random.default_rng([seed, cameras, k]),
                               top=scene.table.height)[0]
                note = f"{FELL_BACK}; with the table's plane given: {100 * given:.3f} %"
            rows.append((spec.id, worst, note))
        except TwinError as exc:  # the same error before and after a motion is invariant too; said, not counted
            rows.append((spec.id, float("nan"), f"error: {exc}"))
        print(f"{label} {cameras} cam [{k + 1}/{len(scene.objects)}] {spec.id}", file=sys.stderr, flush=True)
    return rows


def main() -> int:
    from scenes.scenefile import load_scene

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--motions", type=int, default=4, help="random rigid motions per object (default 4)")
    ap.add_argument("--tables", type=int, nargs="*", default=[8, 9], help="random tabletop seeds (default 8 9)")
    ap.add_argument("--cameras", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()
    t0 = time.perf_counter()
    lines = [f"bench/rigid_motion.py: each object alone, scanned once at sigma 1 mm, views cropped; volume spread "
             f"over {args.motions} random rigid motions (points and camera origins moved along, --support-plane "
             f"auto); the issue asks <= {100 * LIMIT:g} %", ""]
    header = (f"{'scene':10s} {'cams':>4s} {'objects':>7s} | {'spread % median':>15s} {'p90':>6s} {'max':>6s} | "
              f"{'within 0.5 %':>12s} | worst object")
    lines += [header, "-" * len(header)]
    detail = []
    with tempfile.TemporaryDirectory() as tmp:
        scenes = [("clutter20", load_scene(ROOT / "scenes" / "data" / "clutter20.toml"))]
        for seed in args.tables:
            folder = Path(tmp) / f"table{seed}"
            folder.mkdir()
            scenes.append((f"table{seed}", load_scene(write_scene(folder, seed)[0])))
        for label, scene in scenes:
            for cameras in args.cameras:
                rows = spreads(scene, cameras, args.motions, 0, label)
                counted = [r for r in rows if np.isfinite(r[1]) and not r[2]]
                ok = np.array([r[1] for r in counted])
                worst = max(counted, key=lambda r: r[1], default=("-", np.nan, ""))
                if not len(ok):
                    lines.append(f"{label:10s} {cameras:4d} {0:7d} | (no object counted)")
                    continue
                lines.append(f"{label:10s} {cameras:4d} {len(ok):7d} | {100 * np.median(ok):15.3f} "
                             f"{100 * np.percentile(ok, 90):6.3f} {100 * ok.max():6.3f} | "
                             f"{int((ok <= LIMIT).sum()):5d} of {len(ok):<3d} | {worst[0]} ({100 * worst[1]:.3f} %)")
                detail += [f"  {label} {cameras} cam {name}: {'-' if not np.isfinite(v) else f'{100 * v:.3f} %'} {note}"
                           for name, v, note in rows if note or not np.isfinite(v) or v > LIMIT / 5]
    lines += ["", f"not counted above (no plane in the data, or the estimate failed), or past a fifth of the limit "
              f"(0.1 %): {len(detail)}", *detail,
              "", f"{time.perf_counter() - t0:.0f} s"]
    text = "\n".join(lines)
    print(text)
    args.out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
