"""Headless replay speed, as a multiple of real time, and the twin's own stepping rate, against a baseline.

Two tables, each run for the current configuration, for the baseline (every object colliding with its
CoACD hulls and with the table's box: the configuration before ``twin.model`` substituted MuJoCo primitives)
and for the step between (primitives, the table's box: before ``twin.tabletop`` let objects wholly over the
table collide with its top as a plane), in this one process, so machine load hits all alike. Times are this
process's CPU time (``time.process_time``; the machine's two cores are shared) with wall time beside it.

1. The twin C' alone (clutter20, its model as the headless session built it from estimated clouds):
   steps/s (best of two runs) with every body awake (sleeping off, every object kicked at 0.2-0.4 m/s every 0.5 s, the end
   effector sweeping across the table), and at rest with sleeping on (as the twin runs).
2. Replay: remote C and twin C' in one process (:class:`scenes.headless.Headless`), for ``--seconds``
   simulated seconds, every object of C kicked the same way, the twin following C's poses over the
   in-process bus. "x real time" is simulated seconds per CPU second of stepping (1.0: as fast as the live
   1 kHz loops; the issue's target is 20x). "moving": the mean fraction of C's objects faster than 1 cm/s.
   "physics CPU s" is the part of it spent in the two sides' ``Twin.step`` (``mj_step`` and its checks), and
   "physics-only x" what the replay would reach if everything else took no time: the bound that Python work
   on the sync path can approach, not pass.

With ``--profile`` the clutter scene's replay runs once more under cProfile (top functions by cumulative
time; cProfile inflates Python against MuJoCo's C).
With ``--fills`` it prints, for clutter20 and the paper scene, each object's best-fitting primitive and
fill (estimated from its cloud and from its true mesh): the data behind ``twin.objects.PRIMITIVE_MIN_FILL``.

    .venv/bin/python bench/replay.py [--seconds 5] [--profile] [--fills] | tee bench/results/replay.txt
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import sys
import time
from collections.abc import Callable
from importlib import resources
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from scenes.headless import Headless
from scenes.scenefile import load_scene
from twin.model import COLLIDES
from twin.sim import Twin
from twin.tabletop import PLANE_NAME
from twin.trajectory import push_trajectory

SCENES = {
    "small": Path(__file__).resolve().parent.parent / "tests" / "data" / "small.toml",
    "clutter20": Path(str(resources.files("scenes").joinpath("data/clutter20.toml"))),
}

KICK_EVERY = 0.5  # seconds between kicks: sliding friction stops a 0.3 m/s object in well under a second


def box_table(spec) -> None:  # type: ignore[no-untyped-def]
    """Every object collides with the table's box: drop the top's plane (``twin.tabletop``)."""
    for geom in list(spec.geoms):
        if geom.name == PLANE_NAME:
            spec.delete(geom)


def meshes_only(spec) -> None:  # type: ignore[no-untyped-def]
    """The baseline collision: the table's box, and every ``<id>/primitive`` geom dropped and the hulls
    colliding again."""
    box_table(spec)
    for geom in list(spec.geoms):
        if geom.name.endswith("/primitive"):
            spec.delete(geom)
        elif "/hull" in geom.name:
            geom.contype, geom.conaffinity = COLLIDES, 1


CONFIGS: dict[str, Callable[[object], None] | None] = {"baseline (hulls)": meshes_only,
                                                        "primitives, table box": box_table, "current": None}


def _kick(twin: Twin, rng: np.random.Generator) -> None:
    for object_id in sorted(twin.object_ids()):
        angle, speed = rng.uniform(0, 2 * np.pi), rng.uniform(0.2, 0.4)
        twin.set_velocity(object_id, speed * np.array([np.cos(angle), np.sin(angle), 0.0]), np.zeros(3))


def _times() -> tuple[float, float]:
    return time.process_time(), time.perf_counter()


def twin_rates(spec, seconds: float, repeats: int = 2) -> dict[str, float]:  # type: ignore[no-untyped-def]
    """Steps per CPU second of ``spec``'s model, the best of ``repeats`` runs (the least disturbed by other
    processes): all awake (sleep off, kicked, pushed), and resting asleep (sleep on, after 1 s to settle)."""
    import mujoco

    awake = spec.copy()
    awake.option.enableflags &= ~int(mujoco.mjtEnableBit.mjENBL_SLEEP)
    out = {"awake": 0.0, "asleep": 0.0}
    for _ in range(repeats):
        with Twin(awake) as twin:
            start = twin.data.mocap_pos[0].copy()
            push = push_trajectory(start, start + np.array([1.0, 0.6, -0.03]), seconds, start_time=twin.time)
            rng, n = np.random.default_rng(0), round(seconds / twin.model.opt.timestep)
            kick_every = round(KICK_EVERY / twin.model.opt.timestep)
            c0 = time.process_time()
            for k in range(n):
                if k % kick_every == 0:
                    _kick(twin, rng)
                twin.set_end_effector(push(twin.time))
                twin.step()
            out["awake"] = max(out["awake"], n / (time.process_time() - c0))
        with Twin(spec.copy()) as twin:
            twin.step(1000)  # settle and fall asleep
            hold, n = twin.data.mocap_pos[0].copy(), round(seconds / twin.model.opt.timestep)
            c0 = time.process_time()
            for _ in range(n):
                twin.set_end_effector(hold)
                twin.step()
            out["asleep"] = max(out["asleep"], n / (time.process_time() - c0))
    return out


def replay(path: Path, seconds: float, cache: Path, config: Callable[[object], None] | None,
           profile: cProfile.Profile | None = None, rates: bool = False) -> dict:
    """One headless session of ``path``: set-up, then ``seconds`` of kicked, pushed replay (CPU and wall)."""
    c0, w0 = _times()
    with Headless(load_scene(path), cache_dir=cache) as s:
        s.tick()  # the twin takes in every estimated object at its first tick
        if config is not None:
            s.remote.twin.edit(config)
            s.local.twin.edit(config)
        setup_cpu = time.process_time() - c0
        twin_rate = twin_rates(s.local.twin.spec, min(seconds, 2.0)) if rates else {}
        start, tw = s.local.twin.data.mocap_pos[0].copy(), s.local.twin.time
        push = push_trajectory(start, start + np.array([1.0, 0.6, -0.03]), seconds, start_time=tw)
        rng = np.random.default_rng(0)
        ids = sorted(s.remote.twin.object_ids())
        physics = [0.0]  # CPU seconds inside either side's Twin.step
        for twin in (s.remote.twin, s.local.twin):
            twin.step = _timed(twin.step, physics)  # type: ignore[method-assign]
        steps, kick_every, moving = round(seconds / s.dt), round(KICK_EVERY / s.dt), []
        if profile is not None:
            profile.enable()
        c2, w2 = _times()
        for k in range(steps):
            if k % kick_every == 0:
                _kick(s.remote.twin, rng)
            s.tick(push)
            if k % 50 == 25:
                moving.append(np.mean([np.linalg.norm(s.remote.twin.velocity(i)[0]) > 0.01 for i in ids]))
        c3, w3 = _times()
        if profile is not None:
            profile.disable()
        return {"objects": len(ids), "setup_cpu_s": setup_cpu, "setup_wall_s": time.perf_counter() - w0,
                "run_cpu_s": c3 - c2, "run_wall_s": w3 - w2, "sim_s": seconds, "moving": float(np.mean(moving)),
                "physics_cpu_s": physics[0],
                "steps": steps, **{f"twin_{k}": v for k, v in twin_rate.items()}}


def _timed(step: Callable[..., None], total: list[float]) -> Callable[..., None]:
    """``step`` adding its CPU time to ``total[0]`` (two clock reads a call: about a microsecond)."""

    def timed(*args: object, **kwargs: object) -> None:
        c0 = time.process_time()
        step(*args, **kwargs)
        total[0] += time.process_time() - c0

    return timed


def fills(console: Console, cache: Path) -> None:
    """Each object's best primitive, fill and misfit, estimated and true (clutter20 and the paper scene)."""
    from scenes.sources import estimate_object, prepare_objects, reference_estimate
    from twin.objects import PRIMITIVE_MAX_MISFIT, PRIMITIVE_MIN_FILL, collision_primitive

    table = Table(title=f"best primitive, fill (object volume / primitive volume; accepted in "
                        f"[{PRIMITIVE_MIN_FILL:g}, {1 / PRIMITIVE_MIN_FILL:.3f}]) and misfit (at most "
                        f"{PRIMITIVE_MAX_MISFIT:g})")
    for col in ("scene", "object", "estimated", "fill", "misfit", "true mesh", "fill ", "misfit "):
        table.add_column(col, justify="right")
    for name in ("clutter20", "paper_table"):
        scene = load_scene(str(resources.files("scenes").joinpath(f"data/{name}.toml")))
        top = scene.table.height if scene.table else None
        sides = [prepare_objects(scene.objects, table_top=top, cache_dir=cache, progress=False,
                                 estimates=[make(s) for s in scene.objects])
                 for make in (estimate_object, reference_estimate)]
        for est, ref in zip(*sides, strict=True):
            row = [name, est.id]
            for obj in (est, ref):
                # The fit used, or the best one refused.
                fit = collision_primitive(obj)
                ok = fit is not None
                fit = fit or collision_primitive(obj, min_fill=1e-9, max_misfit=float("inf"))
                row += ([f"{fit.kind}{'' if ok else ' (no)'}", f"{fit.fill:.3f}", f"{fit.misfit:.3f}"] if fit
                        else ["-", "-", "-"])
            table.add_row(*row)
    console.print(table)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=5.0, help="simulated seconds (default 5)")
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    ap.add_argument("--cache-dir", type=Path, default=Path(".cache/bench-headless"),
                    help="CoACD cache (warm after the first run)")
    ap.add_argument("--profile", action="store_true", help="profile the clutter scene's stepping (cProfile)")
    ap.add_argument("--fills", action="store_true", help="print each object's primitive fit (slow: estimates)")
    args = ap.parse_args()
    console = Console(width=200)  # the replay table has 14 columns
    runs = {(name, label): replay(SCENES[name], args.seconds, args.cache_dir, config, rates=name == "clutter20")
            for name in args.scenes for label, config in CONFIGS.items()}
    base_label = next(iter(CONFIGS))

    if "clutter20" in args.scenes:
        table = Table(title="twin C' alone, clutter20: steps per CPU second")
        for col in ("configuration", "all awake steps/s", "resting, asleep steps/s", "awake x baseline",
                    "target 10k awake"):
            table.add_column(col, justify="right")
        base = runs["clutter20", base_label]
        for label in CONFIGS:
            r = runs["clutter20", label]
            table.add_row(label, f"{r['twin_awake']:,.0f}", f"{r['twin_asleep']:,.0f}",
                          f"{r['twin_awake'] / base['twin_awake']:.2f}x",
                          "met" if r["twin_awake"] >= 10_000 else "NOT met")
        console.print(table)

    table = Table(title=f"headless replay: {args.seconds:g} s simulated, remote + twin in one process, all kicked")
    for col in ("scene", "configuration", "objects", "set-up CPU s", "stepping CPU s", "physics CPU s", "wall s",
                "ticks/CPU s", "moving", "x real time (CPU)", "(wall)", "physics-only x", "x baseline", "target 20x"):
        table.add_column(col, justify="right")
    for (name, label), r in runs.items():
        ratio = r["sim_s"] / r["run_cpu_s"]
        base = runs[name, base_label]
        table.add_row(name, label, str(r["objects"]), f"{r['setup_cpu_s']:.1f}", f"{r['run_cpu_s']:.2f}",
                      f"{r['physics_cpu_s']:.2f}", f"{r['run_wall_s']:.2f}", f"{r['steps'] / r['run_cpu_s']:,.0f}",
                      f"{100 * r['moving']:.0f} %", f"{ratio:.1f}x", f"{r['sim_s'] / r['run_wall_s']:.1f}x",
                      f"{r['sim_s'] / r['physics_cpu_s']:.1f}x", f"{base['run_cpu_s'] / r['run_cpu_s']:.2f}x",
                      "met" if ratio >= 20 else "NOT met")
    console.print(table)
    if args.profile:
        prof = cProfile.Profile()
        replay(SCENES["clutter20"], min(args.seconds, 2.0), args.cache_dir, None, profile=prof)
        buf = io.StringIO()
        pstats.Stats(prof, stream=buf).sort_stats("cumulative").print_stats(20)
        text = buf.getvalue()
        console.print("cProfile, clutter20 stepping (current configuration), top 20 by cumulative time:")
        console.print(text[text.find("ncalls") - 1:].rstrip(), markup=False, highlight=False)
    if args.fills:
        fills(console, args.cache_dir)


if __name__ == "__main__":
    main()
