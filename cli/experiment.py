"""``twin experiment``: a latency sweep, direct teleoperation against the twin (see :mod:`scenes.experiment`).

Writes ``OUT/results.csv`` (one row per mode and condition), PNG plots and ``OUT/report.md``. The human
force-discrimination threshold marked on the mass plot is a Weber fraction of 7 %: Jones (1989), "Matching
forces: constant errors and differential thresholds", Perception 18(5):681-687 (JND for force ~7 %); Pang,
Tan & Durlach (1991) report 5-15 % for pinch force, ~7-10 % at the forces used here.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import logging
import math
from pathlib import Path

from cli.outputs import check_output_folder, claim_output_folder, write_output
from estimation.errors import TwinError, refused_number
from twin.settings import MAX_WORKERS

log = logging.getLogger(__name__)

#: Human force discrimination threshold (Weber fraction), percent: Jones 1989 (see the module docstring).
FORCE_JND_PCT = 7.0

#: The file that marks a folder as this command's own: only such a folder (or an empty one) is written into.
MARKER = ".twin-experiment"

#: The command, as its marker and its refusals name it.
COMMAND = "twin experiment"

#: The files this command writes into --out (none may be an input).
WRITES = ("results.csv", "report.md", "force_vs_delay.png", "force_vs_mass.png", "divergence.png", "bytes_per_s.png")

HELP = """Run a latency sweep headless: per condition one session on the simulated clock gives both direct
teleoperation (the operator feels C's force after the round trip) and the twin (the operator feels C' at once).
SCENE_OR_RECORDING is a scene TOML file (tasks: push, press) or an MCAP recording of a session (twin demo/local
--record, twin replay --out): its scene, and its operator's targets replayed as the task 'recorded'.
Writes OUT/results.csv, OUT/*.png, OUT/report.md."""


def add_parser(sub) -> None:  # type: ignore[no-untyped-def]
    """Register ``twin experiment`` on the ``twin`` command's subparsers."""
    p = sub.add_parser("experiment", help="latency sweep: direct teleoperation against the twin, headless",
                       description=HELP)
    p.add_argument("scene", type=Path, metavar="SCENE_OR_RECORDING",
                   help="scene TOML file, or an .mcap recording (its scene and its operator's targets)")
    p.add_argument("--scene", dest="scene_file", type=Path, metavar="SCENE.toml",
                   help="with a recording: its scene file (default: the one the recording carries; twin local "
                        "records none)")
    p.add_argument("--delays", default="0,10,25,50,100,200",
                   help="one-way delays in ms, each direction, comma-separated (default 0,10,25,50,100,200)")
    p.add_argument("--jitter", type=float, default=0.0,
                   help="jitter in ms (standard deviation, normal; needs jitter <= delay/3 at every delay)")
    p.add_argument("--loss", dest="loss_pct", type=float, default=0.0,
                   help="independent packet loss, percent, each direction, below 100")
    p.add_argument("--mass-scale", default="1",
                   help="twin mass / true mass, comma-separated, each from 0.01 to 100 (default 1)")
    p.add_argument("--seeds", type=int, default=1,
                   help="network seeds per condition, for --jitter or --loss (the seed draws only those; default 1)")
    p.add_argument("--tasks", default=None,
                   help="tasks, comma-separated: push, press, recorded (default: push,press for a scene, "
                        "recorded for a recording)")
    p.add_argument("--speed", type=float, default=1.0,
                   help="task speed factor, from 0.05 to 20 (2: twice as fast; default 1)")
    p.add_argument("--sensor", choices=["surface", "cameras"], default=None,
                   help="the remote's sensor in every session (default: 'surface' for a scene, the one a recording "
                        "names for a recording; see twin demo --help)")
    p.add_argument("--workers", type=int, default=2, help="worker processes (default 2; 0: this process)")
    p.add_argument("--dask", metavar="ADDRESS",
                   help="run the sessions on a Dask cluster instead: a scheduler address (tcp://HOST:8786) or "
                        "'local' (a LocalCluster of --workers processes on loopback); needs the 'dask' extra")
    p.add_argument("--out", type=Path, required=True, help="output folder (new, empty or written by this command)")
    p.set_defaults(handler=run)



def _floats(text: str, flag: str) -> tuple[float, ...]:
    parts = [x.strip() for x in text.split(",")]
    if not any(parts):
        raise TwinError(f"{flag}: no values in {text!r}")
    if not all(parts):  # '0,,5' or a trailing comma: a value left out by mistake, not skipped quietly
        raise TwinError(f"{flag}: an empty value in {text!r}")
    try:
        values = tuple(float(x) for x in parts)
    except ValueError:
        raise TwinError(f"{flag}: not a comma-separated list of numbers: {text!r}") from None
    for v in values:
        if not math.isfinite(v):
            raise TwinError(f"{flag}: {v} is not a finite number")
    twice = next((v for i, v in enumerate(values) if v in values[:i]), None)
    if twice is not None:  # '0,10,10': a typo, and each repeat would run every condition again
        raise TwinError(f"{flag}: {twice:g} is given twice in {text!r}")
    return values


def parse(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    """The sweep the options describe, checked.

    Raises:
        TwinError: a bad list, a negative or non-finite number, jitter the distribution cannot
            take at some delay, an unknown task, or an --out folder with files this command did not write.
    """
    from scenes.experiment import MASS_SCALE_RANGE, SPEED_RANGE, Sweep
    from sync.netem import MAX_DELAY_S

    delays = _floats(args.delays, "--delays")
    if min(delays) < 0:
        raise TwinError(f"--delays: a delay cannot be negative, got {refused_number(min(delays), 0)} ms")
    if not math.isfinite(args.jitter) or args.jitter < 0:  # --loss: cli.main.check_args, as for twin replay
        raise TwinError(f"--jitter must be a finite number >= 0, got {refused_number(args.jitter, 0)}")
    top = MAX_DELAY_S * 1e3  # the link model's bound, in the ms these options take (it says it in seconds)
    for flag, value in (("--delays: a delay", max(delays)), ("--jitter", args.jitter)):
        if value > top:
            raise TwinError(f"{flag} must be at most {top:g} ms (an hour), got {refused_number(value, top)} ms")
    low, high = SPEED_RANGE
    if not (math.isfinite(args.speed) and low <= args.speed <= high):
        raise TwinError(f"--speed must be from {low:g} to {high:g}, got {refused_number(args.speed, low, high)}")
    masses = _floats(args.mass_scale, "--mass-scale")
    low, high = MASS_SCALE_RANGE
    if not all(low <= m <= high for m in masses):
        bad = next(m for m in masses if not low <= m <= high)
        raise TwinError(f"--mass-scale: a mass scale must be from {low:g} to {high:g}, got {refused_number(bad, low, high)}")
    if args.seeds < 1:
        raise TwinError(f"--seeds must be at least 1, got {args.seeds}")
    if not 0 <= args.workers <= MAX_WORKERS:
        raise TwinError(f"--workers must be from 0 to {MAX_WORKERS}, got {args.workers}")
    if args.dask is not None and args.dask != "local" and "://" not in args.dask:
        raise TwinError(f"--dask: expected 'local' or a scheduler address like tcp://HOST:8786, got {args.dask!r}")
    if args.tasks is None:
        args.tasks = "recorded" if is_recording(args.scene) else "push,press"
    tasks = tuple(t.strip() for t in args.tasks.split(","))
    if not all(tasks):  # as for the numbers: 'push,,press' is a task left out by mistake
        raise TwinError(f"--tasks: an empty name in {args.tasks!r}")
    twice = next((t for i, t in enumerate(tasks) if t in tasks[:i]), None)
    if twice is not None:  # as for the numbers: each repeat would run every condition again
        raise TwinError(f"--tasks: {twice} is given twice in {args.tasks!r}")
    if "recorded" in tasks and not is_recording(args.scene):
        raise TwinError("--tasks recorded needs a recording (.mcap) in place of the scene file")
    if getattr(args, "scene_file", None) is not None and not is_recording(args.scene):
        raise TwinError("--scene is for a recording's scene: the input is a scene file already")
    sweep = Sweep(tasks=tasks, delays=tuple(d / 1e3 for d in delays), jitter=args.jitter / 1e3,
                  loss=args.loss_pct / 100, mass_scales=masses, seeds=args.seeds, speed=args.speed)
    sweep.conditions()  # every condition checked before any work
    if sweep.draws < args.seeds:
        log.warning("--seeds %d changes nothing without --jitter or --loss (the seed draws only those): running one "
                    "seed", args.seeds)
    check_output_folder(args.out, marker=MARKER, command=COMMAND, writes=WRITES,
                        inputs=(args.scene, getattr(args, "scene_file", None)))
    return sweep


def is_recording(path: Path) -> bool:
    """Whether the command's input is a recording (by its suffix, as ``twin replay`` takes them)."""
    return path.suffix.lower() == ".mcap"


def source(args: argparse.Namespace, tasks: tuple[str, ...]):  # type: ignore[no-untyped-def]
    """The scene, for a recording its operator as a :class:`scenes.experiment.RecordedTask` (else None), and
    the remote's sensor (``--sensor``, else the one a recording names, else "surface"); ``tasks`` as
    :func:`parse` read them (``"push, recorded"`` holds ``recorded``).

    Raises:
        TwinError: an unreadable scene file or recording, a recording without a scene or naming a sensor
            replay does not know (without ``--sensor``), or, when the recorded task is asked for, one whose
            operator applied no target or one outside the operator's reach (as ``twin replay`` refuses it).
    """
    from scenes.experiment import RecordedTask
    from scenes.scenefile import load_scene

    if not is_recording(args.scene):
        return load_scene(args.scene), None, args.sensor or "surface"
    scene_file = getattr(args, "scene_file", None)
    from cli.record import recorded_scene, recorded_sensor, recorded_targets
    from sync.recording import read_recording
    from twin.model import OPERATOR_REACH, scene_reach_corners

    recording = read_recording(args.scene)
    if recording.damage:
        log.warning("%s", recording.damage)
    scene = recorded_scene(recording) if scene_file is None else load_scene(scene_file)
    sensor = args.sensor or recorded_sensor(recording)
    targets = recorded_targets(recording)
    times, points = targets.times, targets.points
    if len(times) == 0:
        if "recorded" in tasks:
            raise TwinError(f"{args.scene}: the recording has no operator targets (a remote's recording has none; "
                            "record the twin side, or give --tasks push,press)")
        return scene, None, sensor
    task = RecordedTask(times=times, points=points)
    if "recorded" in tasks:
        # As twin replay checks them: a target under the floor went into results.csv as a 27 kN "blow-up" of the
        # twin, while the remote dropped it (outside its workspace) and C and C' were driven differently.
        targets.check_reach(scene_reach_corners(scene.table, scene.end_effector, OPERATOR_REACH))
        try:
            task.plan(args.speed)  # its length checked before any work
        except TwinError as exc:
            raise TwinError(f"{args.scene}: {exc}") from None
    return scene, task, sensor


def run(args: argparse.Namespace) -> int:
    """The ``twin experiment`` handler: sweep, CSV, plots, report."""
    from contextlib import nullcontext

    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from scenes.experiment import dask_executor, run_experiment

    sweep = parse(args)
    scene, recorded, sensor = source(args, sweep.tasks)
    sweep = dataclasses.replace(sweep, sensor=sensor)
    out: Path = args.out
    engine = nullcontext(None) if args.dask is None else dask_executor(args.dask, args.workers)
    with engine as executor:
        # Claimed once the engine is up (an unreachable scheduler left an out folder holding only the marker), and
        # before the bar starts: a refused folder printed the bar's empty line above its one-line error.
        claim_output_folder(out, marker=MARKER, command=COMMAND)
        with Progress(TextColumn("sessions"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                      console=Console(stderr=True), transient=False) as bar:
            task = bar.add_task("sessions", total=None)

            def progress(done: int, total: int) -> None:
                bar.update(task, completed=done, total=total)

            rows, traces = run_experiment(scene, sweep, workers=args.workers, executor=executor, recorded=recorded,
                                          progress=progress)
    write_output(out, "results.csv", lambda tmp: write_csv(rows, tmp), marker=MARKER)
    plots = write_plots(rows, traces, out)
    text = report(rows, args, plots, sweep.sensor)
    write_output(out, "report.md", lambda tmp: tmp.write_text(text), marker=MARKER)
    print(f"{len(rows)} rows ({sweep.sensor} sensor) -> {out / 'results.csv'}; plots: {', '.join(p.name for p in plots)}; "
          f"report: {out / 'report.md'}")
    return 0


def write_csv(rows, path: Path) -> None:  # type: ignore[no-untyped-def]
    """``results.csv``: a header of :data:`scenes.experiment.COLUMNS`, then one line per row (NaN: empty)."""
    from dataclasses import astuple

    from scenes.experiment import COLUMNS

    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for r in rows:
            w.writerow(["" if isinstance(v, float) and not math.isfinite(v) else
                        (f"{v:.6g}" if isinstance(v, float) else v) for v in astuple(r)])


def _mean(values) -> float:  # type: ignore[no-untyped-def]
    values = [v for v in values if math.isfinite(v)]
    return sum(values) / len(values) if values else math.nan


def _by(rows, **match):  # type: ignore[no-untyped-def]
    return [r for r in rows if all(getattr(r, k) == v for k, v in match.items())]


def write_plots(rows, traces, out: Path) -> list[Path]:  # type: ignore[no-untyped-def]
    """Force error vs delay, force error vs mass scale (JND marked), divergence over time, bytes per second."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    tasks = sorted({r.task for r in rows})
    delays = sorted({r.delay_ms for r in rows})
    masses = sorted({r.mass_scale for r in rows})
    m1 = 1.0 if 1.0 in masses else masses[0]
    paths = []

    fig, axes = plt.subplots(1, len(tasks), figsize=(5 * len(tasks), 4), squeeze=False)
    for ax, task in zip(axes[0], tasks, strict=True):
        for mode, style in (("direct", "o-"), ("twin", "s-")):
            ys = [_mean(r.force_rms_pct for r in _by(rows, task=task, mode=mode, delay_ms=d, mass_scale=m1))
                  for d in delays]
            ax.plot(delays, ys, style, label=mode)
        ax.set(title=f"{task}: force error vs delay (mass x{m1:g})", xlabel="one-way delay, ms",
               ylabel="RMS force error, % of truth's peak")
        ax.grid(alpha=0.3)
        ax.legend()
    paths.append(_save(fig, out / "force_vs_delay.png"))

    fig, axes = plt.subplots(1, len(tasks), figsize=(5 * len(tasks), 4), squeeze=False)
    for ax, task in zip(axes[0], tasks, strict=True):
        for d in delays:
            ys = [_mean(r.contact_force_err_pct for r in _by(rows, task=task, mode="twin", delay_ms=d, mass_scale=m))
                  for m in masses]
            ax.plot(masses, ys, "o-", label=f"twin, {d:g} ms")
        ax.axhspan(-FORCE_JND_PCT, FORCE_JND_PCT, color="green", alpha=0.12,
                   label=f"force JND +/-{FORCE_JND_PCT:g} % (Jones 1989)")
        ax.axhline(0, color="k", lw=0.5)
        ax.set(title=f"{task}: felt contact force vs mass", xlabel="twin mass / true mass",
               ylabel="mean contact force error, %")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    paths.append(_save(fig, out / "force_vs_mass.png"))

    fig, axes = plt.subplots(1, len(tasks), figsize=(5 * len(tasks), 4), squeeze=False)
    for ax, task in zip(axes[0], tasks, strict=True):
        for c, trace in sorted(traces.items(), key=lambda kv: kv[0].delay):
            if c.task != task or c.mass_scale != m1 or c.seed != 0 or c.loss != rows[0].loss_pct / 100:
                continue
            t = np.arange(len(trace.divergence)) * 0.01
            ax.plot(t, trace.divergence * 1e3, label=f"{c.delay * 1e3:g} ms")
        ax.set(title=f"{task}: C'-C divergence (mass x{m1:g})", xlabel="task time, s", ylabel="max |C'-C|, mm")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    paths.append(_save(fig, out / "divergence.png"))

    fig, ax = plt.subplots(figsize=(6, 4))
    for mode, style in (("direct", "o-"), ("twin", "s-")):
        for task in tasks:
            ys = [_mean(r.bytes_per_s / 1e3 for r in _by(rows, task=task, mode=mode, delay_ms=d, mass_scale=m1))
                  for d in delays]
            ax.plot(delays, ys, style, label=f"{mode}, {task}")
    ax.set(title="traffic during the task (both directions)", xlabel="one-way delay, ms", ylabel="kB/s")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    paths.append(_save(fig, out / "bytes_per_s.png"))
    return paths


def _save(fig, path: Path) -> Path:  # type: ignore[no-untyped-def]
    fig.tight_layout()
    write_output(path.parent, path.name, lambda tmp: fig.savefig(tmp, dpi=110, format="png"), marker=MARKER)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path


def _table(header: list[str], lines: list[list[str]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---:" for _ in header) + "|"]
    out += ["| " + " | ".join(line) + " |" for line in lines]
    return "\n".join(out)


def _f(x: float, fmt: str = ".1f") -> str:
    return "-" if not math.isfinite(x) else format(x, fmt)


def report(rows, args: argparse.Namespace, plots: list[Path], sensor: str) -> str:  # type: ignore[no-untyped-def]
    """``report.md``: the command, a table per task, and the findings with their numbers. ``sensor``: the
    remote's in every session."""
    tasks = sorted({r.task for r in rows})
    delays = sorted({r.delay_ms for r in rows})
    masses = sorted({r.mass_scale for r in rows})
    seeds = len({r.seed for r in rows})  # what the means below are over (one where the link draws nothing)
    m1 = 1.0 if 1.0 in masses else masses[0]
    lines = ["# Latency experiment", "",
             f"Scene `{args.scene}`, delays {args.delays} ms each way, jitter {args.jitter:g} ms, loss {args.loss_pct:g} %, "
             f"mass scales {args.mass_scale}, {seeds} seed(s), tasks {args.tasks}, speed {args.speed:g}, "
             f"the remote's {sensor} sensor. "
             "Force errors are against C's force in the same task with no delay, no loss and the true mass; "
             "RMS and peak are % of the truth's peak force, the contact error is the signed error of the mean "
             "force magnitude while the truth is in contact." + (" Values are means over seeds." if seeds > 1 else ""), ""]
    for task in tasks:
        lines += [f"## {task}", ""]
        body = []
        for d in delays:
            for mode in ("direct", "twin"):
                sel = _by(rows, task=task, mode=mode, delay_ms=d, mass_scale=m1)
                body.append([f"{d:g}", mode, _f(_mean(r.perceived_delay_ms for r in sel), ".0f"),
                             _f(_mean(r.force_rms_pct for r in sel)), _f(_mean(r.force_peak_pct for r in sel), ".0f"),
                             _f(_mean(r.contact_force_err_pct for r in sel), "+.1f"),
                             _f(_mean(r.end_err_felt_truth_mm for r in sel)), _f(_mean(r.div_p99_mm for r in sel)),
                             _f(_mean(r.bytes_per_s for r in sel) / 1e3), _f(_mean(r.energy_j for r in sel), ".3f"),
                             "yes" if any(r.blowup for r in sel) else "no"])
        lines += [f"Mass x{m1:g}:", "", _table(["delay ms", "mode", "felt delay ms", "RMS err %", "peak err %",
                                                 "contact err %", "end err mm", "div p99 mm", "kB/s", "energy J",
                                                 "blow-up"], body), ""]
        if len(masses) > 1:
            body = []
            for m in masses:
                body.append([f"{m:g}"] + [_f(_mean(r.contact_force_err_pct for r in _by(
                    rows, task=task, mode="twin", delay_ms=d, mass_scale=m)), "+.1f") for d in delays])
            lines += ["Twin, mean contact force error % by mass scale (rows) and delay ms (columns):", "",
                      _table(["mass"] + [f"{d:g}" for d in delays], body), ""]
    lines += ["## Findings", "", *findings(rows), "", "Plots: " + ", ".join(f"`{p.name}`" for p in plots), ""]
    return "\n".join(lines)


def findings(rows) -> list[str]:  # type: ignore[no-untyped-def]
    """Sentences with numbers: where each mode wins, and what mass accuracy keeps the twin under the JND."""
    out = []
    tasks = sorted({r.task for r in rows})
    delays = sorted({r.delay_ms for r in rows})
    masses = sorted({r.mass_scale for r in rows})
    m1 = 1.0 if 1.0 in masses else masses[0]
    for task in tasks:
        def rms(mode: str, d: float, m: float = m1, task: str = task) -> float:
            return _mean(r.force_rms_pct for r in _by(rows, task=task, mode=mode, delay_ms=d, mass_scale=m))

        twins = [rms("twin", d) for d in delays]
        worse = [d for d in delays if rms("direct", d) > rms("twin", d)]
        first, last = rms("direct", delays[0]), rms("direct", delays[-1])
        # Said as measured: one delay is no trend, and a longer delay may give a smaller error (it "grew" down).
        trend = (f"is {first:.1f} % at {delays[0]:g} ms" if len(delays) == 1 else
                 f"{'grows' if last > first else 'falls' if last < first else 'stays'} from {first:.1f} % at "
                 f"{delays[0]:g} ms to {last:.1f} % at {delays[-1]:g} ms")
        low, high = f"{min(twins):.1f}", f"{max(twins):.1f}"
        span = (f"is {low} %" if len(delays) == 1 else f"stays at {low} %" if low == high
                else f"stays within {low}-{high} %")
        out.append(f"- **{task}**: direct teleoperation's RMS force error {trend}; the twin's "
                   f"{span} (its floor is the estimated shape, not "
                   "the network). " + (f"The twin is closer to the truth (RMS) at {', '.join(f'{d:g}' for d in worse)} ms "
                                        "one way." if worse else "Direct beats the twin at every delay measured."))
        better = [d for d in delays if rms("direct", d) <= rms("twin", d)]
        if better:
            out.append(f"- **{task}, where the twin loses**: at {', '.join(f'{d:g}' for d in better)} ms direct "
                       "teleoperation is closer to the truth than the twin: the twin's own modelling error "
                       "(estimated surface and mass) outweighs a short round trip.")
        if len(masses) > 1:
            ok = [m for m in masses if all(abs(_mean(r.contact_force_err_pct for r in _by(
                rows, task=task, mode="twin", delay_ms=d, mass_scale=m))) <= FORCE_JND_PCT for d in delays)]
            errs = {m: _mean(r.contact_force_err_pct for r in _by(rows, task=task, mode="twin", mass_scale=m))
                    for m in masses}
            out.append(f"- **{task}, mass**: the twin's mean contact force error by mass scale (all delays): "
                       + ", ".join(f"x{m:g}: {e:+.1f} %" for m, e in errs.items())
                       + f". Within the {FORCE_JND_PCT:g} % force JND at every delay: "
                       + (", ".join(f"x{m:g}" for m in ok) if ok else "none of the scales tried") + ".")
            # How much a mass error moves the felt force: a line through (mass scale, contact error) per delay.
            # The mass error that moves the force by one JND is the accuracy the mass needs, if nothing else
            # were wrong.
            slopes = []
            for d in delays:
                pts = [(m, _mean(r.contact_force_err_pct for r in _by(rows, task=task, mode="twin", delay_ms=d,
                                                                        mass_scale=m))) for m in masses]
                pts = [(m, e) for m, e in pts if math.isfinite(e)]
                if len(pts) > 1:
                    mx, my = _mean(m for m, _ in pts), _mean(e for _, e in pts)
                    slope = (sum((m - mx) * (e - my) for m, e in pts) / sum((m - mx) ** 2 for m, _ in pts))
                    slopes.append(f"{d:g} ms: {slope / 100:.2f} -> +/-{100 * FORCE_JND_PCT / abs(slope):.1f} %"
                                  if slope else f"{d:g} ms: 0")
            out.append(f"- **{task}, how accurate the mass must be**: felt force change per unit of relative mass "
                       f"error, and the mass error that makes one {FORCE_JND_PCT:g} % JND, by delay: "
                       + "; ".join(slopes) + ".")
    blow = [r for r in rows if r.blowup]
    out.append(f"- Stability: {len(blow)} of {len(rows)} runs blew up (non-finite or absurd force or speed).")
    return out
