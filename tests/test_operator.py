"""Operator input and force feedback over real Zenoh sessions (peer mode, scouting off, free loopback ports):
a device driver publishes targets, the twin's end effector follows, forces come back; bad targets are
dropped and counted."""

from __future__ import annotations

import logging
import queue
import re
import time
from collections import Counter

import numpy as np
import pytest

from sync.keys import Keys
from sync.messages import VERSION, OperatorForce, OperatorTarget, Pose, decode, encode
from sync.recording import FORCE_TOPIC, TARGET_TOPIC, read_recording
from sync.zenoh_transport import ZenohTransport, free_port, make_config, open_session
from twin.runtime import Local, LocalSettings, OperatorSettings

from loopback import SCENE, running_remote, wait_objects

KEYS = Keys(SCENE["name"])


@pytest.fixture
def endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture
def cache(tmp_path_factory):  # type: ignore[no-untyped-def]
    return tmp_path_factory.getbasetemp() / "coacd"


class Driver:
    """A device driver on its own Zenoh session: publishes targets, collects the forces it is sent."""

    def __init__(self, endpoint: str) -> None:
        self.session = open_session(make_config(connect=[endpoint], listen=[]))
        self.forces: queue.SimpleQueue = queue.SimpleQueue()
        self._sub = self.session.declare_subscriber(KEYS.operator_force,
                                                    lambda s: self.forces.put(s.payload.to_bytes()))
        self.seq = 0

    def target(self, position, *, seq: int | None = None, device: str = "haptic0") -> None:  # type: ignore[no-untyped-def]
        self.seq += 1
        msg = OperatorTarget(v=VERSION, stamp_ns=time.time_ns(), device=device, epoch=1,
                             seq=self.seq if seq is None else seq, position=tuple(float(x) for x in position))
        self.session.put(KEYS.operator_target, encode(msg))

    def received(self) -> list[OperatorForce]:
        out = []
        while True:
            try:
                out.append(decode(self.forces.get_nowait()))
            except queue.Empty:
                return out

    def close(self) -> None:
        self._sub.undeclare()
        self.session.close()


def _run_until(local: Local, condition, timeout: float = 20.0) -> None:  # type: ignore[no-untyped-def]
    """Run the twin until ``condition()``; the deadline is a failsafe for a hung side, not a measurement."""
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        local.run(0.05)


@pytest.fixture
def twin(endpoint, cache, tmp_path):  # type: ignore[no-untyped-def]
    with running_remote(endpoint, cache) as remote:
        # The driver connects to the twin's own endpoint: peers with scouting off do not route for others.
        twin_endpoint = f"tcp/127.0.0.1:{free_port()}"
        session = open_session(make_config(connect=[endpoint], listen=[twin_endpoint]))
        recording = tmp_path / "local.mcap"
        from cli.record import open_recorder, recording_transport
        from sync.clock import REAL_CLOCK

        recorder = open_recorder(recording, clock=REAL_CLOCK, command="test", side="twin", scene_name="synctest")
        local = Local(recording_transport(ZenohTransport(session), recorder, "twin"),
                      settings=LocalSettings(cache_dir=cache), recorder=recorder,
                      operator=OperatorSettings(listen=True, force_rate=200.0))
        driver = Driver(twin_endpoint)
        try:
            wait_objects(local, 2)
            yield local, driver, remote.remote, recorder
        finally:
            driver.close()
            local.close()
            recorder.close()  # type: ignore[union-attr]
            session.close()


def test_the_end_effector_follows_a_device_and_forces_come_back(twin):
    local, driver, remote, recorder = twin
    free = np.array([-0.25, -0.1, 0.6])
    driver.target(free)
    _run_until(local, lambda: local.device_target is not None)
    local.run(0.3)
    assert np.allclose(local.twin.data.mocap_pos[0], free)
    # Passed on to the remote as commands: its own loop applies them when they arrive (waited for, not timed).
    _run_until(local, lambda: np.allclose(remote.twin.data.mocap_pos[0], free))
    driver.received()  # forget the free-space forces so far
    # Into the crate (centre 0.53 m high at the table's middle, its face at x = -0.06) as a hand would push, at
    # 0.1 m/s from in front of it: contact, and a force pushing back in -x. (A jump there, which this test made
    # before the end effector's speed limit, hit the crate at 2 m/s now and knocked it out of reach.)
    sent = 1
    for x in np.linspace(-0.12, -0.05, 71):
        driver.target([x, 0.0, 0.53])
        sent += 1
        local.run(0.01)
    _run_until(local, lambda: np.allclose(local.twin.data.mocap_pos[0], [-0.05, 0.0, 0.53]))
    local.run(0.3)
    forces = driver.received()
    assert len(forces) > 20 and all(isinstance(f, OperatorForce) for f in forces)
    assert all(np.isfinite(f.force).all() for f in forces)
    assert max(np.linalg.norm(f.force) for f in forces) > 0.1
    seqs = [f.seq for f in forces]
    assert seqs == sorted(seqs)
    # Published at 200 Hz of twin time, not at the 1 kHz loop rate.
    times = np.array([f.sim_time for f in forces])
    assert np.median(np.diff(times)) == pytest.approx(0.005, abs=1.5e-3)
    assert local.report.operator_targets == sent and not local.report.operator_dropped
    recorder.close(twin_time_s=local.twin.time)
    rec = read_recording(recorder.path)
    assert rec.counts[TARGET_TOPIC] > 500 and rec.counts[FORCE_TOPIC] > 5
    assert any(w.key == KEYS.operator_target and w.direction == "received" for w in rec.wire())
    assert any(w.key == KEYS.operator_force and w.direction == "sent" for w in rec.wire())


