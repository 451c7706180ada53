"""`twin build` at scale: a cold build of scenes/data/mixed100.toml (100 objects), stage by stage.

    .venv/bin/python bench/build.py                      # the full scene, then the levers on its first 20 objects
    .venv/bin/python bench/build.py --subset 0           # the full scene only
    .venv/bin/python bench/build.py --profile 10         # cProfile of an in-process build of 10 objects
    .venv/bin/python bench/build.py --cli 3              # `twin build` itself, cold, 3 times: wall and CPU

Cold means an empty CoACD cache folder and a fresh output folder (both in a temporary folder), as
`twin build` meets a new scene. The full build runs as `twin build` does (:func:`scenes.build.build_scene`
with its default worker pool, then :func:`scenes.build.write_scene`). Stage times are wall seconds summed
over objects, measured in the process that built each (with two workers they add up to about twice the
wall time they took; on a loaded machine the niced workers wait, and these grow); "CPU" is process time
of this process plus its reaped children (the workers); "objCPU" sums every object's own CPU (estimate,
visual mesh, hulls, in its worker) and "CoACD" that of the objects that went to CoACD.
The subset rows build the first N objects again, cold, with one lever changed at a time: the near-convex
skip off (``convex_tolerance = 0``: every object goes to CoACD), and one process instead of the pool.
Writes bench/results/build.txt.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's packages, not an installed copy

SCENE = ROOT / "scenes" / "data" / "mixed100.toml"
RESULTS = Path(__file__).parent / "results" / "build.txt"


@dataclass(frozen=True)
class Run:
    """One cold build and write. Seconds: ``wall`` and ``cpu`` for the whole; stages summed over objects."""

    label: str
    objects: int
    workers: int
    wall: float
    cpu: float
    source: float
    estimate: float
    hulls: float
    compile: float
    write: float
    skipped: int
    coacd: int
    hull_count: int
    cpu_objects: float
    cpu_coacd: float


def _cpu() -> float:
    """CPU seconds of this process and of its children that have ended (pool workers, once shut down)."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def cold_build(scene, label: str, *, coacd=None, workers: int | None = None, verbose: bool = False) -> Run:  # type: ignore[no-untyped-def]
    """Build and write ``scene`` with an empty cache into a fresh folder; what it cost."""
    from scenes.build import build_scene, write_scene
    from twin.decompose import DEFAULT_SETTINGS

    def line(k: int, n: int, obj, report) -> None:  # type: ignore[no-untyped-def]
        how = (obj.primitive.kind if obj.primitive else "near-convex" if report.skipped_coacd
               else "cached" if obj.hull_cached else "CoACD")
        print(f"  [{k + 1}/{n}] {obj.id}: estimate {report.source_seconds + report.estimate_seconds:.1f} s, hulls "
              f"{report.hull_seconds:.1f} s ({len(obj.hulls)}, {how}, concavity {report.concavity:.4f})",
              file=sys.stderr)

    with tempfile.TemporaryDirectory(prefix="bench-build-") as tmp:
        cpu0, t0 = _cpu(), time.perf_counter()
        built = build_scene(scene, coacd=coacd or DEFAULT_SETTINGS, cache_dir=Path(tmp) / "coacd", progress=False,
                            workers=workers, on_object=line if verbose else None)
        t1 = time.perf_counter()
        write_scene(built.spec, Path(tmp) / "out", built=built)
        t2 = time.perf_counter()
        wall, cpu = t2 - t0, _cpu() - cpu0
    reports = built.reports.values()
    skipped = sum(r.skipped_coacd for r in reports)
    ran_coacd = [built.reports[o.id] for o in built.objects
                 if not o.hull_cached and not built.reports[o.id].skipped_coacd]
    return Run(label, len(built.objects), built.workers, wall, cpu, sum(r.source_seconds for r in reports),
               sum(r.estimate_seconds for r in reports), sum(r.hull_seconds for r in reports), built.compile_seconds,
               t2 - t1, skipped,
               len(built.objects) - skipped - sum(o.hull_cached for o in built.objects),
               sum(len(o.hulls) for o in built.objects), sum(r.cpu_seconds for r in reports),
               sum(r.cpu_seconds for r in ran_coacd))


def _table(runs: list[Run]) -> str:
    head = (f"{'build':44s} {'objs':>4s} {'proc':>4s} {'wall s':>7s} {'CPU s':>7s} | {'sample':>7s} {'estim':>7s} "
            f"{'hulls':>7s} {'compile':>7s} {'write':>7s} | {'skip':>4s} {'CoACD':>5s} {'hulls':>5s} | {'objCPU':>6s} "
            f"{'CoACD':>6s}")
    rows = [head, "-" * len(head)]
    for r in runs:
        rows.append(f"{r.label:44s} {r.objects:4d} {r.workers:4d} {r.wall:7.1f} {r.cpu:7.1f} | {r.source:7.1f} "
                    f"{r.estimate:7.1f} {r.hulls:7.1f} {r.compile:7.2f} {r.write:7.1f} | {r.skipped:4d} {r.coacd:5d} "
                    f"{r.hull_count:5d} | {r.cpu_objects:6.1f} {r.cpu_coacd:6.1f}")
    return "\n".join(rows)


