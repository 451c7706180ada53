"""Latency experiments: a tiny sweep on the small scene, checked against what must hold, never wall time."""

from __future__ import annotations

import csv
import math
import re
import subprocess
import sys
from pathlib import Path

import pytest

from cli.experiment import write_csv
from cli.main import main
from scenes.experiment import COLUMNS, Sweep, run_experiment
from scenes.scenefile import load_scene

SMALL = Path(__file__).parent / "data" / "small.toml"

#: Two delays, two masses, the push task at twice the normal speed: 4 sessions (the truth is one of them).
SWEEP = Sweep(tasks=("push",), delays=(0.0, 0.05), mass_scales=(1.0, 1.5), seeds=1, speed=2.0)
ARGS = ["experiment", str(SMALL), "--delays", "0,50", "--mass-scale", "1,1.5", "--tasks", "push", "--speed", "2"]


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return tmp_path_factory.getbasetemp() / "coacd"


@pytest.fixture(scope="module")
def rows(cache):  # type: ignore[no-untyped-def]
    rows, _ = run_experiment(load_scene(SMALL), SWEEP, workers=0, cache_dir=cache)
    return rows


def _row(rows, **match):  # type: ignore[no-untyped-def]
    (row,) = [r for r in rows if all(getattr(r, k) == v for k, v in match.items())]
    return row


def test_direct_at_zero_delay_is_the_truth_and_delay_makes_it_worse(rows):
    zero = _row(rows, mode="direct", delay_ms=0.0, mass_scale=1.0)
    late = _row(rows, mode="direct", delay_ms=50.0, mass_scale=1.0)
    assert zero.force_rms_n == 0.0 and zero.force_peak_n == 0.0  # the same session as the truth
    assert zero.truth_peak_n > 1.0  # a real push: newtons of contact force
    assert late.force_rms_pct > 5.0 > zero.force_rms_pct
    assert not zero.blowup and not late.blowup and late.energy_j > 0


def test_perceived_delay_twin_is_one_step_direct_is_the_round_trip(rows):
    for d in (0.0, 50.0):
        twin = _row(rows, mode="twin", delay_ms=d, mass_scale=1.0)
        direct = _row(rows, mode="direct", delay_ms=d, mass_scale=1.0)
        assert twin.perceived_delay_ms == pytest.approx(1.0)  # one 1 ms physics step
        # The round trip, plus the step both modes need; at zero delay the remote still sees a command one
        # step late (it steps before the operator within a tick).
        assert direct.perceived_delay_ms - twin.perceived_delay_ms == pytest.approx(max(2 * d, 1.0))


def test_a_heavier_twin_pushes_back_harder(rows):
    for d in (0.0, 50.0):
        true_mass = _row(rows, mode="twin", delay_ms=d, mass_scale=1.0)
        heavy = _row(rows, mode="twin", delay_ms=d, mass_scale=1.5)
        assert heavy.contact_force_err_pct > true_mass.contact_force_err_pct + 10.0
        assert heavy.force_rms_pct != true_mass.force_rms_pct
        # Direct teleoperation feels C, which the twin's mass does not touch.
        direct, direct_heavy = (_row(rows, mode="direct", delay_ms=d, mass_scale=m) for m in (1.0, 1.5))
        assert direct.force_rms_n == direct_heavy.force_rms_n


def test_twin_rows_carry_divergence_and_traffic(rows):
    twin = _row(rows, mode="twin", delay_ms=50.0, mass_scale=1.0)
    direct = _row(rows, mode="direct", delay_ms=50.0, mass_scale=1.0)
    assert 0.0 <= twin.div_p50_mm <= twin.div_p99_mm <= twin.div_max_mm < 50.0
    assert twin.messages > 0 and direct.messages > twin.messages  # direct streams a force sample every step
    assert direct.bytes_per_s > twin.bytes_per_s > 0


