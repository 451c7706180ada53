"""Recordings (MCAP) of headless sessions, read back and replayed: bit for bit, with other inputs, torn."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cli.main import main
from cli.record import replay
from scenes.headless import Headless
from scenes.scenefile import load_scene
from sync.clock import SimClock
from sync.messages import decode
from sync.recording import (
    FORCE_TOPIC,
    RECORDED_TIME_SLACK_S,
    SCHEMA_VERSION,
    TARGET_TOPIC,
    TRUTH_TOPIC,
    Recorder,
    Recording,
    RecordingError,
    read_recording,
    written_here,
)
from twin.trajectory import push_trajectory

SMALL = Path(__file__).parent / "data" / "small.toml"
ROOT = Path(__file__).resolve().parent.parent
SECONDS = 3.0


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return tmp_path_factory.getbasetemp() / "coacd"


@pytest.fixture(scope="module")
def recorded(tmp_path_factory, cache):  # type: ignore[no-untyped-def]
    """A 3 s headless session pushing the crate, recorded; (path, final twin poses, final remote poses)."""
    path = tmp_path_factory.mktemp("rec") / "session.mcap"
    with Headless(load_scene(SMALL), cache_dir=cache, record=path) as session:
        start = session.local.twin.data.mocap_pos[0].copy()
        session.run(SECONDS, trajectory=push_trajectory(start, start + np.array([0.6, 0.0, -0.03]), SECONDS))
        twin = {i: np.concatenate(p) for i, p in session.poses().items()}
        remote = {i: np.concatenate(session.remote.twin.pose(i)) for i in twin}
    return path, twin, remote


def test_a_recording_reads_back_with_every_channel_in_order(recorded):
    path, _, _ = recorded
    rec = read_recording(path)
    assert rec.damage is None and rec.end is not None
    assert rec.schema_version == SCHEMA_VERSION
    assert rec.metadata["clock"] == "sim" and rec.metadata["scene_name"] == "small"
    assert rec.metadata["scene_toml"] == SMALL.read_text()
    steps = round(SECONDS / 0.001)
    assert rec.counts[TARGET_TOPIC] == steps  # one target per twin step
    assert rec.counts[TRUTH_TOPIC] == rec.counts[FORCE_TOPIC] == steps // 10  # 100 Hz
    assert int(rec.end["messages"]) == len(rec.records)
    wire = rec.wire()
    by = {(w.side, w.direction, w.key.rsplit("/", 1)[-1]) for w in wire}
    for expected in [("remote", "sent", "pose"), ("twin", "received", "pose"), ("remote", "sent", "cloud"),
                     ("twin", "received", "cloud"), ("twin", "sent", "command"), ("remote", "received", "command"),
                     ("remote", "sent", "heartbeat"), ("twin", "received", "heartbeat")]:
        assert expected in by, expected
    # No emulated network: each command the twin sent, the remote received, at the same simulated time.
    sent = [w for w in wire if w.side == "twin" and w.direction == "sent"]
    got = [w for w in wire if w.side == "remote" and w.direction == "received"]
    assert [w.data for w in sent] == [w.data for w in got] and len(sent) > 100
    assert all(a.log_time == b.log_time for a, b in zip(sent, got, strict=True))
    for w in wire:  # every message is a wire message, sent at its stamp, received no earlier
        msg = decode(w.data)
        assert w.publish_time == msg.stamp_ns <= w.log_time
    for topic in rec.counts:
        times = [r.log_time for r in rec.topic(topic)]
        assert times == sorted(times), topic
    times, targets = rec.targets()
    assert np.all(np.diff(times) > 0) and targets.shape == (steps, 3)
    truth = rec.truth()
    assert sorted(truth) == ["can", "crate"]
    assert truth["crate"][1][-1][0] > truth["crate"][1][0][0] + 0.1  # the crate was pushed in +x
    assert np.allclose(np.linalg.norm(truth["crate"][2], axis=1), 1.0)


def test_a_replay_is_bit_identical_twice_and_to_the_recorded_session(recorded, cache, monkeypatch):
    path, twin, remote = recorded
    decodes = []
    targets = Recording.targets
    monkeypatch.setattr(Recording, "targets", lambda self: decodes.append(self.path) or targets(self))
    first = replay(path, cache_dir=cache)
    second = replay(path, cache_dir=cache)
    assert decodes == [path, path]  # once a replay: the trajectory, its reach and the summary were three decodes
    assert sorted(first.twin_poses) == ["can", "crate"]
    for object_id in first.twin_poses:
        assert first.twin_poses[object_id].tobytes() == second.twin_poses[object_id].tobytes()
        assert first.remote_poses[object_id].tobytes() == second.remote_poses[object_id].tobytes()
        # The recorded targets drive the same session: the recorded poses come back exactly.
        assert first.twin_poses[object_id].tobytes() == twin[object_id].tobytes()
        assert first.remote_poses[object_id].tobytes() == remote[object_id].tobytes()
    s = first.summary
    assert s["operator"] == "recorded" and s["remote_vs_recorded_truth_mm"]["max"] == 0.0
    assert all(f["difference_mm"] == 0.0 for f in s["final_vs_recorded_truth"].values())
    assert s["speed_x_realtime"] > 1.0  # faster than real time (no wall-time bound beyond that)


def test_a_replay_with_another_trajectory_or_network_differs(recorded, cache, tmp_path, capsys):
    path, _, remote = recorded
    script = tmp_path / "aside.csv"
    script.write_text("t,x,y,z\n0,-0.3,0.0,0.56\n3,-0.3,0.25,0.56\n")  # moves sideways, never touches the crate
    other = replay(path, script=script, cache_dir=cache)
    assert other.summary["operator"] == "script"
    assert np.linalg.norm(other.remote_poses["crate"][:3] - remote["crate"][:3]) > 0.05
    assert other.summary["final_vs_recorded_truth"]["crate"]["difference_mm"] > 50
    out = tmp_path / "delayed"
    assert main(["replay", str(path), "--delay", "30", "--seed", "3", "--json", "--out", str(out),
                 "--cache-dir", str(cache)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["network"]["downlink"]["delay_ms"] == 30.0 and summary["network"]["seed"] == 3
    assert summary["twin_vs_remote_mm"]["max"] > 0
    assert read_recording(out / "replay.mcap").metadata["command"] == "replay"
    # A summary the user added to was replaced by the re-run, exit 0; twin build refuses an edited folder so.
    capsys.readouterr()
    mine = (out / "summary.json").read_text() + "my notes\n"
    (out / "summary.json").write_text(mine)
    assert main(["replay", str(path), "--out", str(out), "--cache-dir", str(cache)]) == 2
    assert capsys.readouterr().err == (f"twin replay: error: --out {out}: summary.json was edited since twin replay "
                                       "wrote it; move the folder aside or give --out a new folder\n")
    assert (out / "summary.json").read_text() == mine
    (out / "summary.json").write_text(mine.removesuffix("my notes\n"))
    # A seed with no network to draw for changes nothing, and says so (it was taken without a word).
    capsys.readouterr()
    assert main(["replay", str(path), "--seed", "5", "--json", "--duration", "0.2", "--cache-dir", str(cache)]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["network"] is None
    assert captured.err.endswith("\ntwin replay: warning: --seed changed nothing: the replay has no emulated network "
                                 "(the recording had none; give --delay, --jitter or --loss)\n"), captured.err
    # A link planted in the folder it wrote is replaced, not written through: it overwrote the user's file.
    victim = tmp_path / "victim.txt"
    victim.write_text("mine\n")
    (out / "summary.json").unlink()
    (out / "summary.json").symlink_to(victim)
    assert main(["replay", str(path), "--out", str(out), "--cache-dir", str(cache)]) == 0
    assert victim.read_text() == "mine\n" and not (out / "summary.json").is_symlink()
    umask = os.umask(0)
    os.umask(umask)
    assert (out / "summary.json").stat().st_mode & 0o777 == 0o666 & ~umask  # as open() makes it, not 0600
    assert json.loads((out / "summary.json").read_text())["twin_vs_remote_mm"]["max"] > 0


def test_a_torn_tail_is_reported_and_the_intact_part_replays(recorded, cache, tmp_path, capsys):
    path, _, _ = recorded
    data = path.read_bytes()
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(data[: int(len(data) * 0.7)])
    rec = read_recording(torn)
    whole = read_recording(path)
    assert rec.damage is not None and "damaged after" in rec.damage and rec.end is None
    assert 0 < len(rec.records) < len(whole.records)
    assert [r.data for r in rec.records] == [r.data for r in whole.records[: len(rec.records)]]
    assert main(["replay", str(torn), "--json", "--cache-dir", str(cache)]) == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert f"after {len(rec.records)} messages" in captured.err and "warning" in captured.err
    assert captured.err.count("damaged after") == 1  # said once (it was logged, then printed again)
    assert summary["damage"] == rec.damage and summary["duration_s"] < SECONDS
    # Progress on stderr (not a terminal: plain lines), up to the simulated time replayed; stdout the JSON.
    progress = [line for line in captured.err.splitlines() if not line.startswith("twin replay: warning")]
    assert progress[0] == "twin replay: building the scene", progress
    assert progress[-1] == f"twin replay: {summary['duration_s']:.3g} / {summary['duration_s']:.3g} s simulated"


def test_bad_recordings_are_one_line_errors(tmp_path, capsys):
    old = tmp_path / "future.mcap"
    with Recorder(old, clock=SimClock(), metadata={"schema_version": "99"}) as r:
        r.target(0.0, np.zeros(3))
    with pytest.raises(RecordingError, match=rf"schema version 99; this tool reads version {SCHEMA_VERSION}"):
        read_recording(old)
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"not an mcap file at all" * 10)
    stub = tmp_path / "stub.mcap"
    stub.write_bytes(old.read_bytes()[:20])  # the header only: no metadata survives
    # Random bytes in the header's text said "(UnicodeDecodeError: 'utf-8' codec can't decode byte 0xff ...)".
    mangled = tmp_path / "mangled.mcap"
    mangled.write_bytes(old.read_bytes().replace(b"tactile-twin", b"\xff" * len("tactile-twin"), 1))
    for bad, words in [(old, "schema version 99"), (garbage, "not a readable tactile-twin recording"),
                       (stub, "not a readable tactile-twin recording"), (tmp_path / "missing.mcap", "no such recording"),
                       (mangled, f"{mangled}: not a readable tactile-twin recording (a record's text is not UTF-8)")]:
        assert main(["replay", str(bad)]) == 2
        err = capsys.readouterr().err
        assert words in err and err.count("\n") == 1, err
    assert main(["replay", str(old), "--delay", "-5"]) == 2
    assert "--delay must be >= 0" in capsys.readouterr().err
    assert main(["replay", str(old), "--loss", "150"]) == 2
    assert "--loss must be" in capsys.readouterr().err


def test_impossible_conditions_and_a_recording_without_a_scene_exit_2(recorded, tmp_path, capsys):
    path, _, _ = recorded
    assert main(["replay", str(path), "--delay", "10", "--jitter", "9"]) == 2  # normal jitter <= delay / 3
    assert "jitter" in capsys.readouterr().err
    assert main(["replay", str(path), "--delay", "1e308"]) == 2  # was an OverflowError traceback
    err = capsys.readouterr().err
    assert "delay must be >= 0 and <= 3.6e+06, got 1e+308" in err and err.count("\n") == 1, err
    # The command line's bound, in the ms it takes, is the link model's hour (which said it in seconds, no unit).
    from cli.main import _NUMBERS
    from sync.netem import MAX_DELAY_S

    assert _NUMBERS["delay_ms"][3] == _NUMBERS["jitter_ms"][3] == MAX_DELAY_S * 1e3
    # Of a recording that runs past the hour: its length, not a --duration nobody gave.
    long = tmp_path / "long.mcap"
    clock = SimClock()
    with Recorder(long, clock=clock, metadata={"scene_toml": SMALL.read_text()}) as r:
        r.target(0.0, np.zeros(3))
        clock.advance(3600.0)
        r.target(3600.0, np.zeros(3))
    assert main(["replay", str(long)]) == 2
    err = capsys.readouterr().err
    assert "long.mcap: the recorded session runs 3600.001 s, more than a replay runs (at most 3600 s)" in err, err
    for tasks in ("recorded", "push, recorded"):  # the list as parse() reads it: spaces once skipped this check
        assert main(["experiment", str(long), "--out", str(tmp_path / "x"), "--delays", "0", "--speed", "0.05",
                     "--tasks", tasks]) == 2
        err = capsys.readouterr().err
        assert ("long.mcap: the recorded targets span 3600 s, a 72001 s session at speed 0.05: more than a replay runs"
                in err and err.count("\n") == 1), err
        assert not (tmp_path / "x").exists()
    bare = tmp_path / "bare.mcap"
    with Recorder(bare, clock=SimClock(), metadata={"scene_name": "x", "scene_toml": ""}) as r:
        r.target(0.5, np.zeros(3))
    assert main(["replay", str(bare)]) == 2
    assert "carries no scene file; give one with --scene" in capsys.readouterr().err


def test_a_replays_output_carries_the_recorded_scene_and_replays_in_turn(recorded, cache, tmp_path):
    """`twin replay --out` of a recording's own scene wrote no scene: its replay.mcap could not be replayed."""
    path, _, _ = recorded
    first = replay(path, cache_dir=cache, out=tmp_path / "one", duration=0.3)
    meta = read_recording(tmp_path / "one" / "replay.mcap").metadata
    assert meta["scene_toml"] == SMALL.read_text() and meta["scene_name"] == "small"
    second = replay(tmp_path / "one" / "replay.mcap", cache_dir=cache, duration=0.3)
    assert second.twin_poses["crate"].tobytes() == first.twin_poses["crate"].tobytes()