def _cli_runs(scene_path: Path, runs: int) -> str:
    """``twin build SCENE --out DIR --cache-dir EMPTY`` as a user runs it, ``runs`` times cold: wall seconds
    from start to exit, and the command's CPU (its process and its workers)."""
    import statistics
    import subprocess

    twin = Path(sys.executable).with_name("twin")
    walls, cpus = [], []
    for k in range(runs):
        with tempfile.TemporaryDirectory(prefix="bench-build-cli-") as tmp:
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            subprocess.run([str(twin), "build", str(scene_path), "--out", f"{tmp}/out", "--cache-dir", f"{tmp}/coacd"],
                           check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            walls.append(time.perf_counter() - t0)
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpus.append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
            print(f"  twin build run {k + 1}: {walls[-1]:.1f} s wall, {cpus[-1]:.1f} s CPU", file=sys.stderr)
    return (f"`twin build {scene_path.name}` cold, {runs} runs: wall median {statistics.median(walls):.1f} s "
            f"(min {min(walls):.1f}, max {max(walls):.1f}); CPU median {statistics.median(cpus):.1f} s "
            f"(min {min(cpus):.1f}, max {max(cpus):.1f})")


def _profile(scene, count: int) -> str:  # type: ignore[no-untyped-def]
    import cProfile
    import io
    import pstats

    sub = replace(scene, objects=scene.objects[:count])
    prof = cProfile.Profile()
    prof.enable()
    cold_build(sub, "profile", workers=1)
    prof.disable()
    out = io.StringIO()
    pstats.Stats(prof, stream=out).sort_stats("cumulative").print_stats(30)
    return out.getvalue()


def main(argv: list[str] | None = None) -> int:
    from scenes.scenefile import load_scene
    from twin.decompose import DEFAULT_SETTINGS

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", type=Path, default=SCENE)
    p.add_argument("--subset", type=int, default=20, help="objects for the lever comparison (0: skip it)")
    p.add_argument("--profile", type=int, default=0, help="only cProfile an in-process build of this many objects")
    p.add_argument("--quiet", action="store_true", help="no per-object lines on stderr")
    p.add_argument("--cli", type=int, default=0, help="only time `twin build` itself this many times, cold")
    args = p.parse_args(argv)
    scene = load_scene(args.scene)
    if args.cli:
        line = _cli_runs(args.scene, args.cli)
        print(line)
        RESULTS.with_name("build_cli.txt").write_text(
            f"# .venv/bin/python bench/build.py --cli {args.cli}\n# {time.strftime('%Y-%m-%d %H:%M')}, load average "
            f"{' '.join(f'{x:.1f}' for x in os.getloadavg())} before the last run\n{line}\n")
        return 0
    if args.profile:
        print(_profile(scene, args.profile))
        return 0
    runs = [cold_build(scene, f"{scene.name}: all objects, as `twin build`", verbose=not args.quiet)]
    print(_table(runs), flush=True)
    if args.subset:
        sub = replace(scene, objects=scene.objects[: args.subset])
        no_skip = replace(DEFAULT_SETTINGS, convex_tolerance=0.0)
        runs += [cold_build(sub, f"first {args.subset}: as `twin build`"),
                 cold_build(sub, f"first {args.subset}: near-convex skip off", coacd=no_skip),
                 cold_build(sub, f"first {args.subset}: one process", workers=1),
                 cold_build(sub, f"first {args.subset}: skip off, one process", coacd=no_skip, workers=1)]
        base, new = runs[-1], runs[1]
        footer = (f"\nlevers together on the first {args.subset}: {base.cpu / new.cpu:.1f}x less CPU, "
                  f"{base.wall / new.wall:.1f}x less wall time than skip off in one process")
    else:
        footer = ""
    text = _table(runs) + footer + "\n"
    print(text)
    RESULTS.parent.mkdir(exist_ok=True)
    cmd = " ".join(["bench/build.py", *(argv if argv is not None else sys.argv[1:])])
    RESULTS.write_text(f"# .venv/bin/python {cmd}\n# {time.strftime('%Y-%m-%d %H:%M')}, load average "
                       f"{' '.join(f'{x:.1f}' for x in os.getloadavg())} (other jobs share the 2 cores)\n"
                       + text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