def test_bad_targets_are_dropped_and_counted(twin):
    local, driver, _, _ = twin
    good = np.array([-0.2, 0.1, 0.6])
    driver.target(good, seq=100)
    _run_until(local, lambda: local.device_target is not None)
    raw = driver.session
    nan = OperatorTarget(v=VERSION, stamp_ns=0, device="haptic0", epoch=1, seq=101, position=(float("nan"), 0.0, 0.6))
    bad_id = OperatorTarget(v=VERSION, stamp_ns=0, device="no spaces", epoch=1, seq=102, position=(0.0, 0.0, 0.6))
    pose = Pose(v=VERSION, stamp_ns=0, object_id="crate", epoch=1, seq=1, sim_time=0.0, position=(0.0, 0.0, 0.6),
                quat=(1.0, 0.0, 0.0, 0.0), linvel=(0.0,) * 3, angvel=(0.0,) * 3)
    for data in [b"garbage", encode(nan), encode(bad_id), encode(pose)]:
        raw.put(KEYS.operator_target, data)
    driver.target([50.0, 0.0, 0.6], seq=103)  # far outside the table's workspace
    driver.target([0.0, 0.0, 0.6], seq=99)  # older than the good one
    driver.target([0.1, 0.1, 3000.0], seq=104)  # beyond 1 km: refused at decoding
    counters = local.link.counters
    _run_until(local, lambda: counters.dropped_malformed + sum(local.report.operator_dropped.values()) >= 7)
    assert counters.dropped_by_reason == {"undecodable": 1, "non-finite": 1, "bad-id": 1, "out-of-range": 1,
                                          "wrong-key": 1}  # the pose: not what the target key carries
    assert local.report.operator_dropped == {"out-of-workspace": 1, "out-of-order": 1}
    local.run(0.1)
    assert np.allclose(local.device_target, good) and np.allclose(local.twin.data.mocap_pos[0], good)


def test_twin_local_records_a_scripted_session(endpoint, cache, tmp_path, capsys):
    import json

    from cli.main import main

    script = tmp_path / "push.csv"
    script.write_text("t,x,y,z\n0,-0.3,0.0,0.56\n2,-0.1,0.0,0.53\n")
    path = tmp_path / "live.mcap"
    with running_remote(endpoint, cache):
        code = main(["local", "--connect", endpoint, "--duration", "2", "--script", str(script), "--record",
                     str(path), "--force-rate", "100", "--json"])
    assert code == 0
    record = json.loads(capsys.readouterr().out)
    assert record["forces_sent"] > 100  # (objects may still be estimating in a worker: not asked here)
    # The twin's drop and error counters, all of them (only dropped_malformed was printed: an out-of-scene pose
    # read as no drop at all).
    assert {k: record[k] for k in ("dropped_malformed", "dropped_by_reason", "out_of_scene", "estimation_errors",
                                   "failed_edits", "evicted", "resyncs")} == {
        "dropped_malformed": 0, "dropped_by_reason": {}, "out_of_scene": 0, "estimation_errors": 0, "failed_edits": 0,
        "evicted": {}, "resyncs": 0}
    assert record["out_of_order"] >= 0
    # Every object the remote published is either touchable or named as pending.
    assert sorted(record["objects"] + record["objects_pending"]) == ["can", "crate"]
    rec = read_recording(path)
    assert rec.damage is None and rec.metadata["clock"] == "real" and rec.metadata["command"] == "local"
    times, targets = rec.targets()
    assert len(times) > 1000 and np.allclose(targets[0], [-0.3, 0.0, 0.56], atol=1e-3)
    kinds = Counter((w.direction, w.key.rsplit("/", 1)[-1]) for w in rec.wire())
    assert kinds["received", "cloud"] == 2 and kinds["sent", "command"] > 10 and kinds["sent", "force"] > 100
    for topic in rec.counts:
        stamps = [r.log_time for r in rec.topic(topic)]
        assert stamps == sorted(stamps), topic
    # --replay-operator refuses a missing recording before it opens a session.
    assert main(["local", "--connect", endpoint, "--duration", "0.1", "--replay-operator", str(tmp_path / "no.mcap")]) == 2
    assert "no such recording" in capsys.readouterr().err


