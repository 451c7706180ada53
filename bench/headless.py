"""Headless sessions: remote and twin in one process on the simulated clock, as a multiple of real time.

For each scene: build the session (remote settles and publishes; the twin estimates every cloud in its own
thread), then push the end effector across the table for ``--seconds`` simulated seconds while both sides
step. Reports the set-up time, the stepping time, and simulated seconds per wall second (the "x real time"
column; 1.0 means as fast as the live 1 kHz loops). The same session run twice must give identical poses
(checked here too; ``tests/test_headless.py`` asserts it).

    .venv/bin/python bench/headless.py [--seconds 10] [--scenes small paper_table clutter20]
"""

from __future__ import annotations

import argparse
import sys
import time
from importlib import resources
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages, not an installed copy

from scenes.headless import Headless
from scenes.scenefile import load_scene
from twin.trajectory import push_trajectory

SCENES = {
    "small": Path(__file__).resolve().parent.parent / "tests" / "data" / "small.toml",
    "paper_table": Path(str(resources.files("scenes").joinpath("data/paper_table.toml"))),
    "clutter20": Path(str(resources.files("scenes").joinpath("data/clutter20.toml"))),
}


def session(path: Path, seconds: float, cache: Path) -> dict:
    t0 = time.perf_counter()
    with Headless(load_scene(path), cache_dir=cache) as s:
        s.tick()  # the twin takes in every estimated object at its first tick
        t1 = time.perf_counter()
        start, tw = s.local.twin.data.mocap_pos[0].copy(), s.local.twin.time
        push = push_trajectory(start, start + np.array([2.2, 0.0, -0.12]), seconds, start_time=tw)
        s.run(seconds, trajectory=push)
        t2 = time.perf_counter()
        gaps = [float(np.linalg.norm(p[0] - s.remote.twin.pose(i)[0])) for i, p in s.poses().items()]
        return {"objects": len(s.local.objects), "setup_s": t1 - t0, "run_s": t2 - t1, "sim_s": seconds,
                "poses": np.concatenate([np.concatenate(p) for _, p in sorted(s.poses().items())]),
                "max_gap_mm": 1e3 * max(gaps, default=0.0), "messages": s.bus.published, "bytes": s.bus.bytes}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=10.0, help="simulated seconds of pushing (default 10)")
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    ap.add_argument("--cache-dir", type=Path, default=Path(".cache/bench-headless"),
                    help="CoACD cache (warm after the first run)")
    args = ap.parse_args()
    table = Table(title=f"headless sessions: {args.seconds:g} s of pushing, remote + twin in one process")
    for col in ("scene", "objects", "set-up s", "stepping s", "x real time", "repeat identical",
                "max |C'-C| mm", "messages", "bytes"):
        table.add_column(col, justify="right")
    for name in args.scenes:
        a = session(SCENES[name], args.seconds, args.cache_dir)
        b = session(SCENES[name], args.seconds, args.cache_dir)
        same = a["poses"].tobytes() == b["poses"].tobytes()
        table.add_row(name, str(a["objects"]), f"{a['setup_s']:.1f}", f"{a['run_s']:.2f}",
                      f"{a['sim_s'] / a['run_s']:.1f}", "yes" if same else "NO", f"{a['max_gap_mm']:.1f}",
                      f"{a['messages']:,}", f"{a['bytes']:,}")
    Console(width=160).print(table)


if __name__ == "__main__":
    main()
