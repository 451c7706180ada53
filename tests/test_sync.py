"""Synchronisation over real Zenoh sessions: peer mode, scouting off, tcp/127.0.0.1 on free ports."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from msgspec.structs import replace

from sync.keys import Keys
from sync.messages import VERSION, Heartbeat, encode
from sync.zenoh_transport import SessionError, free_port, make_config

from loopback import SCENE, RemoteRunner, close_local, open_local, running_remote, wait_objects, wait_until


@pytest.fixture
def endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture
def remote(endpoint, tmp_path_factory):
    with running_remote(endpoint, tmp_path_factory.getbasetemp() / "coacd") as runner:
        yield runner


def _local(endpoint, tmp_path_factory, **settings):  # type: ignore[no-untyped-def]
    return open_local(endpoint, tmp_path_factory.getbasetemp() / "coacd", **settings)


def test_late_joiner_gets_the_whole_scene_and_follows_poses(remote, endpoint, tmp_path_factory):
    # The remote has published its info and clouds and run on (more messages, simulated time) before the
    # twin exists, so the twin must catch up through the queryable, not the live puts.
    r = remote.remote
    sent_at_start = len(SCENE["objects"]) + 1  # info + one cloud per object, published by the constructor
    wait_until(lambda: r.twin.time >= 0.2 and r.link.counters.messages_sent > sent_at_start, what="the remote")
    local = _local(endpoint, tmp_path_factory)
    try:
        wait_objects(local, 2)
        assert local.report.objects_synced == 2
        # The remote moves the crate; the twin follows through deadband pose updates.
        pos, quat = r.twin.pose("crate")
        r.move("crate", pos + np.array([0.1, 0.05, 0.0]), quat)
        local.run(1.0)
        twin_pos, _ = local.twin.pose("crate")
        true_pos, _ = r.twin.pose("crate")
        assert np.linalg.norm(twin_pos - true_pos) < 0.005
        assert local.report.pose_updates > 0
        assert local.link.counters.dropped_malformed == 0
    finally:
        close_local(local)


def test_malformed_messages_are_dropped_counted_and_survived(remote, endpoint, tmp_path_factory):
    local = _local(endpoint, tmp_path_factory)
    try:
        wait_objects(local, 2)
        keys = Keys(SCENE["name"])
        beat = Heartbeat(v=VERSION, stamp_ns=0, epoch=0, seq=1, sim_time=0.0, objects=0)
        bad = [b"garbage", encode(beat)[:-1], encode(replace(beat, v=99)),
               encode(replace(beat, sim_time=float("nan")))]
        raw = remote.remote.link.transport.session
        for data in bad:
            raw.put(keys.object("crate", "pose"), data)
        raw.put(keys.heartbeat, b"\x93\x01")
        local.run(0.5)
        assert local.link.counters.dropped_malformed == len(bad) + 1
        assert sorted(local.objects) == ["can", "crate"]  # and the twin runs on
    finally:
        close_local(local)


def test_a_dead_estimation_worker_is_replaced_and_its_clouds_estimated_again(remote, endpoint, tmp_path_factory):
    # The remote sends each cloud once: a worker killed while estimating (out of memory, a native crash)
    # must not leave the object out of the twin.
    local = _local(endpoint, tmp_path_factory, workers=1)
    try:
        def estimating() -> bool:
            pool = local._pool
            return bool(local._jobs) and pool is not None and bool(pool._processes)

        local.run(30.0, until=estimating)
        assert estimating(), "no estimation job reached a worker"
        for process in list(local._pool._processes.values()):  # type: ignore[union-attr]
            process.kill()
        wait_objects(local, 2)
        assert local.report.worker_retries >= 1
        assert local.report.estimation_errors == 0
    finally:
        close_local(local)


def test_remote_silence_marks_stale_then_recovers(remote, endpoint, tmp_path_factory):
    local = _local(endpoint, tmp_path_factory, stale_after=0.3)
    try:
        wait_objects(local, 2)
        local.run(0.2)
        assert not local.stale
        remote.stop()
        t0 = local.twin.time
        local.run(0.8)
        assert local.stale and local.report.stale_events == 1
        assert local.twin.time > t0 + 0.7  # the twin kept stepping
        remote.start()
        local.run(0.5)
        assert not local.stale and local.report.recoveries == 1
    finally:
        close_local(local)


def test_two_twins_on_one_remote_and_operator_commands(remote, endpoint, tmp_path_factory):
    a, b = _local(endpoint, tmp_path_factory), _local(endpoint, tmp_path_factory)
    try:
        wait_objects(a, 2)
        wait_objects(b, 2)
        target = np.array([-0.25, -0.1, 0.6])
        a.run(0.5, trajectory=lambda t: target)
        ee = remote.remote.twin.data.mocap_pos[0]
        assert np.allclose(ee, target)  # the remote's end effector obeys the operator of twin a
        for local in (a, b):
            for oid in ("crate", "can"):
                assert np.linalg.norm(local.twin.pose(oid)[0] - remote.remote.twin.pose(oid)[0]) < 0.01
    finally:
        close_local(a)
        close_local(b)


def test_a_missing_config_file_is_a_clear_error(tmp_path):
    with pytest.raises(SessionError, match="no such file"):
        make_config(config_file=tmp_path / "nope.json5")


def test_the_remote_settles_its_scene_before_sensing_it(endpoint, tmp_path_factory):
    from scenes.remote import SETTLED_SPEED, Remote
    from scenes.scenefile import parse_scene
    from sync.zenoh_transport import ZenohTransport, open_session

    falling = {**SCENE, "objects": [{**SCENE["objects"][0], "position": [0.0, 0.0, 0.7]}]}  # 17 cm above the table
    session = open_session(make_config(listen=[endpoint]))
    try:
        r = Remote(parse_scene(falling), ZenohTransport(session), cache_dir=tmp_path_factory.getbasetemp() / "coacd")
        try:
            assert 0.1 < r.settled_after < 3.0
            assert np.abs(r.twin.data.qvel).max() < SETTLED_SPEED
            z = r.twin.pose("crate")[0][2]
            assert z == pytest.approx(0.5 + 0.03, abs=0.002)  # the crate's centre, resting on the table
        finally:
            r.close()
    finally:
        session.close()


def _certificates(folder):  # type: ignore[no-untyped-def]
    """A CA and a server certificate for localhost / 127.0.0.1 it signed, made with the openssl CLI."""
    import subprocess

    def run(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=folder, check=True, capture_output=True)

    run("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2", "-subj", "/CN=tactile-twin test CA",
        "-keyout", "ca.key", "-out", "ca.pem")
    run("req", "-newkey", "rsa:2048", "-nodes", "-subj", "/CN=localhost", "-keyout", "server.key", "-out", "server.csr")
    (folder / "san.ext").write_text("subjectAltName=DNS:localhost,IP:127.0.0.1\n")
    run("x509", "-req", "-in", "server.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial", "-days", "2",
        "-extfile", "san.ext", "-out", "server.pem")
    return folder / "ca.pem", folder / "server.key", folder / "server.pem"


def _tls_config(path, tls: dict) -> None:  # type: ignore[no-untyped-def]
    import json

    path.write_text(json.dumps({"mode": "peer", "scouting": {"multicast": {"enabled": False}},
                                "transport": {"link": {"tls": tls}}}))


def test_tls_on_loopback_with_generated_certificates(tmp_path, tmp_path_factory):
    import shutil

    from scenes.remote import Remote
    from scenes.scenefile import parse_scene
    from sync.zenoh_transport import ZenohTransport, open_session
    from twin.runtime import Local, LocalSettings, SyncError

    if shutil.which("openssl") is None:
        pytest.fail("the openssl CLI is needed to make the test certificates")
    ca, key, cert = _certificates(tmp_path)
    _tls_config(tmp_path / "remote.json5", {"listen_private_key": str(key), "listen_certificate": str(cert)})
    _tls_config(tmp_path / "twin.json5", {"root_ca_certificate": str(ca)})
    other_ca, _, _ = _certificates(tmp_path_factory.mktemp("other"))
    _tls_config(tmp_path / "stranger.json5", {"root_ca_certificate": str(other_ca)})
    endpoint = f"tls/localhost:{free_port()}"
    cache = tmp_path_factory.getbasetemp() / "coacd"
    server = open_session(make_config(listen=[endpoint], config_file=tmp_path / "remote.json5"))
    try:
        remote = Remote(parse_scene(SCENE), ZenohTransport(server), cache_dir=cache)
        # A twin trusting another CA cannot complete the handshake, so no scene ever answers it.
        stranger = open_session(make_config(connect=[endpoint], config_file=tmp_path / "stranger.json5"))
        try:
            with pytest.raises(SyncError, match="no remote scene answered"):
                Local(ZenohTransport(stranger), wait=2.0)
        finally:
            stranger.close()
        client = open_session(make_config(connect=[endpoint], config_file=tmp_path / "twin.json5"))
        local = Local(ZenohTransport(client), settings=LocalSettings(cache_dir=cache))
        try:
            wait_objects(local, 2)
            assert local.link.counters.bytes_received > 0
        finally:
            local.close()
            client.close()
        remote.close()
    finally:
        server.close()


def test_access_control_in_the_remote_config_refuses_operator_commands(tmp_path, tmp_path_factory):
    """An ACL in the remote's --zenoh-config: this twin may watch the scene but not drive the end effector."""
    import json

    from scenes.remote import Remote
    from scenes.scenefile import parse_scene
    from sync.zenoh_transport import ZenohTransport, open_session

    acl = {"enabled": True, "default_permission": "allow",
           "rules": [{"id": "no-operator", "permission": "deny", "flows": ["ingress"], "messages": ["put"],
                      "key_exprs": ["twin/*/operator/**"]}],
           "subjects": [{"id": "loopback", "interfaces": ["lo"]}],
           "policies": [{"rules": ["no-operator"], "subjects": ["loopback"]}]}
    (tmp_path / "remote.json5").write_text(json.dumps({"mode": "peer", "scouting": {"multicast": {"enabled": False}},
                                                       "access_control": acl}))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cache = tmp_path_factory.getbasetemp() / "coacd"
    server = open_session(make_config(listen=[endpoint], config_file=tmp_path / "remote.json5"))
    try:
        runner = RemoteRunner(Remote(parse_scene(SCENE), ZenohTransport(server), cache_dir=cache))
        runner.start()
        local = open_local(endpoint, cache)
        try:
            wait_objects(local, 2)  # clouds, poses and queries still flow
            start = runner.remote.twin.data.mocap_pos[0].copy()
            target = start + np.array([0.05, -0.1, 0.04])
            local.run(0.5, trajectory=lambda t: target)
            assert local.link.counters.messages_sent > 0  # the twin did publish its commands
            assert np.allclose(runner.remote.twin.data.mocap_pos[0], start)  # and the remote never saw them
        finally:
            close_local(local)
            runner.stop()
            runner.remote.close()
    finally:
        server.close()