def test_twin_local_shows_objects_in_flight_on_stderr(endpoint, cache, capsys):
    from cli.main import main

    with running_remote(endpoint, cache):
        assert main(["local", "--connect", endpoint, "--duration", "6"]) == 0
    err = capsys.readouterr().err
    for object_id in ("can", "crate"):  # both clouds arrive as the twin joins
        assert f"twin: {object_id}: cloud received, estimating" in err, err
    touchable = [line for line in err.splitlines() if ": touchable after " in line]
    assert touchable, err  # two small objects, two workers, six seconds: at least one is in the twin
    for line in touchable:
        assert re.match(r"twin: (can|crate): touchable after \d+\.\d s \(\d in the twin, \d in flight\)$", line)


def test_twin_local_refuses_a_script_beyond_the_remote_table_and_reads_units(endpoint, cache, tmp_path, capsys):
    from cli.main import main

    script = tmp_path / "mm.csv"
    script.write_text("t,x,y,z\n0,-300,0,560\n2,-100,0,530\n")  # millimetres: the end effector went to 560 m
    with running_remote(endpoint, cache):
        assert main(["local", "--connect", endpoint, "--duration", "0.5", "--script", str(script)]) == 2
        err = capsys.readouterr().err
        line = [x for x in err.splitlines() if "error" in x]
        assert len(line) == 1 and line[0].endswith("is outside the operator's reach (x -2.5 to 2.5, y -2.3 to 2.3, "
                                                   "z 0 to 2.5 m): looks like millimetres: pass --units mm"), err
        assert main(["local", "--connect", endpoint, "--duration", "0.5", "--script", str(script), "--units", "mm",
                     "--json"]) == 0


def _targets_recording(path, targets):  # type: ignore[no-untyped-def]
    """A recording holding only operator targets ``[(twin time s, (x, y, z) m), ...]``: what --replay-operator reads."""
    from sync.clock import SimClock
    from sync.recording import Recorder

    with Recorder(path, clock=SimClock()) as r:
        for t, position in targets:
            r.target(t, np.array(position, dtype=float))
    return path


def test_twin_local_replays_a_recorded_operator_read_once_and_refuses_one_beyond_the_table(endpoint, cache, tmp_path,
                                                                                           capsys, monkeypatch, caplog):
    """--replay-operator read the recording twice (the trajectory, then its reach); one read, one decode now."""
    import sync.recording
    from cli.main import main

    far = _targets_recording(tmp_path / "far.mcap", [(0.0, (-0.3, 0.0, 0.56)), (0.02, (999.0, -999.0, 999.0))])
    near = _targets_recording(tmp_path / "near.mcap", [(0.0, (-0.3, 0.0, 0.56)), (0.5, (-0.2, 0.0, 0.55))])
    reads, decodes = Counter(), Counter()
    read, targets = sync.recording.read_recording, sync.recording.Recording.targets

    def counted_read(path):  # type: ignore[no-untyped-def]
        reads[str(path)] += 1
        return read(path)

    def counted_targets(self):  # type: ignore[no-untyped-def]
        decodes[str(self.path)] += 1
        return targets(self)

    monkeypatch.setattr(sync.recording, "read_recording", counted_read)
    monkeypatch.setattr(sync.recording.Recording, "targets", counted_targets)
    with running_remote(endpoint, cache):
        assert main(["local", "--connect", endpoint, "--duration", "0.5", "--replay-operator", str(far)]) == 2
        err = capsys.readouterr().err
        line = [x for x in err.splitlines() if "error" in x]
        assert len(line) == 1 and line[0].endswith(f"{far}: the target at t = 0.02 s, (999, -999, 999) m, is outside "
                                                   "the operator's reach (x -2.5 to 2.5, y -2.3 to 2.3, z 0 to 2.5 m)"), err
        assert main(["local", "--connect", endpoint, "--duration", "0.5", "--replay-operator", str(near), "--json"]) == 0
        capsys.readouterr()
        # A torn recording drives the twin with what is intact, and says so (it said nothing).
        many = _targets_recording(tmp_path / "many.mcap", [(k / 400, (-0.3 + k / 4000, 0.0, 0.56)) for k in range(200)])
        torn = tmp_path / "torn.mcap"
        torn.write_bytes(many.read_bytes()[: many.stat().st_size * 2 // 3])
        assert main(["local", "--connect", endpoint, "--duration", "0.3", "--replay-operator", str(torn), "--json"]) == 0
        assert any(f"{torn}: the recording is damaged after" in r.getMessage() and r.levelno == logging.WARNING
                   for r in caplog.records), caplog.records
    assert reads == {str(far): 1, str(near): 1, str(torn): 1} and decodes == {str(far): 1, str(near): 1, str(torn): 1}