def test_the_findings_say_the_trend_the_numbers_show(rows):
    """With one delay the report said "grows from 24.3 % at 50 ms to 24.3 % at 50 ms", and an error that fell
    with delay "grew" from 26.6 to 24.3 %."""
    from dataclasses import replace

    from cli.experiment import findings

    true_mass = [r for r in rows if r.mass_scale == 1.0]
    late = _row(rows, mode="direct", delay_ms=50.0, mass_scale=1.0).force_rms_pct
    assert f"grows from 0.0 % at 0 ms to {late:.1f} % at 50 ms" in findings(true_mass)[0]
    one = findings([r for r in true_mass if r.delay_ms == 50.0])[0]
    assert f"error is {late:.1f} % at 50 ms; the twin's is " in one and "from" not in one, one
    falling = [replace(r, force_rms_pct=100.0 - r.force_rms_pct) if r.mode == "direct" else r for r in true_mass]
    assert f"falls from 100.0 % at 0 ms to {100 - late:.1f} % at 50 ms" in findings(falling)[0]


def test_a_direct_link_that_loses_every_packet_has_no_felt_delay(cache):
    """At 100 % loss the direct row said 2 ms, a perfect link's: the mean of no packets counted as 0."""
    from scenes.experiment import Condition, rows_for, run_session

    scene = load_scene(SMALL)
    lost = run_session(scene, Condition(task="push", delay=0.05, loss=1.0, speed=4.0), cache_dir=cache)
    truth = run_session(scene, Condition(task="push", speed=4.0), cache_dir=cache)
    direct, twin = rows_for(lost, truth)
    assert math.isnan(direct.perceived_delay_ms) and twin.perceived_delay_ms == pytest.approx(1.0)
    assert direct.contact_force_err_pct == pytest.approx(-100.0)  # nothing felt
    zero_direct, _ = rows_for(truth, truth)
    assert zero_direct.perceived_delay_ms == pytest.approx(2.0)  # a perfect link still is one