def test_objects_appearing_and_vanishing_remotely_follow_in_the_twin(remote, endpoint, tmp_path_factory):
    from scenes.scenefile import ObjectSpec

    local = _local(endpoint, tmp_path_factory)
    try:
        wait_objects(local, 2)
        r = remote.remote
        added = r.add(ObjectSpec(id="ball", source="primitive", value={"type": "sphere", "size": [0.03]},
                                 material="rubber", position=(-0.2, -0.15), points=6000))
        assert added.result(timeout=60) == "ball"  # the remote published it
        wait_objects(local, 3)
        twin_mass = local.twin.model.body("ball").mass[0]
        truth_mass = r.twin.model.body("ball").mass[0]
        assert twin_mass == pytest.approx(truth_mass, rel=0.02)
        assert np.linalg.norm(local.twin.pose("ball")[0] - r.twin.pose("ball")[0]) < 0.005
        r.remove("crate")
        local.run(2.0, until=lambda: not local.twin.has("crate") and not local.adding)
        assert not local.twin.has("crate")
        assert sorted(local.objects) == ["ball", "can"]
    finally:
        close_local(local)


def test_a_killed_estimation_worker_is_replaced_and_the_twin_runs_on(remote, endpoint, tmp_path_factory):
    from scenes.scenefile import ObjectSpec

    local = _local(endpoint, tmp_path_factory)
    try:
        wait_objects(local, 2)
        for proc in list(local._pool._processes.values()):  # out of memory, or killed by hand
            proc.kill()
            proc.join(timeout=10)
        r = remote.remote
        r.add(ObjectSpec(id="ball", source="primitive", value={"type": "sphere", "size": [0.03]},
                         material="rubber", position=(-0.2, -0.15), points=6000)).result(timeout=60)
        wait_objects(local, 3)
        assert sorted(local.objects) == ["ball", "can", "crate"]
    finally:
        close_local(local)


