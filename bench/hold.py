"""What holding undisturbed objects at the remote's pose buys, and what it costs the twin's loop.

    .venv/bin/python bench/hold.py [--duration 10] [--rounds 2] [--objects 20] [--json]

1. Effect: ``twin demo`` (remote in a child process, twin here, Zenoh on loopback, the paper's eight
   objects) with the hold off and on, rounds alternating. |twin - remote| is sampled every 10 ms of twin
   time for every object from the moment it is in the twin; "stack" is the paper's stack, which C leaves
   resting on an edge where the twin's estimated hulls do not rest.
2. Cost: one twin of the first N objects of scenes/data/clutter20.toml, end effector pushing through the
   first row, unpaced; ``twin.step()`` alone, or ``hold.apply(twin)`` then ``twin.step()``, each timed,
   with every object's target at its rest pose and C silent (so pushed objects are released, then pinned
   back into the end effector's path: the busiest case; the physics then differs, so the step times do
   too). Same process, rounds alternating; the ratio is against the step with the hold off.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from importlib import resources
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cli.demo import run_demo
from scenes.build import build_scene
from scenes.scenefile import load_scene
from twin.hold import Hold
from twin.sim import Twin
from twin.trajectory import push_trajectory


def effect(duration: float, rounds: int) -> list[dict]:
    rows = []
    for r in range(rounds):
        for hold in (False, True):
            out = run_demo(duration=duration, hold=hold, progress=False)
            rows.append({"hold": hold, "round": r, "p50_mm": out["divergence_p50_mm"],
                         "p99_mm": out["divergence_p99_mm"], "max_mm": out["divergence_max_mm"],
                         "stack_max_mm": out["divergence_max_mm_by_object"].get("stack", float("nan")),
                         "snaps": out["snaps"], "holds": out["holds"], "step_p50_ms": out["step_p50_ms"],
                         "step_p99_ms": out["step_p99_ms"], "missed": out["missed_deadlines"],
                         "pose_updates": out["pose_updates"]})
    return rows


def cost(objects: int, steps: int, rounds: int) -> dict[str, list[float]]:
    """Seconds per call: mj_step without the hold, and hold.apply and mj_step with it."""
    scene = load_scene(Path(str(resources.files("scenes").joinpath("data/clutter20.toml"))))
    scene = type(scene)(**{**scene.__dict__, "objects": scene.objects[:objects]})
    built = build_scene(scene, progress=True)
    times: dict[str, list[float]] = {"step, hold off": [], "step, hold on": [], "hold.apply": []}
    for _ in range(rounds):
        for on in (False, True):
            with Twin(built.spec, built.model) as twin:
                twin.step(500)
                hold = Hold() if on else None
                if hold is not None:
                    for i in twin.object_ids():
                        hold.target(i, *twin.pose(i), np.zeros(3), np.zeros(3), now=twin.time)
                start = twin.data.mocap_pos[0].copy()
                push = push_trajectory(start, start + np.array([1.0, 0.0, -0.05]), steps * twin.model.opt.timestep)
                t0 = twin.time
                for _ in range(steps):
                    twin.set_end_effector(push(twin.time - t0))
                    t = time.perf_counter()
                    if hold is not None:
                        hold.apply(twin)
                        times["hold.apply"].append(time.perf_counter() - t)
                        t = time.perf_counter()
                    twin.step()
                    times["step, hold on" if on else "step, hold off"].append(time.perf_counter() - t)
    return times


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=10.0, help="seconds of pushing per demo run")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--objects", type=int, default=20, help="objects in the cost scene")
    ap.add_argument("--steps", type=int, default=3000, help="steps per cost run")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    console = Console(stderr=args.json, width=140)

    rows = effect(args.duration, args.rounds)
    times = cost(args.objects, args.steps, args.rounds)
    if args.json:
        print(json.dumps({"effect": rows, "cost_us": {k: [t * 1e6 for t in v] for k, v in times.items()}}))
        return 0

    t = Table(title=f"twin demo, {args.duration:g} s of pushing, |twin - remote| every 10 ms (all objects)")
    for col in ("hold", "round", "p50 mm", "p99 mm", "max mm", "stack max mm", "snaps", "holds", "pose updates",
                "step p50 ms", "step p99 ms", "missed"):
        t.add_column(col, justify="right")
    for r in rows:
        t.add_row("on" if r["hold"] else "off", str(r["round"]), f"{r['p50_mm']:.1f}", f"{r['p99_mm']:.1f}",
                  f"{r['max_mm']:.1f}", f"{r['stack_max_mm']:.1f}", str(r["snaps"]), str(r["holds"]),
                  str(r["pose_updates"]), f"{r['step_p50_ms']:.3f}", f"{r['step_p99_ms']:.3f}", str(r["missed"]))
    console.print(t)

    c = Table(title=f"cost per step, {args.objects} objects pushed, unpaced, {args.rounds} x {args.steps} steps")
    for col in ("call", "p50 us", "p99 us", "mean us", "mean x step (hold off)"):
        c.add_column(col, justify="right")
    base = float(np.mean(times["step, hold off"]))
    for name, v in times.items():
        a = np.asarray(v) * 1e6
        c.add_row(name, f"{np.percentile(a, 50):.0f}", f"{np.percentile(a, 99):.0f}", f"{a.mean():.0f}",
                  f"{np.mean(v) / base:.2f}")
    console.print(c)
    return 0


if __name__ == "__main__":
    sys.exit(main())
