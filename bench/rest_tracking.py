"""Tracking at rest over many scans: how far each scan's noise moves a track, with and without averaging.

    .venv/bin/python bench/rest_tracking.py      # output in bench/results/rest_tracking.txt
    .venv/bin/python bench/rest_tracking.py --scans 4 --cameras 1
    .venv/bin/python bench/rest_tracking.py --seed 2 --out bench/results/rest_tracking_seed2.txt

The 20-object clutter settles; the rig (the issue's sigma 1 mm cameras at 1280 x 720, as bench/cameras.py)
observes every object once, then the scene is stepped one tracking period at a time (0.5 s) while nothing
touches it, and every object is tracked after each step, ``--scans`` times. Each track is compared with the
object's frame as first observed (nothing moved: the truth is no motion). Three trackers in the same process,
on the same scans: each scan's own fit (``rest_window=1``, the tracker before averaging); the running mean of
the fits at rest (``scenes.restfilter.REST_WINDOW``) onto a model of the first view alone (``refine=False``,
the tracker before the model gathered scans at rest); and the default, whose model gathers each scan while the
object rests and whose fits are polished by registering the segment onto it (``CameraSensor``'s ``refine``).
"corrections" counts the poses the remote would have published of objects that did not move: tracks that left
its deadband (1 mm, 0.5 degree) around the last one published.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's packages, not an installed copy

RESULTS = ROOT / "bench" / "results" / "rest_tracking.txt"
CAMERA = {"width": 1280, "height": 720, "fov_y_deg": 42.0}


def run(cameras: int, scans: int, rest_window: int | None, seed: int = 1, refine: bool = True) -> dict:
    """Tracks of every clutter20 object over ``scans`` periods at rest: errors (mm, deg) and corrections."""
    from scenes import cameras as cams
    from scenes.remote import Deadband, Remote
    from scenes.scenefile import load_scene
    from scenes.sensing import CameraSensor
    from sync.clock import SimClock
    from sync.inprocess import InProcessBus
    from twin.poses import angle_deg

    scene = load_scene(ROOT / "scenes" / "data" / "clutter20.toml")
    clock = SimClock()
    remote = Remote(scene, InProcessBus(clock, {}).transport("remote"), clock=clock, publish=False)
    sensor = CameraSensor.for_scene(scene, cameras=cameras, seed=seed, noise=cams.SIGMA_1MM, rest_window=rest_window,
                                    refine=refine, **CAMERA)
    sensor._current(remote, force=True)
    frames = {}
    for spec in scene.objects:
        seen = sensor.observe(remote, spec.id, 0, shot=1)
        if len(seen.points) >= 100:
            frames[spec.id] = seen.frame_position
    band = Deadband()
    identity = np.array([1.0, 0, 0, 0])
    published = {k: (frame, identity) for k, frame in frames.items()}
    mm = np.full((scans, len(frames)), np.nan)
    deg = np.full((scans, len(frames)), np.nan)
    corrections = 0
    t0 = time.perf_counter()
    for s in range(scans):
        remote.twin.step(round(sensor.track_period / remote.twin.model.opt.timestep) + 1)
        for j, (object_id, frame) in enumerate(frames.items()):
            tr = sensor.track(remote, object_id)
            mm[s, j] = 1000 * float(np.linalg.norm(tr.position - frame))
            deg[s, j] = angle_deg(tr.quat, identity)
            last_pos, last_quat = published[object_id]
            if (np.linalg.norm(tr.position - last_pos) > band.position
                    or angle_deg(tr.quat, last_quat) > band.angle_deg):
                corrections += 1
                published[object_id] = (tr.position, tr.quat)
    remote.close()
    worst = list(frames)[int(np.nanargmax(deg.max(axis=0)))]
    return {"mm": mm, "deg": deg, "corrections": corrections, "worst": worst, "seconds": time.perf_counter() - t0,
            "objects": len(frames)}


def main(argv: list[str] | None = None) -> int:
    from scenes.restfilter import REST_WINDOW

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    # 24: the mean of 8 fits reaches a bias in a few windows, not in one (a one-view model's dice, one camera,
    # noise seed 2: 0.97 degrees by scan 10, 1.35 by scan 24).
    parser.add_argument("--scans", type=int, default=24, help="tracking periods at rest (default 24: 12 s)")
    parser.add_argument("--cameras", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--seed", type=int, default=1, help="the cameras' noise draw (default 1)")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)

    table = Table(title=f"clutter20 at rest, sigma 1 mm cameras (noise seed {args.seed}), {args.scans} scans 0.5 s "
                        "apart: track error against the unmoved frame")
    for column in ("cameras", "tracker", "objects", "mm p50", "mm max", "deg p50", "deg max", "deg max, last scan",
                   "most turned", "corrections", "track s"):
        table.add_column(column, justify="right")
    for cameras in args.cameras:
        rows = {}
        for label, window, refine in (("each scan's fit, one view", 1, False),
                                      (f"mean of {REST_WINDOW}, one view", None, False),
                                      (f"mean of {REST_WINDOW}, gathered (default)", None, True)):
            r = rows[label] = run(cameras, args.scans, window, args.seed, refine)
            table.add_row(str(cameras), label, str(r["objects"]), f"{np.nanmedian(r['mm']):.2f}",
                          f"{np.nanmax(r['mm']):.2f}", f"{np.nanmedian(r['deg']):.2f}", f"{np.nanmax(r['deg']):.2f}",
                          f"{np.nanmax(r['deg'][-1]):.2f}", r["worst"], str(r["corrections"]), f"{r['seconds']:.1f}")
            print(f"[{cameras} camera(s), {label}] done", file=sys.stderr, flush=True)
    console = Console(record=True, width=170)
    console.print(table)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(console.export_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