def test_a_query_for_some_keys_gets_those_of_them_the_remote_has_and_logs_nothing(remote, endpoint, caplog):
    from sync.zenoh_transport import open_session

    keys = Keys(SCENE["name"])
    asker = open_session(make_config(connect=[endpoint]))
    try:
        wait_until(lambda: len(list(asker.info.peers_zid())) == 1, what="the link to the remote")
        with caplog.at_level(logging.ERROR, logger="sync.zenoh_transport"):
            for selector, expected in [(f"{keys.root}/objects/*/pose", [keys.object(i, "pose") for i in ("can", "crate")]),
                                       (f"{keys.root}/objects/crate/*", [keys.object("crate", k) for k in ("cloud", "pose")])]:
                # Zenoh refuses a reply on a key the query does not match: the remote used to send one (every
                # current cloud and pose), which ended its answer there with a traceback in its log.
                got = sorted(str(r.ok.key_expr) for r in asker.get(selector, timeout=5.0) if r.ok is not None)
                assert got == expected, selector
        assert not caplog.records
    finally:
        asker.close()


def test_the_scene_can_be_moved_from_another_thread_while_the_remote_steps(remote):
    # MuJoCo releases the GIL inside mj_step: a set_pose from this thread used to run mj_forward on the
    # remote's mjData during a step of its loop thread, and crashed the process within seconds.
    r = remote.remote
    start, quat = r.twin.pose("crate")
    lift = np.array([0.0, 0.0, 0.05])
    wait_until(lambda: r.twin.time > 0.05, what="the remote to step")  # its loop thread is running
    # A fixed number of moves, queued as fast as this thread can while the loop thread steps; in the crash
    # this guards against, mj_forward from here ran during mj_step there and the process died in seconds.
    for moves in range(3000):
        r.move("crate", start + lift * (moves % 2), quat)
    aside = start + np.array([0.05, 0.0, 0.0])  # on the table, at rest: a pose that stays once applied
    r.move("crate", aside, quat)  # the last one wins
    wait_until(lambda: abs(r.twin.pose("crate")[0][0] - aside[0]) < 1e-3, what="the last move")
    t_applied = r.twin.time
    wait_until(lambda: r.twin.time > t_applied + 0.05, what="the remote to step on")  # it survived
    remote.stop()
    try:
        # 50 ms after the last move it still sits where it was put: no move after it was applied.
        np.testing.assert_allclose(r.twin.pose("crate")[0], aside, atol=0.005)
    finally:
        remote.start()


