"""Headless replay speed, as a multiple of real time: remote C and twin C' in one process, every object pushed.

For each scene: build the session (set-up, not timed in the ratio), then for ``--seconds`` simulated seconds
the end effector sweeps across the table while every object of C gets a seeded horizontal kick
(0.2-0.4 m/s) every 0.5 s, so nothing sleeps; the twin follows C's poses over the in-process bus. The ratio
is simulated seconds per wall second of stepping (1.0: as fast as the live 1 kHz loops; the issue's target
is 20x). "moving" is the mean fraction of C's objects faster than 1 cm/s over the run. With ``--profile``,
the clutter scene's stepping runs once more under cProfile and the top functions by own time are printed.

    .venv/bin/python bench/replay.py [--seconds 5] [--profile] | tee bench/results/replay.txt
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import time
from importlib import resources
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from scenes.headless import Headless
from scenes.scenefile import load_scene
from twin.trajectory import push_trajectory

SCENES = {
    "small": Path(__file__).resolve().parent.parent / "tests" / "data" / "small.toml",
    "clutter20": Path(str(resources.files("scenes").joinpath("data/clutter20.toml"))),
}

KICK_EVERY = 0.5  # seconds between kicks: sliding friction stops a 0.3 m/s object in well under a second


def _kick(session: Headless, rng: np.random.Generator) -> None:
    for object_id in sorted(session.remote.twin.object_ids()):
        angle, speed = rng.uniform(0, 2 * np.pi), rng.uniform(0.2, 0.4)
        session.remote.twin.set_velocity(object_id, speed * np.array([np.cos(angle), np.sin(angle), 0.0]),
                                         np.zeros(3))


def replay(path: Path, seconds: float, cache: Path, profile: cProfile.Profile | None = None) -> dict:
    t0 = time.perf_counter()
    with Headless(load_scene(path), cache_dir=cache) as s:
        s.tick()  # the twin takes in every estimated object at its first tick
        t1 = time.perf_counter()
        start, tw = s.local.twin.data.mocap_pos[0].copy(), s.local.twin.time
        push = push_trajectory(start, start + np.array([1.0, 0.6, -0.03]), seconds, start_time=tw)
        rng = np.random.default_rng(0)
        ids = sorted(s.remote.twin.object_ids())
        steps, kick_every, moving = round(seconds / s.dt), round(KICK_EVERY / s.dt), []
        if profile is not None:
            profile.enable()
        t2 = time.perf_counter()
        for k in range(steps):
            if k % kick_every == 0:
                _kick(s, rng)
            s.tick(push)
            if k % 50 == 25:
                moving.append(np.mean([np.linalg.norm(s.remote.twin.velocity(i)[0]) > 0.01 for i in ids]))
        t3 = time.perf_counter()
        if profile is not None:
            profile.disable()
        return {"objects": len(ids), "setup_s": t1 - t0, "run_s": t3 - t2, "sim_s": seconds,
                "moving": float(np.mean(moving)), "steps": steps}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=5.0, help="simulated seconds (default 5)")
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    ap.add_argument("--cache-dir", type=Path, default=Path(".cache/bench-headless"),
                    help="CoACD cache (warm after the first run)")
    ap.add_argument("--profile", action="store_true", help="profile the clutter scene's stepping (cProfile)")
    args = ap.parse_args()
    console = Console(width=140)
    table = Table(title=f"headless replay: {args.seconds:g} s simulated, remote + twin in one process, all pushed")
    for col in ("scene", "objects", "set-up s", "stepping s", "ticks/s", "moving", "x real time", "target"):
        table.add_column(col, justify="right")
    for name in args.scenes:
        r = replay(SCENES[name], args.seconds, args.cache_dir)
        ratio = r["sim_s"] / r["run_s"]
        table.add_row(name, str(r["objects"]), f"{r['setup_s']:.1f}", f"{r['run_s']:.2f}",
                      f"{r['steps'] / r['run_s']:,.0f}", f"{100 * r['moving']:.0f} %", f"{ratio:.1f}x",
                      "20x " + ("met" if ratio >= 20 else "NOT met"))
    console.print(table)
    if args.profile:
        prof = cProfile.Profile()
        replay(SCENES["clutter20"], min(args.seconds, 2.0), args.cache_dir, profile=prof)
        buf = io.StringIO()
        pstats.Stats(prof, stream=buf).sort_stats("tottime").print_stats(14)
        text = buf.getvalue()
        console.print("cProfile, clutter20 stepping, top functions by own time:")
        console.print(text[text.find("ncalls") - 1:].rstrip(), markup=False, highlight=False)


if __name__ == "__main__":
    main()