@pytest.mark.slow
def test_the_cli_writes_every_column_and_the_same_rows_with_workers(rows, cache, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("TWIN_CACHE_DIR", str(cache))
    out = tmp_path / "sweep"
    assert main([*ARGS, "--workers", "2", "--out", str(out)]) == 0
    with (out / "results.csv").open() as f:
        table = list(csv.reader(f))
    assert tuple(table[0]) == COLUMNS
    assert len(table) == 1 + len(rows) == 1 + 8
    write_csv(rows, tmp_path / "in_process.csv")  # workers=0, this process
    assert (out / "results.csv").read_bytes() == (tmp_path / "in_process.csv").read_bytes()
    for name in ("force_vs_delay.png", "force_vs_mass.png", "divergence.png", "bytes_per_s.png", "report.md"):
        assert (out / name).stat().st_size > 0, name
    assert "Findings" in (out / "report.md").read_text()
    # A file of its own the user edited is theirs now, as twin build says of its folder: the re-run replaced it, exit 0.
    capsys.readouterr()
    for name in ("report.md", "results.csv"):
        mine = (out / name).read_text() + "my notes\n"
        (out / name).write_text(mine)
        assert main([*ARGS, "--delays", "0", "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err == (f"twin experiment: error: --out {out}: {name} was edited since twin experiment wrote it; move "
                       "the folder aside or give --out a new folder\n")
        assert (out / name).read_text() == mine
        (out / name).write_text(mine.removesuffix("my notes\n"))
    # Its own folder may be written again; another one may not. Links planted in it are replaced, not written
    # through (results.csv -> a user's file elsewhere had that file overwritten).
    victims = {}
    from cli.experiment import MARKER

    for name in ("results.csv", "report.md", "divergence.png", MARKER):
        victim = victims[name] = tmp_path / f"victim{name}"
        victim.write_text("mine\n")
        (out / name).unlink()
        (out / name).symlink_to(victim)
    assert main([*ARGS, "--delays", "0", "--mass-scale", "1", "--workers", "0", "--out", str(out)]) == 0
    assert all(v.read_text() == "mine\n" for v in victims.values())
    assert not any(p.is_symlink() for p in out.iterdir())


@pytest.mark.parametrize(("extra", "message"), [
    (["--delays", "0,-10"], "--delays: a delay cannot be negative, got -10 ms"),
    (["--loss", "101"], "--loss must be below 100 .*, got 101"),
    # Every packet lost was accepted, exit 0: direct teleoperation felt nothing and the rows measured nothing.
    (["--loss", "100"], "--loss must be below 100 \\(at 100 % every packet is lost both ways and the run would "
                        "measure nothing\\), got 100$"),
    (["--loss", "-1"], "--loss must be >= 0, got -1"),
    (["--delays", "0,inf"], "--delays: inf is not a finite number"),
    (["--delays", "0,,50"], "--delays: an empty value in '0,,50'"),  # the empty one was skipped
    (["--mass-scale", "1,"], "--mass-scale: an empty value in '1,'"),
    (["--mass-scale", "1,nan"], "--mass-scale: nan is not a finite number"),
    (["--mass-scale", "0"], "--mass-scale: a mass scale must be from 0.01 to 100, got 0"),
    (["--mass-scale", "1,1e-300"], "--mass-scale: a mass scale must be from 0.01 to 100, got 1e-300"),
    (["--speed", "1e-6"], "--speed must be from 0.05 to 20, got 1e-06"),
    (["--speed", "0"], "--speed must be from 0.05 to 20, got 0"),
    (["--jitter", "20", "--delays", "50"], "delay 50 ms: jitter 0.02 s is more than normal jitter allows"),
    (["--jitter", "1", "--delays", "0"], "delay 0 ms: jitter 0.001 s is more than normal jitter allows"),
    (["--tasks", "push,wave"], "unknown task 'wave' \\(known: push, press\\)"),
    (["--seeds", "0"], "--seeds must be at least 1, got 0"),
    # built a list of 2e11 runs until memory ran out, printing nothing
    (["--seeds", "99999999999", "--mass-scale", "1", "--loss", "1"],
     "1 task\\(s\\) x 2 delay\\(s\\) x 1 mass scale\\(s\\) x 99999999999 seed\\(s\\) is 199,999,999,998 runs, more than the "
     "10,000 a sweep holds"),
    # a delay of 1e308 ms passed the checks; its arrival times were infinite (an OverflowError once run)
    # (then refused in the link model's seconds, no unit: "delay must be finite and in [0, 3600]")
    (["--delays", "0,1e308"], "--delays: a delay must be at most 3.6e\\+06 ms \\(an hour\\), got 1e\\+308 ms"),
    # 78 repeats of one delay ran every condition 78 times; 100,000 workers were accepted
    (["--delays", "0,10,10"], "--delays: 10 is given twice in '0,10,10'"),
    (["--tasks", "push, push"], "--tasks: push is given twice in 'push, push'"),
    (["--tasks", "push,,press"], "--tasks: an empty name in 'push,,press'"),  # was push and press, silently
    (["--tasks", "push,"], "--tasks: an empty name in 'push,'"),
    (["--workers", "100000"], "--workers must be from 0 to 256, got 100000"),
])
def test_bad_arguments_are_one_line_and_exit_2(extra, message, tmp_path, capsys):
    assert main([*ARGS, *extra, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("twin experiment: error: ")
    assert re.search(message, err), err
    assert not (tmp_path / "o").exists()  # refused before any work


@pytest.mark.parametrize(("extra", "seeds"), [([], 1), (["--loss", "1"], 3), (["--jitter", "1", "--delays", "50"], 3)])
def test_seeds_run_only_where_the_network_draws_at_random(extra, seeds, tmp_path, caplog):
    """--seeds 3 with neither jitter nor loss ran three identical sessions per condition and reported their mean."""
    from cli.experiment import parse
    from cli.main import _parser

    args = _parser().parse_args([*ARGS, "--seeds", "3", *extra, "--out", str(tmp_path / "o")])
    sweep = parse(args)
    assert sweep.draws == seeds
    assert len(sweep.conditions()) == len(sweep.tasks) * len(sweep.delays) * len(sweep.mass_scales) * seeds
    assert sorted({c.seed for c in sweep.conditions()}) == list(range(seeds))
    said = [r.getMessage() for r in caplog.records if "--seeds" in r.getMessage()]
    assert said == ([] if seeds == 3 else ["--seeds 3 changes nothing without --jitter or --loss (the seed draws only "
                                           "those): running one seed"])


def test_the_report_says_how_many_seeds_its_means_are_over(rows):
    """It said "means over seeds" of K identical sessions; the count is taken from the rows it averages."""
    import argparse
    from dataclasses import replace

    from cli.experiment import report

    args = argparse.Namespace(scene=SMALL, delays="0,50", jitter=0.0, loss_pct=0.0, mass_scale="1,1.5", tasks="push",
                              speed=2.0)
    one = report(rows, args, [], "surface")
    assert "1 seed(s)" in one and "means over seeds" not in one
    two = report([*rows, *(replace(r, seed=1) for r in rows)], args, [], "surface")
    assert "2 seed(s)" in two and "Values are means over seeds." in two


def test_an_out_folder_this_command_did_not_write_is_refused(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("mine")
    assert main([*ARGS, "--out", str(tmp_path)]) == 2
    assert "exists and is not empty (and not a folder this command wrote)" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


def test_an_out_folder_refused_at_its_claim_is_one_line_with_no_progress_bar(tmp_path, capsys, monkeypatch):
    """As root, /proc/x passed the early writability check and was refused when claimed, after the progress bar
    had started: its empty line came before the error."""
    import cli.experiment
    from estimation.errors import TwinError

    def refuse(out, **_):  # type: ignore[no-untyped-def]
        raise TwinError(f"{out}: cannot write the output folder (No such file or directory)")

    monkeypatch.setattr(cli.experiment, "claim_output_folder", refuse)
    assert main([*ARGS, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot write the output folder" in err, repr(err)


def test_help_names_both_inputs():
    out = subprocess.run([sys.executable, "-m", "cli.main", "experiment", "--help"], capture_output=True,
                         text=True, check=True, cwd=Path(__file__).parent.parent).stdout
    assert "SCENE_OR_RECORDING" in out and "recorded" in out and "--dask" in out


@pytest.mark.slow
def test_a_dask_local_cluster_gives_the_rows_local_processes_give(rows, cache):
    from scenes.experiment import dask_executor

    one = Sweep(tasks=("push",), delays=(0.05,), mass_scales=(1.5,), seeds=1, speed=2.0)  # 2 sessions, truth too
    with dask_executor("local", workers=2) as executor:
        on_dask, _ = run_experiment(load_scene(SMALL), one, executor=executor, cache_dir=cache)
        # Every socket the cluster listens on is on loopback, and its HTTP server is not on the dashboard's
        # 8787, which distributed took though told "no dashboard" (psutil comes with distributed).
        import psutil

        me = psutil.Process()
        listening = [c.laddr for p in (me, *me.children(recursive=True)) for c in p.net_connections("tcp")
                     if c.status == psutil.CONN_LISTEN]
        assert listening and all(a.ip == "127.0.0.1" for a in listening), listening
        assert 8787 not in {a.port for a in listening}, listening
    assert len(on_dask) == 2
    # repr: NaN fields (undefined for a mode) compare equal as text, and every float to the last digit.
    assert repr(on_dask) == repr([r for r in rows if r.delay_ms == 50 and r.mass_scale == 1.5])


@pytest.mark.slow
def test_an_unreachable_dask_scheduler_is_one_line(tmp_path, capsys):
    from sync.zenoh_transport import free_port

    assert main([*ARGS, "--dask", f"tcp://127.0.0.1:{free_port()}", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no Dask scheduler at" in err, err
    assert not (tmp_path / "o").exists()  # nothing was run, so nothing is left behind


def test_a_blow_up_is_a_speed_in_metres_or_a_spin_past_what_a_hand_makes():
    """An end-effector sphere rolling along a pushed box spins at tens of rad/s: not a blow-up."""
    import numpy as np

    from scenes.experiment import ABSURD_SPEED, ABSURD_SPIN, _absurd
    from twin.model import EndEffectorSpec, TableSpec, new_spec
    from twin.sim import Twin

    twin = Twin(new_spec("blowup", table=TableSpec(), end_effector=EndEffectorSpec()), background=False)
    none = np.zeros(3)
    assert not _absurd(twin, none)
    twin.data.qvel[3:6] = (0.0, 25.0, 0.0)  # the sphere's spin, rad/s
    assert not _absurd(twin, none)
    twin.data.qvel[3:6] = (0.0, ABSURD_SPIN, 0.0)
    assert _absurd(twin, none)
    twin.data.qvel[:] = 0.0
    twin.data.qvel[0] = ABSURD_SPEED
    assert _absurd(twin, none)
    twin.data.qvel[0] = 0.0
    assert _absurd(twin, np.array([0.0, 0.0, np.inf]))


LOW = """
name = "low"
[table]
size = [1.0, 0.6, 0.04]
height = 0.5
[end_effector]
radius = 0.02
position = [-0.3, 0.0, 0.56]
[[objects]]
id = "slab"
primitive = { type = "box", size = [0.06, 0.2, 0.008] }
density = 700
position = [0.0, 0.0]
points = 4000
[[objects]]
id = "wall"
primitive = { type = "box", size = [0.04, 0.3, 0.1] }
density = 700
position = [0.3, 0.0]
points = 4000
"""


def test_a_push_meets_an_object_lower_than_the_end_effector_centre(cache):
    """The push finds what the sphere touches first, not what a ray from its centre meets: an 8 mm slab under a 20 mm
    sphere (centre 23 mm up) is pushed from its near face, not ploughed through towards the wall behind it."""
    import numpy as np
    import tomllib

    from scenes.experiment import plan_task
    from scenes.remote import Remote
    from scenes.scenefile import parse_scene
    from sync.clock import SimClock
    from sync.inprocess import InProcessBus

    clock = SimClock()
    remote = Remote(parse_scene(tomllib.loads(LOW)), InProcessBus(clock).transport("remote"), clock=clock,
                    cache_dir=cache)
    try:
        trajectory, duration = plan_task("push", remote.scene, remote.twin.model, remote.twin.data)
        path = np.array([trajectory(t) for t in np.linspace(0.0, duration, 2001)])
        assert path[:, 2].min() == pytest.approx(0.5 + 0.02 + 0.003, abs=1e-9)  # the push's height: 3 mm clear
        # The sphere meets the slab's near top edge (x = -0.03, 15 mm below its centre) with its centre
        # sqrt(20^2 - 15^2) mm short of it, and pushes 10 cm on from there.
        assert path[:, 0].max() - 0.10 == pytest.approx(-0.03 - np.sqrt(0.02**2 - 0.015**2), abs=2e-4)
    finally:
        remote.close()


def test_a_press_on_a_ring_says_why_it_cannot(cache):
    """A ring's centre of mass is in its hole: the ray down meets nothing, and the message says so (it said "no top
    surface found on 'ring'")."""
    import tomllib

    from scenes.experiment import ExperimentError, plan_task
    from scenes.remote import Remote
    from scenes.scenefile import parse_scene
    from sync.clock import SimClock
    from sync.inprocess import InProcessBus

    ring = LOW.split("[[objects]]")[0] + """[[objects]]
id = "ring"
primitive = { type = "torus", size = [0.04, 0.01] }
density = 700
position = [0.0, 0.0]
points = 4000
"""
    clock = SimClock()
    remote = Remote(parse_scene(tomllib.loads(ring)), InProcessBus(clock).transport("remote"), clock=clock,
                    cache_dir=cache)
    try:
        with pytest.raises(ExperimentError, match=r"press: a ray straight down through the centre of mass of 'ring' meets "
                                                  r"nothing \(a ring or a tube, open there\?\).*--tasks push"):
            plan_task("press", remote.scene, remote.twin.model, remote.twin.data)
    finally:
        remote.close()
