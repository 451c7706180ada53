"""`twin estimate VIEW [VIEW ...] --support-plane auto` on ray-cast scans of one object at a time.

    .venv/bin/python bench/views.py              # 3 cameras; output in bench/results/views.txt
    .venv/bin/python bench/views.py --cameras 2  # output in bench/results/views_2cams.txt

Each object of the 20-object clutter is put alone on the table (its pose in the scene file), scanned
once by the camera ring of ``scenes.sensing.CameraSensor`` at the issue's sigma 1 mm (1280 x 720,
42 degrees vertical field of view). Two ways to hand the views over, points only (no depth images, so no
carving): "cropped", each camera's points within half the object's diagonal plus a centimetre
(horizontally) and above 0.70 m, as a user would crop them, the table's ring and edge included; and
"whole frames", every point each camera returned: the floor around the table, the table, the object. ``estimation.views.estimate_views``
finds the plane, cuts it, fuses, closes and estimates, as the CLI does. The volume is compared with the
true mesh's; the interval is the one the JSON reports.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's packages, not an installed copy

RESULTS = ROOT / "bench" / "results" / "views.txt"
CROP_MARGIN = 0.01  # metres beyond half the object's diagonal
CROP_FLOOR = 0.70  # metres: points below (the floor) are not in a user's crop of a table top


def scan_alone(scene, spec, cameras: int, crop: bool):  # type: ignore[no-untyped-def]
    """``spec`` put alone on ``scene``'s table (its pose in the scene file) and scanned once by ``cameras``
    cameras of the issue's sigma 1 mm condition: (views as :class:`estimation.views.View` points with their
    camera's origin, the object's reference estimate from its true mesh). ``crop``: each camera's points
    within half the object's diagonal plus :data:`CROP_MARGIN` (horizontally) and above :data:`CROP_FLOOR`."""
    from estimation.views import View
    from scenes import cameras as cams
    from scenes.remote import Remote
    from scenes.sensing import CameraSensor
    from scenes.sources import reference_estimate
    from sync.clock import SimClock
    from sync.inprocess import InProcessBus

    alone = dataclasses.replace(scene, objects=(spec,))
    clock = SimClock()
    remote = Remote(alone, InProcessBus(clock, {}).transport("remote"), clock=clock, publish=False)
    sensor = CameraSensor.for_scene(alone, cameras=cameras, seed=1, noise=cams.SIGMA_1MM, width=1280,
                                    height=720, fov_y_deg=42.0)
    scan = sensor._current(remote, force=True)
    ref = reference_estimate(spec)[0]
    centre = remote.twin.pose(spec.id)[0]
    remote.close()
    reach = float(np.linalg.norm(ref.obb.extents)) / 2 + CROP_MARGIN
    views = []
    for frame in scan.frames:
        pts = frame.points()[0]
        if crop:
            pts = pts[(np.linalg.norm(pts[:, :2] - centre[:2], axis=1) < reach) & (pts[:, 2] > CROP_FLOOR)]
        views.append(View(pts, np.asarray(frame.camera.position, float)))
    return views, ref


def run(cameras: int, crop: bool) -> list[tuple[str, float, bool, float, str]]:
    from estimation.errors import TwinError
    from estimation.views import estimate_views
    from scenes.scenefile import load_scene

    full = load_scene(ROOT / "scenes" / "data" / "clutter20.toml")
    rows = []
    for k, spec in enumerate(full.objects):
        views, ref = scan_alone(full, spec, cameras, crop)
        try:
            res = estimate_views(views, ref.mass.mass / ref.volume, support="auto")
            low, high = res.volume_bounds_m3
            note = ("no plane found" if any("no support plane" in w for w in res.warnings) else
                    "table under the first plane" if any("a table on the floor?" in w for w in res.warnings) else "")
            rows.append((spec.id, res.estimate.volume / ref.volume - 1, low <= ref.volume <= high, res.coverage, note))
        except TwinError as exc:
            rows.append((spec.id, float("nan"), False, 0.0, f"error: {exc}"))
        print(f"[{k + 1}/{len(full.objects)}] {spec.id}", file=sys.stderr, flush=True)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cameras", type=int, default=3)
    args = ap.parse_args()
    lines = [f"bench/views.py: clutter20's objects one at a time, {args.cameras} cameras, sigma 1 mm, "
             f"points only, --support-plane auto"]
    for crop in (True, False):
        t0 = time.perf_counter()
        rows = run(args.cameras, crop)
        lines += ["", "cropped around the object" if crop else "whole frames (floor, table, object)", "",
                  f"{'object':14s} {'volume %':>9s} {'in interval':>12s} {'coverage':>9s}  note"]
        for name, err, held, cov, note in rows:
            lines.append(f"{name:14s} {100 * err:+9.1f} {'yes' if held else 'NO':>12s} {cov:9.2f}  {note}")
        errs = np.abs([r[1] for r in rows]) * 100
        lines += ["", f"abs volume error: median {np.nanmedian(errs):.1f} %, max {np.nanmax(errs):.1f} %; "
                  f"interval holds the truth {sum(r[2] for r in rows)} of {len(rows)}; "
                  f"{time.perf_counter() - t0:.0f} s"]
    text = "\n".join(lines)
    print(text)
    out = RESULTS if args.cameras == 3 else RESULTS.with_name(f"views_{args.cameras}cams.txt")
    out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
