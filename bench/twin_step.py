"""Simulation speed of the twin with N objects, resting and pushed, and the levers that set it.

    .venv/bin/python bench/twin_step.py [--objects 1,5,10,20] [--json] [--seconds 2]

Objects are the first N of scenes/data/clutter20.toml (estimated from 30k-point clouds, CoACD cached on
disk). "Pushed": the end effector sweeps through the first row of objects for 3 s. Steps/s counts one
Python-driven ``mj_step`` per iteration with the mocap target set each time: the haptic loop's shape.

The second table changes one lever at a time on the 20-object scene against the baseline the issue calls
naive (CoACD's fine settings: threshold 0.05, no hull cap, 256 vertices per hull; no sleeping), all in this
process. Accuracy columns: collision volume excess (sum of hull volumes over the mesh volume, minus 1),
resting drift (how far objects creep in 2 s of rest: contact quality), and push difference (median over
the pushed row of final-position distance to the baseline: what the lever changes in an interaction;
objects knocked into each other make this chaotic, so read it as an order of magnitude). The naive
baseline keeps our short MCTS search: CoACD's own (150 iterations) takes about a minute per object.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from estimation.inertia import signed_volumes
from scenes.scenefile import SceneSpec, load_scene
from scenes.sources import estimate_object, prepare_objects
from twin.decompose import DEFAULT_SETTINGS, CoacdSettings
from twin.model import DEFAULT_PHYSICS, PhysicsSettings, add_object
from twin.objects import TwinObject
from twin.sim import Twin
from twin.trajectory import push_trajectory

PUSH_SECONDS = 3.0
NAIVE_COACD = replace(DEFAULT_SETTINGS, threshold=0.05, max_convex_hull=-1, max_ch_vertex=256, convex_tolerance=0.0)


@dataclass(frozen=True)
class Run:
    objects: int
    hulls: int
    rest_steps_per_s: float
    push_steps_per_s: float
    rest_drift_mm: tuple[float, float]  # median, max
    push_final: dict[str, np.ndarray]
    hull_excess_pct: float


def measure(scene: SceneSpec, objects: list[TwinObject], physics: PhysicsSettings, seconds: float,
            maxhullvert: int | None = None) -> Run:
    spec = scene.empty_spec(physics)
    for obj in objects:
        add_object(spec, obj)
    if maxhullvert is not None:
        for mesh in spec.meshes:
            if "/hull" in mesh.name:
                mesh.maxhullvert = maxhullvert
    rest = _rest(spec, objects, seconds)
    push, final = _push(spec, objects)
    excess = [sum(float(signed_volumes(v[f]).sum()) for v, f in o.hulls) / float(signed_volumes(
        o.visual[0][o.visual[1]]).sum()) - 1 for o in objects]
    return Run(len(objects), sum(len(o.hulls) for o in objects), rest[0], push, rest[1], final,
               100 * float(np.mean(excess)))


def _rest(spec, objects: list[TwinObject], seconds: float) -> tuple[float, tuple[float, float]]:  # type: ignore[no-untyped-def]
    with Twin(spec) as twin:
        twin.step(500)  # settle the placement gap
        start = {o.id: twin.pose(o.id)[0] for o in objects}
        hold = twin.data.mocap_pos[0].copy()
        n = round(seconds / twin.model.opt.timestep)
        t0 = time.perf_counter()
        for _ in range(n):
            twin.set_end_effector(hold)
            twin.step()
        rate = n / (time.perf_counter() - t0)
        drift = [float(np.linalg.norm(twin.pose(o.id)[0] - start[o.id])) for o in objects]
    return rate, (1e3 * float(np.median(drift)), 1e3 * max(drift))


def _push(spec, objects: list[TwinObject]) -> tuple[float, dict[str, np.ndarray]]:  # type: ignore[no-untyped-def]
    row_y = float(objects[0].position[1])
    z = float(min(o.position[2] for o in objects[:5]))
    path = push_trajectory(np.array([-0.7, row_y, z]), np.array([0.7, row_y, z]), PUSH_SECONDS)
    with Twin(spec) as twin:
        twin.set_end_effector(path(0.0))
        twin.data.qpos[:3] = path(0.0)  # start the end effector at its target, not flying to it
        n = round(PUSH_SECONDS / twin.model.opt.timestep)
        t0 = time.perf_counter()
        for _ in range(n):
            twin.set_end_effector(path(twin.time))
            twin.step()
        rate = n / (time.perf_counter() - t0)
        final = {o.id: twin.pose(o.id)[0] for o in objects}
    return rate, final


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--objects", default="1,5,10,20", help="comma-separated object counts (max 20)")
    parser.add_argument("--seconds", type=float, default=2.0, help="simulated seconds of rest per run")
    parser.add_argument("--json", action="store_true", help="one JSON object per line, no tables")
    parser.add_argument("--no-levers", action="store_true", help="skip the lever table")
    args = parser.parse_args(argv)
    counts = [int(c) for c in args.objects.split(",")]
    console = Console(stderr=args.json, width=200)
    scene = load_scene(str(resources.files("scenes").joinpath("data/clutter20.toml")))
    if max(counts) > len(scene.objects):
        parser.error(f"--objects: the scene has {len(scene.objects)} objects")
    top = scene.table.height if scene.table else None

    estimates = [estimate_object(s) for s in scene.objects]

    def prepared(coacd: CoacdSettings) -> list[TwinObject]:
        return prepare_objects(scene.objects, table_top=top, coacd=coacd, progress=not args.json,
                               estimates=estimates)

    ours, naive = prepared(DEFAULT_SETTINGS), prepared(NAIVE_COACD)
    baseline_physics = replace(DEFAULT_PHYSICS, sleep=False, table_plane=False)

    table = Table(title=f"twin steps/s by object count (clutter20, {args.seconds:g} s rest, {PUSH_SECONDS:g} s push)")
    for col in ("objects", "hulls", "rest steps/s", "pushed steps/s", "naive rest", "naive pushed", "ratio pushed"):
        table.add_column(col, justify="right")
    for n in counts:
        run = measure(scene, ours[:n], DEFAULT_PHYSICS, args.seconds)
        base = measure(scene, naive[:n], baseline_physics, args.seconds)
        ratio = run.push_steps_per_s / base.push_steps_per_s
        if args.json:
            print(json.dumps({"objects": n, "steps_per_s": round(min(run.rest_steps_per_s, run.push_steps_per_s)),
                              "rest_steps_per_s": round(run.rest_steps_per_s),
                              "pushed_steps_per_s": round(run.push_steps_per_s), "hulls": run.hulls,
                              "naive_rest_steps_per_s": round(base.rest_steps_per_s),
                              "naive_pushed_steps_per_s": round(base.push_steps_per_s), "naive_hulls": base.hulls}),
                  flush=True)
        table.add_row(str(n), str(run.hulls), f"{run.rest_steps_per_s:,.0f}", f"{run.push_steps_per_s:,.0f}",
                      f"{base.rest_steps_per_s:,.0f}", f"{base.push_steps_per_s:,.0f}", f"{ratio:.1f}x")
    if not args.json:
        console.print(table)
    if args.no_levers or args.json:
        return 0

    n = max(counts)
    levers: list[tuple[str, list[TwinObject], PhysicsSettings, int | None]] = [
        ("naive: fine CoACD, no sleep (baseline)", naive, baseline_physics, None),
        ("our CoACD settings, no sleep", ours, baseline_physics, None),
        ("our CoACD settings, no sleep, the top a plane", ours, replace(baseline_physics, table_plane=True), None),
        ("  + sleep, the table's box (before twin.tabletop)", ours, replace(DEFAULT_PHYSICS, table_plane=False), None),
        ("  + sleep, the top a plane (default)", ours, DEFAULT_PHYSICS, None),
        ("  + sleep, 32 vertices per hull", ours, DEFAULT_PHYSICS, 32),
        ("  + sleep, 16 vertices per hull", ours, DEFAULT_PHYSICS, 16),
        ("  + sleep, one contact per pair (no multiccd)", ours, replace(DEFAULT_PHYSICS, multiccd=False), None),
        ("  + sleep, pyramidal cones", ours, replace(DEFAULT_PHYSICS, elliptic=False), None),
        ("  + sleep, 10 solver iterations", ours, replace(DEFAULT_PHYSICS, iterations=10), None),
    ]
    no_convex = prepared(replace(DEFAULT_SETTINGS, convex_tolerance=0.0))
    levers.insert(2, ("our CoACD, no near-convex shortcut, no sleep", no_convex, baseline_physics, None))
    runs = [(name, measure(scene, objs[:n], phys, args.seconds, hv)) for name, objs, phys, hv in levers]
    ref = runs[0][1]
    pushed_ids = [o.id for o in ours[:5]]
    lever_table = Table(title=f"levers, {n} objects: speed against accuracy (same process)")
    for col in ("setting", "hulls", "rest steps/s", "pushed steps/s", "x baseline (pushed)",
                "hull volume excess %", "rest drift mm (median / max)", "push diff mm (median)"):
        lever_table.add_column(col, justify="right" if col != "setting" else "left")
    for name, run in runs:
        diff = np.median([np.linalg.norm(run.push_final[i] - ref.push_final[i]) for i in pushed_ids])
        lever_table.add_row(name, str(run.hulls), f"{run.rest_steps_per_s:,.0f}", f"{run.push_steps_per_s:,.0f}",
                            f"{run.push_steps_per_s / ref.push_steps_per_s:.1f}", f"{run.hull_excess_pct:.1f}",
                            f"{run.rest_drift_mm[0]:.2f} / {run.rest_drift_mm[1]:.2f}", f"{1e3 * diff:.1f}")
    console.print(lever_table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
