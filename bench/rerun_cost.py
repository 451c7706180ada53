"""What rerun logging costs the twin's loop: rerun off vs on at several frame rates, same process.

    .venv/bin/python bench/rerun_cost.py [--objects 20] [--seconds 3] [--rounds 3] [--json]

The scene is the first N objects of scenes/data/clutter20.toml with the end effector pushing through the
first row (the haptic loop's shape: set the mocap target, one mj_step). Each configuration logs the
objects first (meshes, hulls, clouds, as ``twin run --rerun`` does), then poses and force at the given
rate to an .rrd file in a temporary directory, twice: paced at 1 kHz in real time (what an operator's
twin does: the loop's own work per step, and deadlines missed) and unpaced (throughput: the logging
thread then competes with a loop that never idles, the worst case). Rounds alternate the configurations
so machine noise hits all of them; the table shows the median over rounds. "close" is the time to drain
the logging thread's queue and flush the file when the run ends.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import replace
from importlib import resources
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from scenes.build import build_scene
from scenes.scenefile import load_scene
from twin.debuglog import OFF
from twin.rerunlog import RerunLog, RerunTarget
from twin.sim import Twin, run_paced
from twin.trajectory import push_trajectory

RATES = (None, 30.0, 100.0, 1000.0)  # None: rerun off


def run_once(built, rate: float | None, seconds: float, folder: Path, *,  # type: ignore[no-untyped-def]
             realtime: bool, settle: float = 0.0) -> dict:
    path = folder / f"bench-{rate}-{realtime}.rrd"
    rlog = OFF if rate is None else RerunLog.open(RerunTarget("save", str(path), rate_hz=rate))
    with Twin(built.spec) as twin:
        t = built.scene.table
        if t is not None:
            rlog.table(t.size, t.height)
        for obj in built.objects:
            rlog.object("twin", obj)
        time.sleep(settle)  # let the writer start and draw the objects: what follows is the steady state
        start = twin.data.mocap_pos[0].copy()
        push = push_trajectory(start, start + np.array([1.0, 0.0, -0.12]), seconds)
        stats = run_paced(twin, seconds, 1000.0, trajectory=push, realtime=realtime, rlog=rlog)
        t0 = time.perf_counter()
        rlog.close()
        close = time.perf_counter() - t0
    return {"rate_hz": rate, "us_per_step": stats.wall / stats.steps * 1e6, "p50_us": stats.p50 * 1e6,
            "p99_us": stats.p99 * 1e6, "max_us": stats.max * 1e6, "missed": stats.missed, "close_s": close,
            "items": rlog.logged, "dropped": rlog.dropped, "rrd_bytes": path.stat().st_size if path.exists() else 0}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--objects", type=int, default=20)
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--settle", type=float, default=3.0,
                        help="seconds between logging the objects and starting the loop (0: the start-up burst "
                             "falls into the measured loop)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()

    scene = load_scene(Path(str(resources.files("scenes").joinpath("data/clutter20.toml"))))
    scene = replace(scene, objects=scene.objects[: args.objects])
    built = build_scene(scene, progress=not args.json)
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for realtime in (True, False):
            runs: dict[float | None, list[dict]] = {r: [] for r in RATES}
            for k in range(args.rounds):
                for rate in RATES if k % 2 == 0 else RATES[::-1]:
                    runs[rate].append(run_once(built, rate, args.seconds, Path(tmp), realtime=realtime,
                                               settle=args.settle))
            rows = []
            for rate in RATES:
                med = {key: float(np.median([r[key] for r in runs[rate]])) for key in runs[rate][0] if key != "rate_hz"}
                rows.append({"rate_hz": rate, **med})
            for row in rows:
                row["ratio_to_off"] = row["us_per_step" if not realtime else "p99_us"] / rows[0]["us_per_step" if not realtime else "p99_us"]
            results["paced" if realtime else "unpaced"] = rows
    if args.json:
        print(json.dumps({"objects": args.objects, "seconds": args.seconds, "rounds": args.rounds, **results}))
        return 0
    console = Console()
    title = f"{args.objects} objects pushed for {args.seconds:g} s, median of {args.rounds} rounds"
    table = Table(title=f"paced at 1 kHz (real time): the loop's work per step, {title}")
    for col in ("rerun", "p50 us", "p99 us", "p99 x off", "max us", "missed", "items", "dropped", "close s", ".rrd MB"):
        table.add_column(col, justify="right")
    for r in results["paced"]:
        table.add_row(_rate(r), f"{r['p50_us']:.0f}", f"{r['p99_us']:.0f}", f"{r['ratio_to_off']:.2f}",
                      f"{r['max_us']:.0f}", f"{r['missed']:.0f}", f"{r['items']:.0f}", f"{r['dropped']:.0f}",
                      f"{r['close_s']:.2f}", f"{r['rrd_bytes'] / 1e6:.1f}")
    console.print(table)
    table = Table(title=f"unpaced (as fast as it goes): throughput, {title}")
    for col in ("rerun", "us/step", "x off", "p99 us", "max us"):
        table.add_column(col, justify="right")
    for r in results["unpaced"]:
        table.add_row(_rate(r), f"{r['us_per_step']:.1f}", f"{r['ratio_to_off']:.2f}", f"{r['p99_us']:.0f}",
                      f"{r['max_us']:.0f}")
    console.print(table)
    return 0


def _rate(row: dict) -> str:
    return "off" if row["rate_hz"] is None else f"{row['rate_hz']:g} Hz"

if __name__ == "__main__":
    sys.exit(main())