def test_twin_replay_runs_as_a_command(recorded, cache):
    path, _, _ = recorded
    done = subprocess.run([sys.executable, "-m", "cli.main", "replay", str(path), "--duration", "0.5",
                           "--cache-dir", str(cache)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "replayed" in done.stdout and "x real time" in done.stdout


@pytest.mark.slow
def test_an_experiment_on_a_recording_replays_its_operator_under_each_delay(recorded, cache, tmp_path, monkeypatch):
    import csv

    monkeypatch.setenv("TWIN_CACHE_DIR", str(cache))
    out = tmp_path / "sweep"
    path, _, _ = recorded
    assert main(["experiment", str(path), "--delays", "0,50", "--workers", "0", "--out", str(out)]) == 0
    with (out / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert {r["task"] for r in rows} == {"recorded"}
    assert sorted((r["mode"], float(r["delay_ms"])) for r in rows) == [
        ("direct", 0.0), ("direct", 50.0), ("twin", 0.0), ("twin", 50.0)]
    direct = {float(r["delay_ms"]): r for r in rows if r["mode"] == "direct"}
    assert float(direct[0.0]["force_rms_n"]) == 0.0  # direct at zero delay is the truth
    assert float(direct[0.0]["truth_peak_n"]) > 1.0  # the recorded push reached the crate
    assert float(direct[50.0]["force_rms_n"]) > 0.0
    assert float(direct[50.0]["perceived_delay_ms"]) >= 100.0


def test_an_experiment_asks_for_what_its_input_can_give(recorded, tmp_path, capsys):
    assert main(["experiment", str(SMALL), "--tasks", "recorded", "--out", str(tmp_path / "a")]) == 2
    assert "--tasks recorded needs a recording (.mcap)" in capsys.readouterr().err
    remote_only = tmp_path / "remote.mcap"
    with Recorder(remote_only, clock=SimClock(), metadata={"scene_toml": SMALL.read_text(),
                                                           "scene_dir": str(SMALL.parent)}):
        pass
    assert main(["experiment", str(remote_only), "--out", str(tmp_path / "b")]) == 2
    assert "the recording has no operator targets" in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_an_experiment_refuses_a_recorded_operator_out_of_reach_as_replay_does(tmp_path, capsys):
    """Replay refused a target under the floor; the experiment ran it: a 27 kN twin row in results.csv."""
    path = tmp_path / "floor.mcap"
    with Recorder(path, clock=SimClock(), metadata={"scene_toml": SMALL.read_text(),
                                                    "scene_dir": str(SMALL.parent)}) as r:
        r.target(0.0, np.array([0.0, 0.0, 0.9]))
        r.target(0.5, np.array([0.0, 0.0, -5.0]))
    for command in (["replay", str(path)], ["experiment", str(path), "--delays", "0", "--out", str(tmp_path / "x")]):
        assert main(command) == 2
        err = capsys.readouterr().err
        assert "the target at t = 0.5 s, (0, 0, -5) m, is outside the operator's reach" in err, err
        assert err.count("\n") == 1
    assert not (tmp_path / "x").exists()
    # The scene's own tasks do not use the recorded operator: they run.
    assert main(["experiment", str(path), "--tasks", "push", "--delays", "0", "--workers", "0", "--speed", "4",
                 "--out", str(tmp_path / "y")]) == 0


def test_an_experiment_on_a_recording_without_a_scene_takes_one_with_scene(tmp_path, capsys, cache, monkeypatch):
    """`twin local` records no scene: the error said to give --scene, which twin experiment did not take."""
    monkeypatch.setenv("TWIN_CACHE_DIR", str(cache))
    path = tmp_path / "local.mcap"
    with Recorder(path, clock=SimClock(), metadata={"command": "local", "side": "twin"}) as r:
        r.target(0.0, np.array([-0.3, 0.0, 0.56]))
        r.target(0.3, np.array([-0.2, 0.0, 0.56]))
    base = ["experiment", str(path), "--delays", "0", "--workers", "0"]
    assert main([*base, "--out", str(tmp_path / "a")]) == 2
    assert "carries no scene file; give one with --scene" in capsys.readouterr().err
    assert main([*base, "--scene", str(SMALL), "--out", str(tmp_path / "b")]) == 0
    said = capsys.readouterr()
    # The result on stdout, one line; the progress bar on stderr (it went to stdout).
    assert "rows (surface sensor)" in said.out and said.out.count("\n") == 1 and "sessions" in said.err, said
    assert main(["experiment", str(SMALL), "--scene", str(SMALL), "--out", str(tmp_path / "c")]) == 2
    assert "--scene is for a recording's scene" in capsys.readouterr().err


def test_a_recorded_scene_folder_is_read_only_where_the_recording_or_the_package_is(tmp_path, capsys):
    import trimesh

    from cli.record import recorded_scene

    elsewhere = tmp_path / "designs"  # someone's own folder, named by a recording made elsewhere
    elsewhere.mkdir()
    trimesh.creation.box(extents=[0.05] * 3).export(elsewhere / "part.stl")
    toml = SMALL.read_text().split("[[objects]]")[0] + (
        '[[objects]]\nid = "part"\nmesh = "part.stl"\nmaterial = "wood_pine"\nposition = [0.0, 0.0]\n')
    shared = tmp_path / "shared"
    shared.mkdir()
    path = shared / "handed_around.mcap"
    with Recorder(path, clock=SimClock(), metadata={"scene_toml": toml, "scene_dir": str(elsewhere)}):
        pass
    assert main(["replay", str(path), "--duration", "0.1"]) == 2
    err = capsys.readouterr().err
    assert f"it was recorded in {elsewhere}, which is not read unasked" in err and err.count("\n") == 1, err
    # The same file beside the recording is read: a recording and its meshes handed around together.
    (shared / "part.stl").write_bytes((elsewhere / "part.stl").read_bytes())
    assert [o.id for o in recorded_scene(read_recording(path)).objects] == ["part"]
    # The package's own scenes are read where the package is.
    packaged = ROOT / "scenes" / "data" / "mixed100.toml"
    with Recorder(path, clock=SimClock(), metadata={"scene_toml": packaged.read_text(),
                                                    "scene_dir": str(packaged.parent)}):
        pass
    assert len(recorded_scene(read_recording(path)).objects) == 100


def test_replay_out_never_overwrites_an_input_or_a_users_folder(recorded, cache, tmp_path, capsys):
    path, _, _ = recorded
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "summary.json").write_text("my own notes\n")
    assert main(["replay", str(path), "--out", str(mine), "--duration", "0.1", "--cache-dir", str(cache)]) == 2
    err = capsys.readouterr().err
    assert "not a folder this command wrote" in err and err.count("\n") == 1, err
    assert [p.name for p in mine.iterdir()] == ["summary.json"] and (mine / "summary.json").read_text() == "my own notes\n"
    out = tmp_path / "out"
    assert main(["replay", str(path), "--out", str(out), "--duration", "0.1", "--cache-dir", str(cache)]) == 0
    capsys.readouterr()
    first = (out / "replay.mcap").read_bytes()
    # The folder is replay's own now, but its replay.mcap is this replay's input: refused, not truncated.
    assert main(["replay", str(out / "replay.mcap"), "--out", str(out), "--duration", "0.1"]) == 2
    assert "is the input" in capsys.readouterr().err
    assert (out / "replay.mcap").read_bytes() == first


def test_record_refuses_an_input_or_a_users_file_and_a_failed_start_leaves_the_file(recorded, tmp_path, capsys):
    path, _, _ = recorded
    before = path.read_bytes()
    args = ["local", "--replay-operator", str(path), "--record", str(path), "--duration", "1"]
    assert main(args) == 2
    assert "is the input" in capsys.readouterr().err and path.read_bytes() == before
    notes = tmp_path / "notes.mcap"
    notes.write_text("precious\n")
    assert main(["local", "--record", str(notes), "--duration", "1"]) == 2
    assert "not a recording this program wrote" in capsys.readouterr().err and notes.read_text() == "precious\n"
    # A recorder whose session never started leaves an earlier recording as it was, and nothing beside it.
    kept = tmp_path / "kept.mcap"
    kept.write_bytes(before)
    Recorder(kept, clock=SimClock()).discard()
    assert kept.read_bytes() == before and sorted(tmp_path.iterdir()) == sorted([notes, kept])
    with Recorder(kept, clock=SimClock()) as r:  # one that ran replaces it, when it is closed
        r.target(0.0, np.zeros(3))
        assert kept.read_bytes() == before
    assert read_recording(kept).counts[TARGET_TOPIC] == 1


def _rewrite(src: Path, dst: Path, *, topic: str | None = None, data: bytes = b"", end: dict | None = None,
             session: dict | None = None, drop: tuple[str, ...] = ()) -> Path:
    """A copy of recording ``src`` with the first message on ``topic`` replaced by ``data``, and entries of
    the end or session metadata replaced (``drop``: session entries left out): valid MCAP, bad content."""
    from mcap.records import Channel, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import Writer

    with src.open("rb") as f, dst.open("wb") as g:
        w = Writer(g)
        w.start(profile="tactile-twin")
        schemas, channels, done = {}, {}, False
        for r in StreamReader(f).records:
            if isinstance(r, Schema):
                schemas[r.id] = w.register_schema(r.name, r.encoding, r.data)
            elif isinstance(r, Channel):
                channels[r.id] = (w.register_channel(r.topic, r.message_encoding, schemas.get(r.schema_id, 0),
                                                     dict(r.metadata)), r.topic)
            elif isinstance(r, Message):
                cid, name = channels[r.channel_id]
                replace = name == topic and not done
                done = done or replace
                w.add_message(cid, r.log_time, data if replace else r.data, r.publish_time)
            elif isinstance(r, Metadata):
                extra = {"tactile_twin.end": end, "tactile_twin.session": session}.get(r.name) or {}
                w.add_metadata(r.name, {k: v for k, v in {**dict(r.metadata), **extra}.items() if k not in drop})
        w.finish()
    return dst


@pytest.mark.parametrize(("change", "words"), [
    ({"topic": TARGET_TOPIC, "data": b'{"position": {"x": 0, "y": 0, "z": 0}}'}, "/operator/target record's sim_time is missing"),
    ({"topic": TARGET_TOPIC, "data": b"[1, 2]"}, "/operator/target record is not a JSON object"),
    ({"topic": TARGET_TOPIC, "data": b"\xff\xfe garbage"}, "/operator/target record is not JSON"),
    ({"topic": TARGET_TOPIC, "data": b'{"sim_time": NaN, "position": {"x": 0, "y": 0, "z": 0}}'}, "sim_time nan is outside"),
    ({"topic": TARGET_TOPIC, "data": b'{"sim_time": 0.1, "position": {"x": 1e300, "y": 0, "z": 0}}'}, "position.x 1e+300 is outside"),
    ({"topic": TARGET_TOPIC, "data": b'{"sim_time": 1e9, "position": {"x": 0, "y": 0, "z": 0}}'}, "sim_time 1e+09 is outside"),
    # JSON integers have no bound: a 401-digit one was an OverflowError traceback.
    ({"topic": TARGET_TOPIC, "data": b'{"sim_time": 1' + b"0" * 400 + b', "position": {"x": 0, "y": 0, "z": 0}}'},
     "sim_time is an integer of about 401 digits, outside"),
    ({"topic": TARGET_TOPIC, "data": b'{"sim_time": 0.1, "position": {"x": -1' + b"0" * 400 + b', "y": 0, "z": 0}}'},
     "position.x is an integer of about 401 digits, outside [-1000, 1000]"),
    ({"topic": TRUTH_TOPIC, "data": b'{"sim_time": 0, "transforms": [{"child_frame_id": 5}]}'}, "child_frame_id is not a string"),
    ({"topic": TRUTH_TOPIC, "data": b"{not json"}, "/truth/transforms record is not JSON"),
    ({"end": {"twin_time_s": "inf"}}, "twin_time_s inf is outside"),
    ({"end": {"twin_time_s": "1e12"}}, "twin_time_s 1e+12 is outside"),
    ({"end": {"twin_time_s": "abc"}}, "twin_time_s 'abc' is not a number"),
    ({"session": {"network": json.dumps({"uplink": {"delay": 0.01}, "downlink": None, "seed": -5})}}, "seed must be"),
    ({"session": {"scene_toml": 'name="x"\nq=' + "[" * 5000 + "]" * 5000 + "\n"}}, "nested too deeply"),
    ({"session": {"scene_toml": 'name="x"\nq=1' + "0" * 5000 + "\n"}}, "the recorded scene: not a scene file Python"),
    ({"session": {"scene_toml": 'name="x"\n[[objects]]\nid="a"\nprimitive={type="box",size=[0.05,0.05,0.05]}\n'
                                'position=[1' + "0" * 400 + ',0]\n'}}, "not a valid scene"),
    ({"session": {"network": json.dumps({"uplink": {"rate_bps": 1e-300}, "downlink": None, "seed": 0})}}, "rate_bps"),
    ({"topic": TARGET_TOPIC, "data": b"[" * 100_000 + b"]" * 100_000}, "/operator/target record is not JSON"),
    ({"topic": TRUTH_TOPIC, "data": b"[" * 100_000 + b"]" * 100_000}, "/truth/transforms record is not JSON"),
    # 5 MiB of transforms in one record (a review's 96 KB file held eight of 120 MiB: 7.5 GB to replay).
    ({"topic": TRUTH_TOPIC, "data": b'{"sim_time": 0, "transforms": [' + b",".join(
        [b'{"child_frame_id": "truth/x", "translation": {"x": 0, "y": 0, "z": 0}, "rotation": {"x": 0, "y": 0, '
         b'"z": 0, "w": 1}}'] * 50_000) + b"]}"}, "/truth/transforms record of 5,"),
    ({"session": {"network": "[" * 100_000 + "]" * 100_000}}, "unreadable network metadata"),
    # A number written as text would have reached the link model's arithmetic mid-replay.
    ({"session": {"network": json.dumps({"uplink": None, "downlink": {"delay": "0.05"}, "seed": 0})}}, "delay must be a number"),
    ({"session": {"network": json.dumps({"uplink": None, "downlink": {"reorder": "yes"}, "seed": 0})}}, "reorder must be"),
    ({"session": {"network": json.dumps({"uplink": None, "downlink": None, "seed": 1.5})}}, "seed must be an integer"),
    # A misspelt side replayed with no network at all, and said nothing.
    ({"session": {"network": json.dumps({"uplinks": {"delay": 0.05}, "seed": 0})}}, "unknown key 'uplinks'; known: uplink"),
    ({"session": {"network": json.dumps([{"delay": 0.05}])}}, "a JSON list, not an object"),
    ({"session": {"sensor": "lidar"}}, "the recorded sensor 'lidar' is not one replay knows (surface, cameras)"),
    ({"session": {"sensor": "x" * 10_000}}, "the recorded sensor 'xxxxxxxxxxxxxxxxxxxxxxxx..."),
])
def test_malformed_records_are_one_line_errors_naming_the_record_and_field(recorded, tmp_path, capsys, change, words):
    path, _, _ = recorded
    bad = _rewrite(path, tmp_path / "bad.mcap", **change)
    commands = [["replay", str(bad), "--duration", "0.1"]]
    if "topic" in change and change["topic"] == TARGET_TOPIC:
        commands += [["local", "--replay-operator", str(bad)], ["experiment", str(bad), "--out", str(tmp_path / "x")]]
    for command in commands:
        assert main(command) == 2, command
        err = capsys.readouterr().err
        assert words in err and err.count("\n") == 1 and "Traceback" not in err, err
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("topic", [TARGET_TOPIC, TRUTH_TOPIC])
def test_records_whose_time_goes_back_are_a_one_line_error_naming_the_record(tmp_path, capsys, topic):
    """Truth records in reverse time order replayed with no damage and an empty truth comparison (null stats,
    no objects): replay looks truth samples up by time. Targets were refused; truth now is, the same way."""
    path = tmp_path / "back.mcap"
    pose = (np.array([0.0, 0.0, 0.45]), np.array([1.0, 0.0, 0.0, 0.0]))
    with Recorder(path, clock=SimClock(), metadata={"scene_toml": SMALL.read_text(),
                                                    "scene_dir": str(SMALL.parent)}) as r:
        for t in (0.0, 0.5, 0.2) if topic == TARGET_TOPIC else (0.0, 0.2, 0.5):
            r.target(t, np.array([-0.3, 0.0, 0.56]))
        for t in (0.0, 0.5, 0.2) if topic == TRUTH_TOPIC else (0.0, 0.2, 0.5):
            r.truth(t, {"crate": pose})
    words = f"{topic} record's sim_time 0.2 s goes back (previous 0.5 s)"
    rec = read_recording(path)
    assert rec.damage is None  # written whole: inconsistent, not torn
    read = rec.targets if topic == TARGET_TOPIC else rec.truth
    with pytest.raises(RecordingError, match=r"goes back \(previous 0\.5 s\)") as caught:
        read()
    assert words in str(caught.value)
    assert main(["replay", str(path)]) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1 and "Traceback" not in err, err


def test_a_changed_byte_in_the_session_metadata_fails_the_checksum(tmp_path):
    """The scene's density flipped from 700 to 300 replayed another scene without a word: chunk CRCs cover
    messages, not metadata. The data section's CRC covers both."""
    path = tmp_path / "r.mcap"
    with Recorder(path, clock=SimClock(), metadata={"scene_toml": SMALL.read_text()}) as r:
        for k in range(50):
            r.target(k / 100, np.array([0.0, 0.0, 0.6]))
    assert read_recording(path).damage is None
    data = bytearray(path.read_bytes())
    at = data.find(b"density = 700") + len("density = ")
    data[at] = ord("3")
    flipped = tmp_path / "flipped.mcap"
    flipped.write_bytes(bytes(data))
    rec = read_recording(flipped)
    assert "density = 300" in rec.metadata["scene_toml"]  # read, but not trusted silently
    assert rec.damage is not None and "fails its checksum" in rec.damage and len(rec.targets()[0]) == 50


def test_a_damaged_zstd_chunk_is_damage_not_a_traceback(recorded, tmp_path):
    from mcap.writer import CompressionType, Writer

    session = read_recording(recorded[0]).metadata
    path = tmp_path / "damaged.mcap"
    with path.open("wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD, chunk_size=1 << 10)
        w.start(profile="tactile-twin")
        w.add_metadata("tactile_twin.session", session)
        channel = w.register_channel(FORCE_TOPIC, "json", 0)
        for i in range(200):
            w.add_message(channel, i, b'{"sim_time": %d, "force": [0.0, 0.0, 0.0]}' % i, i)
        w.finish()
    data = bytearray(path.read_bytes())
    frame = data.index(b"\x28\xb5\x2f\xfd", data.index(b"\x28\xb5\x2f\xfd") + 4)  # the second chunk's frame
    data[frame + 4 : frame + 40] = b"\xff" * 36
    path.write_bytes(bytes(data))
    # zstandard's C backend raises ZstdError, which is no ValueError: it escaped as a traceback (exit 1)
    rec = read_recording(path)
    assert rec.damage is not None and "a chunk's zstd data is damaged" in rec.damage and "\n" not in rec.damage
    assert 0 < len(rec.records) < 200


def test_a_decompression_bomb_is_refused_naming_the_limit(recorded, tmp_path, capsys):
    from mcap.writer import CompressionType, Writer

    from sync.recording import MAX_RECORD_BYTES

    session = read_recording(recorded[0]).metadata
    bomb = tmp_path / "bomb.mcap"
    with bomb.open("wb") as f:  # one message of zeros just past the limit: ~130 KB on disk
        w = Writer(f, compression=CompressionType.ZSTD, chunk_size=1 << 20)
        w.start(profile="tactile-twin")
        w.add_metadata("tactile_twin.session", session)
        channel = w.register_channel(FORCE_TOPIC, "json", 0)
        w.add_message(channel, 0, bytes(MAX_RECORD_BYTES + 1), 0)
        w.finish()
    assert bomb.stat().st_size < 1 << 20
    assert main(["replay", str(bomb)]) == 2
    err = capsys.readouterr().err
    assert f"more than the {MAX_RECORD_BYTES >> 20} MiB limit" in err and err.count("\n") == 1, err


def test_a_recording_of_more_records_than_the_limit_is_refused(recorded, tmp_path, monkeypatch, capsys):
    import sync.recording

    path, _, _ = recorded
    held = len(read_recording(path).records)
    monkeypatch.setattr(sync.recording, "MAX_RECORDS", held - 1)  # empty records cost memory too
    assert main(["replay", str(path), "--duration", "0.1"]) == 2
    err = capsys.readouterr().err
    assert f"more than {held - 1:,} records, the limit" in err and err.count("\n") == 1


def test_a_small_file_packed_with_empty_records_is_refused_by_its_size(recorded, tmp_path, capsys):
    # 16 M empty messages in four zstd chunks, 43 KB, took 4 GB and 87 s to read: under MAX_RECORDS, ~250 bytes
    # of Python each. Now at most one record per byte of file, and a chunk's records are read one at a time.
    from mcap.writer import CompressionType, IndexType, Writer

    packed = tmp_path / "packed.mcap"
    with packed.open("wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD, chunk_size=64 << 20, index_types=IndexType.NONE)
        w.start(profile="tactile-twin")
        w.add_metadata("tactile_twin.session", read_recording(recorded[0]).metadata)
        channel = w.register_channel(FORCE_TOPIC, "json", 0)
        for _ in range(200_000):
            w.add_message(channel, 0, b"", 0)
        w.finish()
    size = packed.stat().st_size
    assert size < 20_000
    assert main(["replay", str(packed)]) == 2
    err = capsys.readouterr().err
    assert (f"packed.mcap: holds more than {size:,} records in {size:,} bytes, more than 1 a byte" in err
            and err.count("\n") == 1), err
    # A recording of ours takes 20-40 bytes a record even where nothing changes but the time, and reads whole.
    dense, clock = tmp_path / "dense.mcap", SimClock()
    with Recorder(dense, clock=clock, metadata={}) as r:
        for _ in range(20_000):
            clock.advance(0.001)
            r.target(clock.now(), np.zeros(3))
    assert len(read_recording(dense).records) == 20_000 and dense.stat().st_size > 20 * 20_000


def test_a_damaged_recording_with_nothing_left_to_replay_says_it_is_damaged(recorded, tmp_path, capsys):
    path, _, _ = recorded
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(path.read_bytes()[:2000])  # the session metadata and little else
    rec = read_recording(torn)
    assert rec.damage is not None
    assert main(["replay", str(torn)]) == 2
    err = capsys.readouterr().err
    assert "nothing to replay" in err and "damaged after" in err and err.count("\n") == 1, err


def _chunk_offsets(data: bytes) -> list[tuple[int, int]]:
    """(start, length) of each top-level Chunk record of an MCAP file, walking its records' framing."""
    from mcap.opcode import Opcode

    out, at = [], 8  # past the magic
    while at + 9 <= len(data):
        opcode, length = data[at], int.from_bytes(data[at + 1 : at + 9], "little")
        if opcode == Opcode.CHUNK:
            out.append((at, length))
        if opcode == Opcode.FOOTER:
            break
        at += 9 + length
    return out


def test_a_damaged_chunk_mid_file_is_skipped_and_the_rest_replays(recorded, cache, tmp_path, capsys):
    path, _, _ = recorded
    whole = read_recording(path)
    data = bytearray(path.read_bytes())
    chunks = _chunk_offsets(bytes(data))
    assert len(chunks) >= 5, len(chunks)
    start, length = chunks[len(chunks) // 2]
    data[start + 9 + length - 100] ^= 0xFF  # one byte inside the chunk's compressed records
    damaged = tmp_path / "flipped.mcap"
    damaged.write_bytes(bytes(data))
    rec = read_recording(damaged)
    # Only that chunk's messages are lost: those after it, the end record included, are still read.
    assert rec.damage is not None and "1 damaged chunk skipped" in rec.damage and "\n" not in rec.damage
    assert rec.end is not None and rec.records[-1] == whole.records[-1]
    lost = len(whole.records) - len(rec.records)
    assert 0 < lost < len(whole.records) / 4 and f"({lost} messages logged at" in rec.damage, rec.damage
    kept = {(r.topic, r.log_time, r.data) for r in rec.records}
    assert kept < {(r.topic, r.log_time, r.data) for r in whole.records}
    assert main(["replay", str(damaged), "--json", "--cache-dir", str(cache)]) == 0
    captured = capsys.readouterr()
    assert captured.err.count("damaged chunk skipped") == 1 and "warning" in captured.err
    assert json.loads(captured.out)["duration_s"] == pytest.approx(SECONDS, abs=0.01)


def test_damaged_chunks_at_the_end_are_reported_and_what_comes_before_replays(recorded, cache, tmp_path, capsys):
    """Damaged chunks covering the last second and more left the end record's stop time past the intact records'
    span: the replay was refused for that time, without a word of the damage. The damage is said and the intact
    part replays, to its last target."""
    path, _, _ = recorded
    whole = read_recording(path)
    data = bytearray(path.read_bytes())
    chunks = _chunk_offsets(bytes(data))
    lost = [c for c in chunks if c[0] > chunks[len(chunks) // 2][0]]  # the second half of the session
    for start, length in lost:
        data[start + 9 + length // 2] ^= 0x55
    damaged = tmp_path / "tail.mcap"
    damaged.write_bytes(bytes(data))
    rec = read_recording(damaged)
    assert rec.damage is not None and f"{len(lost)} damaged chunks skipped" in rec.damage, rec.damage
    assert rec.end is not None and rec.span_s + RECORDED_TIME_SLACK_S < SECONDS  # the stop is past what is left
    assert rec.end_time() is None
    assert main(["replay", str(damaged), "--json", "--cache-dir", str(cache)]) == 0
    captured = capsys.readouterr()
    assert "damaged chunks skipped" in captured.err and "warning" in captured.err, captured.err
    assert 0 < json.loads(captured.out)["duration_s"] < SECONDS - 1.0
    assert 0 < len(rec.topic(TARGET_TOPIC)) < len(whole.topic(TARGET_TOPIC))
    # An undamaged recording's stop past its records is still refused: that is a forged or broken end record.
    with pytest.raises(RecordingError, match="the end record's twin_time_s"):
        Recording(path, whole.metadata, whole.records[: len(whole.records) // 4], whole.end, None,
                  whole.counts).end_time()


def test_a_folder_a_pipe_or_a_device_is_named_not_read(tmp_path, capsys):
    fifo = tmp_path / "pipe.mcap"
    os.mkfifo(fifo)
    for bad, words in [(tmp_path, "is a folder, not a recording"), (fifo, "is not a regular file"),
                       (Path("/dev/zero"), "is not a regular file")]:
        with pytest.raises(RecordingError, match=words):
            read_recording(bad)  # a FIFO blocked the read; /dev/zero was called "no such recording"
        assert main(["replay", str(bad)]) == 2
        err = capsys.readouterr().err
        assert words in err and err.count("\n") == 1, err


def test_a_chunk_length_past_the_index_range_is_damage_not_a_traceback(recorded, tmp_path):
    """A hostile-input review flipped the top bit of a chunk's records_length (a field inside the chunk, after
    its compression name): the reader asked Python to slice 2**63 bytes and OverflowError escaped (exit 1)."""
    path, _, _ = recorded
    data = bytearray(path.read_bytes())
    chunks = _chunk_offsets(bytes(data))
    start, _ = chunks[len(chunks) // 2]
    # opcode, length, start and end times, uncompressed size, crc, "zstd" as a 4-byte length and 4 bytes: 45 bytes
    data[start + 52] ^= 0x80  # records_length's most significant byte
    damaged = tmp_path / "topbit.mcap"
    damaged.write_bytes(bytes(data))
    rec = read_recording(damaged)
    assert rec.damage is not None and "OverflowError" in rec.damage and "\n" not in rec.damage
    assert 0 < len(rec.records) < len(read_recording(path).records)


def test_an_oversized_record_mid_file_is_damage_and_the_intact_part_replays(recorded, cache, tmp_path, capsys):
    """One byte (the top byte of the middle chunk's length) refused the whole recording with the 128 MiB limit,
    while truncating the file at that byte kept the first half: it is damage at that point, as truncation is."""
    path, _, _ = recorded
    data = bytearray(path.read_bytes())
    whole = read_recording(path)
    start, _ = _chunk_offsets(bytes(data))[len(_chunk_offsets(bytes(data))) // 2]
    data[start + 8] = 0x01  # the length field's top byte: the chunk now claims 2**56 bytes
    damaged = tmp_path / "onebyte.mcap"
    damaged.write_bytes(bytes(data))
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(bytes(data[:start]))
    rec, truncated = read_recording(damaged), read_recording(cut)
    assert rec.damage is not None and "damaged after" in rec.damage and "128 MiB limit" in rec.damage
    assert "\n" not in rec.damage and len(rec.records) == len(truncated.records) > 0
    assert [r.data for r in rec.records] == [r.data for r in whole.records[: len(rec.records)]]
    assert main(["replay", str(damaged), "--duration", "0.3", "--json", "--cache-dir", str(cache)]) == 0
    captured = capsys.readouterr()
    assert captured.err.count("damaged after") == 1 and "warning" in captured.err
    assert json.loads(captured.out)["damage"] == rec.damage
    # Nothing intact: the first record (the header) oversized is still the one-line error.
    first = bytearray(path.read_bytes())
    first[8 + 8] = 0x01  # past the magic, the header record's length field's top byte
    damaged.write_bytes(bytes(first))
    with pytest.raises(RecordingError, match=r"a record is larger than the 128 MiB limit"):
        read_recording(damaged)
    assert main(["replay", str(damaged)]) == 2
    err = capsys.readouterr().err
    assert "128 MiB limit" in err and err.count("\n") == 1, err


def test_a_recorder_refuses_a_folder_or_a_users_file_when_it_opens(tmp_path):
    """A folder at the path failed only at close(), after the whole session, leaving the hidden .partial."""
    (tmp_path / "dir.mcap").mkdir()
    notes = tmp_path / "notes.mcap"
    notes.write_text("precious\n")
    for bad, words in [(tmp_path / "dir.mcap", "is a folder, not a recording file"),
                       (notes, "exists and is not a recording this program wrote; refusing to replace it")]:
        with pytest.raises(RecordingError, match=words):
            Recorder(bad, clock=SimClock())
    assert notes.read_text() == "precious\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir.mcap", "notes.mcap"]  # no .partial


def test_another_tools_mcap_is_a_users_file_and_an_own_recording_is_replaced(tmp_path):
    """An MCAP another tool wrote (a ROS 2 bag) starts with the same magic: only the header's profile and library
    tell this program's recordings from it."""
    from mcap.writer import Writer

    bag = tmp_path / "bag.mcap"
    with bag.open("wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="rosbag2")
        schema = w.register_schema("std_msgs/String", "ros2msg", b"string data")
        channel = w.register_channel("/chatter", "cdr", schema)
        w.add_message(channel, log_time=1, publish_time=1, data=b"hello")
        w.finish()
    before = bag.read_bytes()
    with pytest.raises(RecordingError, match="not a recording this program wrote"):
        Recorder(bag, clock=SimClock())
    assert bag.read_bytes() == before
    own = tmp_path / "own.mcap"
    Recorder(own, clock=SimClock()).close()
    first = own.read_bytes()
    assert written_here(first[:512])
    r = Recorder(own, clock=SimClock())  # its own earlier recording: replaced
    r.target(0.0, np.zeros(3))
    r.close()
    assert own.read_bytes() != first and written_here(own.read_bytes()[:512])
    assert not written_here(before[:512]) and not written_here(first[:20])


def test_a_failed_final_rename_keeps_the_whole_recording_and_names_it_in_one_line(tmp_path):
    path = tmp_path / "late.mcap"
    r = Recorder(path, clock=SimClock())
    r.target(0.0, np.zeros(3))
    path.mkdir()  # a folder appears there during the session
    with pytest.raises(RecordingError, match=r"late.mcap: cannot put the recording in place \(Is a directory\); "
                                             r"it is kept as ") as e:
        r.close()
    assert "\n" not in str(e.value)
    kept = Path(str(e.value).rsplit("it is kept as ", 1)[1])
    assert path.is_dir() and kept.parent == tmp_path and kept.is_file()
    whole = read_recording(kept)  # nothing lost: the session is all there
    assert whole.damage is None and len(whole.topic(TARGET_TOPIC)) == 1


def test_a_recording_gets_the_permissions_open_gives_not_0600(tmp_path):
    """Recordings were mkstemp's 0600, and replaced an earlier recording's 0644 with it."""
    umask = os.umask(0o022)
    try:
        path = tmp_path / "shared.mcap"
        for _ in range(2):  # created, then replacing the first
            with Recorder(path, clock=SimClock()) as r:
                r.target(0.0, np.zeros(3))
            assert path.stat().st_mode & 0o777 == 0o644
    finally:
        os.umask(umask)


def test_demo_refuses_a_remote_recording_path_it_must_not_replace_before_starting(tmp_path, capsys):
    """``--record notes.mcap`` made the remote write ``notes.remote.mcap`` over the user's file, exit 0; a folder
    there was a traceback in the remote process at the end, the recording lost."""
    notes = tmp_path / "notes.remote.mcap"
    notes.write_text("notes\n")
    (tmp_path / "dd.remote.mcap").mkdir()
    for record, words in [(tmp_path / "notes.mcap", f"the remote's side goes to {notes}: exists and is not a "
                                                    "recording this program wrote; refusing to replace it"),
                          (tmp_path / "dd.mcap", "dd.remote.mcap: is a folder, not a recording file")]:
        assert main(["demo", "--scene", str(SMALL), "--duration", "1", "--record", str(record),
                     "--rerun", "save", str(tmp_path / "v.rrd")]) == 2  # refused before rerun starts writing
        err = capsys.readouterr().err
        assert words in err and f"--record {record}" in err and err.count("\n") == 1, err
    assert notes.read_text() == "notes\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dd.remote.mcap", "notes.remote.mcap"]


@pytest.mark.slow  # a remote process each; the default run is near its 10 minutes
@pytest.mark.parametrize("twin_started", [False, True])
def test_the_demos_remote_keeps_an_earlier_recording_when_the_twin_never_started(tmp_path, twin_started):
    """The remote records in its own process; when the twin then failed to start (a scene no twin could join),
    the remote still put its recording over an earlier FILE.remote.mcap, exit 2. The parent now tells it to
    discard (``discard`` set before ``stop``); a session that ran replaces the file as before."""
    import multiprocessing as mp

    from cli.demo import _remote_main
    from sync.zenoh_transport import free_port

    earlier = tmp_path / "demo.remote.mcap"
    with Recorder(earlier, clock=SimClock(), metadata={"note": "earlier"}):
        pass
    before = earlier.read_bytes()
    ctx = mp.get_context("spawn")
    ready, stop, discard, results = ctx.Event(), ctx.Event(), ctx.Event(), ctx.Queue()
    remote = ctx.Process(target=_remote_main, args=(str(SMALL), f"tcp/127.0.0.1:{free_port()}", None, ready, stop,
                                                    results, str(earlier), "surface", discard))
    remote.start()
    try:
        assert ready.wait(120)
        if not twin_started:
            discard.set()
        stop.set()
        said = results.get(timeout=60)
    finally:
        remote.join(timeout=30)
        if remote.is_alive():
            remote.terminate()
    assert "error" not in said
    assert (earlier.read_bytes() == before) is (not twin_started)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo.remote.mcap"]  # no partial file left


# -- the remote's sensor ----------------------------------------------------------------------------------------

ONE_CAN = """name = "onecan"
[table]
size = [1.0, 0.6, 0.04]
height = 0.5
[end_effector]
position = [-0.45, -0.28, 0.6]
[[objects]]
id = "can"
primitive = { type = "cylinder", size = [0.04, 0.12] }
density = 1000
position = [0.1, 0.05]
"""


def test_a_camera_session_is_recorded_with_its_sensor_and_replays_with_it(cache, tmp_path):
    """Replay built every recording's remote with the surface sensor: a camera session replayed as another one."""
    from scenes.sensing import CameraSensor

    (tmp_path / "onecan.toml").write_text(ONE_CAN)
    scene = load_scene(tmp_path / "onecan.toml")
    path = tmp_path / "cameras.mcap"
    with Headless(scene, cache_dir=cache, record=path, sensor=CameraSensor.for_scene(scene)) as session:
        session.run(0.3)
        twin = {i: np.concatenate(p) for i, p in session.poses().items()}
        mass = float(session.local.twin.model.body("can").mass[0])
    assert read_recording(path).metadata["sensor"] == "cameras"
    result = replay(path, cache_dir=cache, out=tmp_path / "out")
    assert result.summary["sensor"] == "cameras"
    assert read_recording(tmp_path / "out" / "replay.mcap").metadata["sensor"] == "cameras"  # what it ran with
    # The cameras' cloud, not the true surface's: the same twin, bit for bit.
    assert sorted(result.twin_poses) == ["can"]
    assert result.twin_poses["can"].tobytes() == twin["can"].tobytes()
    with Headless(scene, cache_dir=cache) as surface:
        surface.run(0.05)
        assert float(surface.local.twin.model.body("can").mass[0]) != pytest.approx(mass, rel=1e-4)
    # --sensor replaces the recorded one.
    assert replay(path, cache_dir=cache, sensor="surface", duration=0.05).summary["sensor"] == "surface"


def test_a_recording_that_names_no_sensor_replays_with_the_surface_sensor_and_says_so(recorded, cache, tmp_path,
                                                                                        caplog, capsys):
    path, _, _ = recorded
    assert read_recording(path).metadata["sensor"] == "surface"  # a headless session with the default sensor
    older = _rewrite(path, tmp_path / "older.mcap", drop=("sensor",))  # as every recording made before
    assert "sensor" not in read_recording(older).metadata
    with caplog.at_level(logging.WARNING, logger="cli.record"):
        summary = replay(older, cache_dir=cache, duration=0.1).summary
    assert summary["sensor"] == "surface"
    said = [r.getMessage() for r in caplog.records if r.name == "cli.record"]
    assert len(said) == 1 and "names no sensor" in said[0] and "surface" in said[0] and "--sensor" in said[0], said
    # A sensor the recording names that replay does not know: --sensor replaces it, and the replay runs.
    bad = _rewrite(path, tmp_path / "bad.mcap", session={"sensor": "lidar"})
    assert main(["replay", str(bad), "--sensor", "surface", "--duration", "0.1", "--cache-dir", str(cache)]) == 0
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:  # the command line's own choices
        main(["replay", str(bad), "--sensor", "lidar"])
    assert exc.value.code == 2 and "invalid choice: 'lidar'" in capsys.readouterr().err


def test_the_live_commands_record_their_remotes_sensor(tmp_path):
    from cli.main import _parser
    from cli.record import open_recorder
    from scenes.headless import SENSORS

    for sensor in SENSORS:
        path = tmp_path / f"{sensor}.mcap"
        open_recorder(path, clock=SimClock(), command="remote", side="remote", scene_path=SMALL, sensor=sensor).close()
        assert read_recording(path).metadata["sensor"] == sensor
    # `twin local` does not know what the remote senses with: its recordings name no sensor.
    open_recorder(tmp_path / "local.mcap", clock=SimClock(), command="local", side="twin").close()
    assert "sensor" not in read_recording(tmp_path / "local.mcap").metadata
    parser = _parser()
    for command in (["demo"], ["remote", str(SMALL)], ["replay", "x.mcap"]):
        sensor = next(a for a in parser._subparsers._group_actions[0].choices[command[0]]._actions  # type: ignore[union-attr]
                      if a.dest == "sensor")
        assert tuple(sensor.choices) == SENSORS, command
    assert parser.parse_args(["replay", "x.mcap"]).sensor is None  # the recording's, by default


@pytest.mark.slow
def test_a_demo_recorded_with_cameras_replays_with_cameras(cache, tmp_path, capsys):
    """The real thing: both sides of a loopback demo with the camera sensor, recorded, then replayed."""
    (tmp_path / "onecan.toml").write_text(ONE_CAN)
    record = tmp_path / "demo.mcap"
    assert main(["demo", "--scene", str(tmp_path / "onecan.toml"), "--sensor", "cameras", "--duration", "0.5",
                 "--record", str(record), "--json"]) == 0
    capsys.readouterr()
    for path in (record, tmp_path / "demo.remote.mcap"):
        assert read_recording(path).metadata["sensor"] == "cameras", path
        assert main(["replay", str(path), "--duration", "0.3", "--json", "--cache-dir", str(cache)]) == 0
        summary = json.loads(capsys.readouterr().out)
        assert summary["sensor"] == "cameras" and summary["objects"] == ["can"], summary


@pytest.mark.slow
def test_an_experiment_on_a_camera_recording_runs_with_the_cameras(cache, tmp_path, monkeypatch, capsys):
    """`twin experiment` ran every session with the surface sensor, whatever the recording named."""
    import csv

    from scenes.sensing import CameraSensor

    monkeypatch.setenv("TWIN_CACHE_DIR", str(cache))
    (tmp_path / "onecan.toml").write_text(ONE_CAN)
    scene = load_scene(tmp_path / "onecan.toml")
    path = tmp_path / "cameras.mcap"
    with Headless(scene, cache_dir=cache, record=path, sensor=CameraSensor.for_scene(scene)) as session:
        session.run(0.05)
    twin_rms = {}
    for name, extra in (("recorded", []), ("surface", ["--sensor", "surface"])):
        out = tmp_path / name
        assert main(["experiment", str(path), "--tasks", "push", "--delays", "0", "--workers", "0",
                     "--out", str(out), *extra]) == 0
        sensor = "surface" if extra else "cameras"
        assert f"({sensor} sensor)" in capsys.readouterr().out
        assert f"the remote's {sensor} sensor" in (out / "report.md").read_text()
        with (out / "results.csv").open() as f:
            twin_rms[name] = next(float(r["force_rms_n"]) for r in csv.DictReader(f) if r["mode"] == "twin")
    # The twin built from the cameras' cloud is not the one built from the true surface: its push feels different.
    assert twin_rms["recorded"] != pytest.approx(twin_rms["surface"], rel=1e-3), twin_rms


def test_a_flood_of_new_keys_is_counted_not_recorded_and_the_recording_is_whole(tmp_path, monkeypatch, caplog):
    """`twin local --record` under 100,000 garbage messages, each on a key of its own: one MCAP channel a key, past
    the format's 16-bit channel ids a struct.error at every message (34,000 tracebacks), then close() raised it and
    the recording was lost (probe of session 39). Recorded as is, with MAX_CHANNELS made small."""
    import sync.recording

    monkeypatch.setattr(sync.recording, "MAX_CHANNELS", 40)
    path = tmp_path / "flood.mcap"
    with caplog.at_level(logging.WARNING, logger="sync.recording"), \
            Recorder(path, clock=SimClock(), metadata={"scene_name": "x", "scene_toml": ""}) as r:
        for i in range(200):
            r.wire("twin", "received", f"twin/x/objects/g{i}/pose", b"\x01")
        r.wire("twin", "received", "twin/x/objects/" + "a" * 2000 + "/pose", b"\x01")  # a key too long to keep
        r.wire("twin", "received", "twin/x/objects/g3/pose", b"\x02")  # a topic it has: recorded
    assert r.dropped == 200 - 40 + 1
    assert read_recording(path).end["not_recorded"] == str(r.dropped)  # the file says so too
    wire = read_recording(path).wire()
    assert len(wire) == 41 and {w.key for w in wire} == {f"twin/x/objects/g{i}/pose" for i in range(40)}
    said = [m.getMessage() for m in caplog.records]
    assert len(said) == 1 and "not recorded" in said[0], said