@pytest.mark.slow
def test_a_twin_object_straying_on_its_own_is_held_at_the_remote_pose(tmp_path):
    from twin.hold import HoldSettings

    endpoint, cache = f"tcp/127.0.0.1:{free_port()}", tmp_path / "coacd"
    gaps = {}
    with running_remote(endpoint, cache, keyframe_s=0.0):  # no keyframes: only the hold can pull it back
        for enabled in (False, True):
            local = open_local(endpoint, cache, hold=HoldSettings(enabled=enabled))
            try:
                wait_objects(local, 2)
                local.run(0.5)
                local.twin.set_velocity("crate", np.array([0.6, 0.0, 0.0]), np.array([0.0, 0.0, 3.0]))  # C's is still
                local.run(1.0)
                remote_pos, _ = local.remote_pose("crate")
                gaps[enabled] = float(np.linalg.norm(local.twin.pose("crate")[0] - remote_pos)), local.report.holds
            finally:
                close_local(local)
    assert gaps[False][0] > 0.02 and gaps[False][1] == 0  # it slid away, and nothing brings it back
    assert gaps[True][0] < 0.002 and gaps[True][1] >= 1


@pytest.mark.parametrize(("endpoint", "exposed"), [
    ("tcp/127.0.0.1:7447", False), ("tcp/localhost:7447", False), ("tcp/[::1]:7447", False),
    ("tcp/0.0.0.0:7447", True), ("tcp/[::]:7447", True), ("tcp/192.0.2.7:7447", True), ("udp/0.0.0.0:7447", True),
    ("tls/0.0.0.0:7447", False), ("quic/[::]:7447", False),
    # A Unix socket or pipe is a file on this machine (it was refused as reachable "in plain text"); a serial
    # line is not.
    ("unixsock-stream//tmp/zenoh.sock", False), ("unixpipe/zenoh-pipe", False), ("serial//dev/ttyUSB0", True),
])
def test_plain_listeners_beyond_loopback_are_named(endpoint, exposed):
    from sync.zenoh_transport import exposed_without_tls

    assert bool(exposed_without_tls([endpoint])) is exposed


def test_listening_beyond_loopback_in_plain_text_needs_insecure(capsys):
    from cli.main import main

    scene = str(Path(__file__).parent / "data" / "small.toml")
    assert main(["remote", scene, "--listen", "tcp/0.0.0.0:0", "--duration", "0.1"]) == 2
    assert "--insecure" in capsys.readouterr().err


@pytest.mark.parametrize("sensor", ["surface", "cameras"])
def test_twin_remote_runs_for_its_duration_and_reports(sensor, capsys):
    from cli.main import main

    scene = str(Path(__file__).parent / "data" / "small.toml")
    # Long enough for the cameras' background scan to start: closing waits for it.
    assert main(["remote", scene, "--listen", f"tcp/127.0.0.1:{free_port()}", "--duration", "0.7",
                 "--sensor", sensor]) == 0
    assert "pose updates" in capsys.readouterr().out


def test_make_config_takes_lists_of_endpoints_not_a_string():
    """A string was read as its characters ("'t': not a Zenoh endpoint"); [None] was an AttributeError."""
    from sync.zenoh_transport import SessionError, make_config

    for bad in ("tcp/127.0.0.1:7447", [None], [7447]):
        with pytest.raises(SessionError, match="expected a list of endpoint strings"):
            make_config(listen=bad)  # type: ignore[arg-type]
        with pytest.raises(SessionError, match="expected a list of endpoint strings"):
            make_config(connect=bad)  # type: ignore[arg-type]
