"""Who may say what: the shipped mutual-TLS + access-control configs (``configs/``), and a flood.

Real Zenoh sessions in peer mode with scouting off, on free loopback ports. The certificates are made here
with the openssl CLI (a CA, the remote's and the twin's certificates, and a stranger's from another CA),
and the shipped configs are copied with their ``configs/certs/`` paths pointed at them.

Negative results ("X never arrived") are not waited out with a sleep: the sender follows its forgeries
with an allowed message on the same link, and Zenoh delivers one link's messages of one priority in
order, so once the allowed one is in, a forgery that was let through would be in too.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from sync.keys import Keys
from sync.messages import VERSION, Gone, OperatorCommand, Pose, SceneInfo, cloud_message, encode
from sync.zenoh_transport import free_port, make_config, open_session

from loopback import SCENE, RemoteRunner, running_remote, wait_objects, wait_until

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
KEYS = Keys(SCENE["name"])
REMOTE_CN = "tactile-twin-remote"  # the names the configs' access_control subjects match
TWIN_CN = "tactile-twin-twin"
#: Every certificate path in the shipped configs starts with this (relative to the working folder).
CERT_PREFIX = "configs/certs/"
SMALL_SCENE = str(Path(__file__).parent / "data" / "small.toml")


# -- certificates and configs -----------------------------------------------------------------------

def _openssl(folder: Path, *args: str) -> None:
    subprocess.run(["openssl", *args], cwd=folder, check=True, capture_output=True)


def _ca(folder: Path, name: str, cn: str) -> None:
    _openssl(folder, "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2", "-subj", f"/CN={cn}",
             "-keyout", f"{name}.key", "-out", f"{name}.pem")


def _leaf(folder: Path, name: str, cn: str, ca: str) -> None:
    """``name.key``/``name.pem``: CN ``cn``, for localhost and 127.0.0.1, signed by ``ca``."""
    _openssl(folder, "req", "-newkey", "rsa:2048", "-nodes", "-subj", f"/CN={cn}", "-keyout", f"{name}.key",
             "-out", f"{name}.csr")
    (folder / f"{name}.ext").write_text("subjectAltName=DNS:localhost,IP:127.0.0.1\n")
    _openssl(folder, "x509", "-req", "-in", f"{name}.csr", "-CA", f"{ca}.pem", "-CAkey", f"{ca}.key",
             "-CAcreateserial", "-days", "2", "-extfile", f"{name}.ext", "-out", f"{name}.pem")


@pytest.fixture(scope="module")
def pki(tmp_path_factory) -> dict[str, Path]:
    """The shipped configs, copied, with their certificates made (as configs/README.md says) and filled in."""
    if shutil.which("openssl") is None:
        pytest.fail("the openssl CLI is needed to make the test certificates")
    root = tmp_path_factory.mktemp("pki")
    certs = root / "certs"
    certs.mkdir()
    _ca(certs, "ca", "tactile-twin CA")
    _leaf(certs, "remote", REMOTE_CN, "ca")
    _leaf(certs, "twin", TWIN_CN, "ca")
    _ca(certs, "other-ca", "somebody else's CA")
    _leaf(certs, "stranger", TWIN_CN, "other-ca")  # the right name, the wrong CA
    out = {"certs": certs}
    for name in ("remote", "twin"):
        text = (CONFIGS / f"{name}.json5").read_text()
        assert text.count(f'"{CERT_PREFIX}') == 5, f"configs/{name}.json5 changed its certificate paths"
        (root / f"{name}.json5").write_text(text.replace(f'"{CERT_PREFIX}', f'"{certs}/'))
        out[name] = root / f"{name}.json5"
    return out


def _session(pki, role: str, *, connect: list[str] | None = None, listen: list[str] | None = None,
             acl: bool = True):  # type: ignore[no-untyped-def]
    conf = make_config(connect=connect, listen=listen, config_file=pki[role])
    if not acl:
        conf.insert_json5("access_control/enabled", "false")
    return open_session(conf)


def _stranger(pki, kind: str, port: int):  # type: ignore[no-untyped-def]
    """A session of someone the configs must keep out, trying the remote's port."""
    conf = make_config(connect=[f"tls/localhost:{port}"])
    ca = str(pki["certs"] / "ca.pem")
    if kind == "no certificate":  # trusts our CA, so only the remote's demand for a certificate stops it
        conf.insert_json5("transport/link/tls", json.dumps({"root_ca_certificate": ca}))
    elif kind == "another CA's certificate":
        conf.insert_json5("transport/link/tls", json.dumps({
            "root_ca_certificate": ca, "enable_mtls": True,
            "connect_certificate": str(pki["certs"] / "stranger.pem"),
            "connect_private_key": str(pki["certs"] / "stranger.key")}))
    else:  # plain TCP to the TLS port
        conf = make_config(connect=[f"tcp/localhost:{port}"])
    return open_session(conf)


class Inbox:
    """Every sample a raw subscriber sees: (key, payload bytes), appended from Zenoh's thread."""

    def __init__(self, session, keyexpr: str = "twin/**") -> None:  # type: ignore[no-untyped-def]
        self.samples: list[tuple[str, bytes]] = []
        self._sub = session.declare_subscriber(keyexpr, lambda s: self.samples.append(
            (str(s.key_expr), s.payload.to_bytes())))

    def has(self, payload: bytes) -> bool:
        return any(data == payload for _, data in self.samples)

    def close(self) -> None:
        self._sub.undeclare()


def _put_all(session, puts: list[tuple[str, bytes]]) -> None:  # type: ignore[no-untyped-def]
    import zenoh

    for key, data in puts:  # BLOCK: under load, a dropped forgery would prove nothing
        session.put(key, data, congestion_control=zenoh.CongestionControl.BLOCK)


def _forgeries(epoch: int, can_position: np.ndarray) -> list[tuple[str, bytes]]:
    """Add a phantom object, remove the crate, move the can 0.2 m: all newer than anything the remote sent."""
    epoch, seq, stamp = epoch + 1, 10**6, time.time_ns()
    box = np.random.default_rng(3).uniform(-0.04, 0.04, (2000, 3)) + np.array([0.0, -0.2, 0.56])
    cloud = cloud_message("phantom", box, stamp_ns=stamp, epoch=epoch, seq=seq, material="wood_pine", density=None,
                          frame_position=np.array([0.0, -0.2, 0.56]), frame_quat=np.array([1.0, 0.0, 0.0, 0.0]))
    moved = tuple(float(x) for x in can_position + np.array([0.2, 0.0, 0.0]))
    pose = Pose(v=VERSION, stamp_ns=stamp, object_id="can", epoch=epoch, seq=seq + 1, sim_time=0.0, position=moved,
                quat=(1.0, 0.0, 0.0, 0.0), linvel=(0.0, 0.0, 0.0), angvel=(0.0, 0.0, 0.0))
    return [(KEYS.object("phantom", "cloud"), encode(cloud)),
            (KEYS.object("crate", "gone"), encode(Gone(v=VERSION, stamp_ns=stamp, object_id="crate", epoch=epoch,
                                                       seq=seq + 2))),
            (KEYS.object("can", "pose"), encode(pose))]


def _command(position, epoch: int = 7) -> bytes:  # type: ignore[no-untyped-def]
    return encode(OperatorCommand(v=VERSION, stamp_ns=time.time_ns(), epoch=epoch, seq=1,
                                  position=tuple(float(x) for x in position)))


# -- the shipped configs ------------------------------------------------------------------------------

def test_the_shipped_configs_parse_and_name_only_documented_certificate_files():
    import re

    readme = (CONFIGS / "README.md").read_text()
    for name in ("remote", "twin"):
        path = CONFIGS / f"{name}.json5"
        make_config(config_file=path)  # Zenoh's own parser and schema accept it as shipped
        text = path.read_text()
        files = set(re.findall(r'"configs/certs/([^"]+)"', text))
        assert files == {"ca.pem", f"{name}.key", f"{name}.pem"}
        for f in files:
            assert f"certs/{f}" in readme, f"configs/README.md does not say how to make {f}"
        assert "enable_mtls: true" in text and 'default_permission: "deny"' in text


# -- who gets in, and what they may say ----------------------------------------------------------------

def test_without_the_access_control_a_certified_twin_could_forge_scene_state(pki):
    """The control for the next test: the same forgeries over the same link do arrive with access control
    off, so it is the policy that stops them, not the topology."""
    port = free_port()
    victim = _session(pki, "twin", listen=[f"tls/localhost:{port}"], acl=False)
    try:
        inbox = Inbox(victim)
        attacker = _session(pki, "twin", connect=[f"tls/localhost:{port}"], acl=False)
        try:
            wait_until(lambda: len(list(attacker.info.peers_zid())) == 1, what="the TLS link")
            forged = _forgeries(1, np.zeros(3))
            _put_all(attacker, forged)
            wait_until(lambda: all(inbox.has(data) for _, data in forged), 10, "the forgeries")
        finally:
            inbox.close()
            attacker.close()
    finally:
        victim.close()


def test_mutual_tls_and_access_control_let_only_the_remote_speak_for_the_scene(pki, tmp_path_factory):
    from scenes.remote import Remote
    from scenes.scenefile import parse_scene
    from sync.zenoh_transport import ZenohTransport
    from twin.runtime import Local, LocalSettings

    remote_port, twin_port = free_port(), free_port()
    remote_ep, twin_ep = f"tls/localhost:{remote_port}", f"tls/localhost:{twin_port}"
    cache = tmp_path_factory.getbasetemp() / "coacd"
    server = _session(pki, "remote", listen=[remote_ep])
    opened = []
    try:
        at_remote = Inbox(server, KEYS.root + "/operator/**")
        runner = RemoteRunner(Remote(parse_scene(SCENE), ZenohTransport(server), cache_dir=cache))
        runner.start()
        # A second, legitimate twin listens too, so a certified attacker can reach it directly.
        client = _session(pki, "twin", connect=[remote_ep], listen=[twin_ep])
        opened.append(client)
        at_twin = Inbox(client)
        attacker = _session(pki, "twin", connect=[remote_ep, twin_ep])
        opened.append(attacker)
        wait_until(lambda: len(list(attacker.info.peers_zid())) == 2, what="the attacker's two TLS links")
        seen_by_attacker = Inbox(attacker)
        # It answers the late joiner's questions with a scene and an object of its own.
        fake_info = encode(SceneInfo(v=VERSION, stamp_ns=1, name="phantom", table_size=(1.0, 1.0, 0.1),
                                     table_height=0.5, table_material="wood_pine", ee_radius=0.02,
                                     ee_position=(0.0, 0.0, 0.6)))
        forged = _forgeries(runner.remote.epoch, runner.remote.twin.pose("can")[0])
        queryables = [
            attacker.declare_queryable("twin/*/scene", lambda q: q.reply("twin/phantom/scene", fake_info)),
            attacker.declare_queryable(KEYS.state, lambda q: q.reply(forged[0][0], forged[0][1]))]
        strangers = {kind: _stranger(pki, kind, remote_port)
                     for kind in ("no certificate", "another CA's certificate", "plain TCP")}
        opened.extend(strangers.values())
        seen_by_stranger = {kind: Inbox(s) for kind, s in strangers.items()}

        local = Local(ZenohTransport(client), settings=LocalSettings(cache_dir=cache))
        try:
            wait_objects(local, 2)  # the twin syncs the scene over mutual TLS
            assert local.keys.scene == SCENE["name"]  # the attacker's scene answer never reached it
            assert local.expected == 2  # nor its phantom cloud
            wait_until(lambda: len(seen_by_attacker.samples) > 0, what="the attacker's subscription")

            # (a), (b): no link, nothing received, nothing delivered
            stranger_command = _command([0.1, 0.1, 0.6], epoch=99)
            own = {stranger_command, *(data for _, data in forged)}  # a session hears its own puts
            for kind, s in strangers.items():
                assert seen_by_stranger[kind].samples == [], f"{kind}: received scene data"
                _put_all(s, [(KEYS.operator, stranger_command), *forged])
                assert list(s.info.peers_zid()) == [], f"{kind}: a peer accepted it"
            assert len(list(server.info.peers_zid())) == 2  # the twin and the certified attacker only

            # (c): a certified twin forges scene state, then sends an allowed command over the same links
            before = {i: local.twin.pose(i)[0].copy() for i in local.objects}
            received, dropped = local.link.counters.messages_received, local.link.counters.dropped_malformed
            target = runner.remote.twin.data.mocap_pos[0] + np.array([0.05, -0.1, 0.04])
            command = _command(target)
            _put_all(attacker, [*forged, (KEYS.operator, command)])
            wait_until(lambda: at_twin.has(command) and at_remote.has(command), what="the allowed command")
            wait_until(lambda: np.allclose(runner.remote.twin.data.mocap_pos[0], target),
                        what="the remote's end effector to follow the command")
            local.run(10.0, until=lambda: local.inbox.empty() and not local.adding)
            for _, data in forged:
                assert not at_twin.has(data), "a forgery reached the twin's session"
                assert not at_remote.has(data)
            assert sorted(local.objects) == ["can", "crate"] and local.expected == 2
            for object_id, position in before.items():  # the forged pose would move the can 200 mm
                now = local.twin.pose(object_id)[0]
                assert np.linalg.norm(now - position) < 0.005, object_id
                # the twin's body frame sits on its estimate, mm off the truth's: 20 mm is no forgery
                assert np.linalg.norm(now - runner.remote.twin.pose(object_id)[0]) < 0.02, object_id
            # the forgeries were not dropped by the twin's checks: they never arrived
            assert local.link.counters.dropped_malformed == dropped == 0
            assert local.link.counters.messages_received >= received
            for kind in strangers:  # while the remote published poses and heartbeats all along
                assert {data for _, data in seen_by_stranger[kind].samples} <= own, f"{kind}: received scene data"
            assert not at_remote.has(stranger_command) and not at_twin.has(stranger_command)
        finally:
            local.close()
            for q in queryables:
                q.undeclare()
            runner.stop()
            runner.remote.close()
    finally:
        for s in opened:
            s.close()
        server.close()


# -- a flood -------------------------------------------------------------------------------------------

#: At most this many messages, for at most FLOOD_SECONDS: bounded, whatever the machine's speed.
FLOOD_COUNT = 20_000
FLOOD_SECONDS = 3.0
GARBAGE = ("undecodable", "wrong-key", "non-finite")  # the flood's kinds the link drops, by reason


def _flood_messages(epoch: int, crate_position: np.ndarray) -> dict[str, tuple[str, bytes]]:
    """One message of each kind a flood cycles through: (key, payload) by the reason the twin should give."""
    far = tuple(float(x) for x in crate_position + np.array([0.3, 0.0, 0.0]))

    def pose(object_id: str, position, epoch: int = epoch - 1) -> bytes:  # type: ignore[no-untyped-def]
        return encode(Pose(v=VERSION, stamp_ns=1, object_id=object_id, epoch=epoch, seq=1, sim_time=0.0,
                           position=position, quat=(1.0, 0.0, 0.0, 0.0), linvel=(0.0, 0.0, 0.0),
                           angvel=(0.0, 0.0, 0.0)))

    return {"undecodable": (KEYS.object("crate", "pose"), b"\xc1" + bytes(range(64))),  # 0xc1: never msgpack
            "wrong-key": (KEYS.object("crate", "pose"), pose("can", far, epoch + 1)),
            "non-finite": (KEYS.object("crate", "pose"), pose("crate", (float("nan"), 0.0, 0.5), epoch + 1)),
            "stale": (KEYS.object("crate", "pose"), pose("crate", far))}  # valid, older epoch: out of order


def test_a_flood_of_garbage_and_stale_poses_is_counted_and_the_twin_runs_on(tmp_path_factory):
    from sync.zenoh_transport import ZenohTransport
    from twin.runtime import Local, LocalSettings

    remote_ep, twin_ep = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    cache = tmp_path_factory.getbasetemp() / "coacd"
    with running_remote(remote_ep, cache) as runner:
        session = open_session(make_config(connect=[remote_ep], listen=[twin_ep]))
        flooder = open_session(make_config(connect=[twin_ep]))
        try:
            local = Local(ZenohTransport(session), settings=LocalSettings(cache_dir=cache))
            try:
                wait_objects(local, 2)
                wait_until(lambda: len(list(flooder.info.peers_zid())) == 1, what="the flooder's link")
                done = threading.Event()
                sentinel = (KEYS.root + "/operator/flood-done", b"done")
                seen = Inbox(session, sentinel[0])
                kinds = _flood_messages(runner.remote.epoch, local.twin.pose("crate")[0])
                sent = dict.fromkeys(kinds, 0)

                import zenoh

                # Publishers that know the twin's subscriptions: a put before they are known goes nowhere.
                pubs = {key: flooder.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
                        for key in {k for k, _ in kinds.values()} | {sentinel[0]}}
                wait_until(lambda: all(p.matching_status.matching for p in pubs.values()),
                            what="the twin's subscriptions to reach the flooder")

                def flood() -> None:
                    names, deadline = list(kinds), time.monotonic() + FLOOD_SECONDS
                    for i in range(FLOOD_COUNT):
                        if time.monotonic() > deadline:
                            break
                        name = names[i % len(names)]
                        pubs[kinds[name][0]].put(kinds[name][1])
                        sent[name] += 1
                    pubs[sentinel[0]].put(sentinel[1])  # same link, after the flood: in order
                    done.set()

                crate = local.twin.pose("crate")[0].copy()
                out_of_order, t0 = local.report.out_of_order, local.twin.time
                thread = threading.Thread(target=flood)
                thread.start()
                try:
                    # Zenoh runs each subscriber's callbacks in order, but not one subscriber's after another's:
                    # the sentinel (its own subscriber) says the flood is over, not that the twin's
                    # subscriber has seen all of it. So the twin runs on until the counts add up.
                    dropped = local.link.counters.dropped_by_reason

                    def counted() -> bool:
                        return (seen.has(b"done")
                                and sum(dropped[r] for r in GARBAGE) >= sum(sent[r] for r in GARBAGE)
                                and local.report.out_of_order - out_of_order >= sent["stale"])

                    # The inbox is empty only for a moment (the remote's heartbeats keep coming): it is part of
                    # when to stop, not of what is asserted after.
                    stats = local.run(120.0, until=lambda: local.inbox.empty() and counted())
                finally:
                    thread.join()
                seen.close()
                for p in pubs.values():
                    p.undeclare()
                assert done.is_set() and seen.has(b"done"), "the flood did not finish within the run's failsafe"
                assert sum(sent.values()) > 0
                # The loop kept stepping: simulated time advanced by every step it took, none skipped.
                assert stats.steps > 0 and 0 <= stats.missed <= stats.steps
                assert local.twin.time - t0 == pytest.approx(stats.steps * local.twin.model.opt.timestep, rel=1e-6)
                # Every garbage message was dropped and counted under its reason; every stale one refused.
                assert counted(), (f"the flood's messages did not all arrive within the run's failsafe: sent {sent}, "
                                   f"dropped {dict(dropped)}, out of order {local.report.out_of_order - out_of_order}, "
                                   f"sentinel {seen.has(b'done')}, ran {stats.wall:.1f} s")
                for reason in GARBAGE:
                    assert dropped[reason] == sent[reason], reason
                assert local.report.out_of_order - out_of_order >= sent["stale"]
                assert sorted(local.objects) == ["can", "crate"]
                assert np.linalg.norm(local.twin.pose("crate")[0] - crate) < 0.005  # the stale poses say +300 mm
                print(f"flood: {sent} in {stats.wall:.2f} s; twin loop {stats.steps} steps, {stats.missed} missed "
                      f"deadlines, step p99 {stats.p99 * 1e3:.2f} ms")
            finally:
                local.close()
        finally:
            flooder.close()
            session.close()


@pytest.mark.parametrize(("argv", "message"), [
    (["local", "--connect", "garbage"], r"--connect 'garbage': not a Zenoh endpoint \(expected PROTOCOL/HOST:PORT"),
    (["local", "--connect", "tcp/notanaddress"], r"--connect 'tcp/notanaddress': no valid port"),
    (["local", "--listen", "tcp/notanaddress"], r"--listen 'tcp/notanaddress': no valid port"),  # not "exposed"
    (["remote", str(Path(__file__).parent / "data" / "small.toml"), "--listen", "tcp/127.0.0.1:99999"],
     r"--listen 'tcp/127.0.0.1:99999': no valid port"),
    # Zenoh takes these and retries them: 'twin local' waited 10 s for "no remote scene answered".
    (["local", "--connect", "tcp/999.0.0.1:1"], r"--connect 'tcp/999\.0\.0\.1:1': '999\.0\.0\.1' is not an IPv4 address"),
    (["local", "--connect", "tcp/10.0.1:7447"], r"'10\.0\.1' is not an IPv4 address \(four numbers 0-255\)"),
    (["local", "--connect", "tcp/::1:7447"], r"'::1' is not a host; an IPv6 address goes in brackets"),
    (["local", "--connect", "tcp/[::g]:7447"], r"'::g' is not an IPv6 address"),
    (["local", "--connect", "tcp/bad host:7447"], r"'bad host' is not a host name"),
    (["local", "--connect", "127.0.0.1:7447"], r"--connect '127\.0\.0\.1:7447': not a Zenoh endpoint"),
    (["local", "--connect", "tpc/127.0.0.1:7447"], r"unknown protocol 'tpc', not one of tcp, udp, tls"),
    (["local", "--connect", "tcp/127.0.0.1:0"], r"--connect 'tcp/127\.0\.0\.1:0': port 0 means any free port"),
    (["local", "--listen", "tcp/300.1.1.1:0"], r"--listen 'tcp/300\.1\.1\.1:0': '300\.1\.1\.1' is not an IPv4"),
])
def test_bad_endpoints_are_one_line_errors_naming_them(argv, message, capsys, monkeypatch):
    reached = _stop_before_opening(monkeypatch)
    from cli.main import main

    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(message, err), err
    assert reached == []  # refused before any session opens: none waits for a peer at a malformed address


@pytest.mark.parametrize(("endpoint", "host", "port"), [
    ("tcp/127.0.0.1:7447", "127.0.0.1", 7447), ("tcp/localhost:0", "localhost", 0), ("tcp/[::1]:7447", "::1", 7447),
    ("tls/router-1.example.org.:7447", "router-1.example.org.", 7447), ("udp/[::]:7447?rel=0#iface=lo", "::", 7447),
    ("unixsock-stream//tmp/zenoh.sock", None, None),
])
def test_good_endpoints_parse_into_their_parts(endpoint, host, port, monkeypatch):
    from sync.zenoh_transport import check_endpoint, parse_endpoint

    _fake_dns(monkeypatch, {"router-1.example.org.": ["192.0.2.1"]})  # this machine has no DNS
    parsed = parse_endpoint(endpoint)
    assert (parsed.protocol, parsed.host, parsed.port) == (endpoint.split("/")[0], host, port)
    check_endpoint(endpoint, "--listen")  # raises nothing


# -- host names: resolved where endpoints are checked ---------------------------------------------------

def _fake_dns(monkeypatch, names: dict[str, list[str]], *, delay: float = 0.0) -> list[str]:  # type: ignore[no-untyped-def]
    """Answer ``names`` (name -> addresses) from a fake resolver, after ``delay`` seconds; other hosts as the
    system does. Returns the hosts asked, in order."""
    import socket

    real, asked = socket.getaddrinfo, []

    def getaddrinfo(host, port, *args, **kwargs):  # type: ignore[no-untyped-def]
        asked.append(host)
        if host not in names:
            return real(host, port, *args, **kwargs)
        time.sleep(delay)
        return [(socket.AF_INET6 if ":" in a else socket.AF_INET, socket.SOCK_STREAM, 6, "",
                 (a, port or 0, 0, 0) if ":" in a else (a, port or 0)) for a in names[host]]

    monkeypatch.setattr(socket, "getaddrinfo", getaddrinfo)
    return asked


# RFC 6761: names under .invalid never resolve, with or without a network.
@pytest.mark.parametrize(("argv", "message"), [
    (["local", "--connect", "tcp/nosuchhost.invalid:7447"],
     r"^twin local: error: --connect 'tcp/nosuchhost\.invalid:7447': host 'nosuchhost\.invalid' does not resolve \("),
    (["remote", SMALL_SCENE, "--listen",
      "tcp/nosuchhost.invalid:0", "--insecure"],
     r"^twin remote: error: --listen 'tcp/nosuchhost\.invalid:0': host 'nosuchhost\.invalid' does not resolve"),
    (["remote", SMALL_SCENE, "--listen", "tcp/nosuchhost.invalid:0"],  # not "exposed": it is nowhere
     r"--listen 'tcp/nosuchhost\.invalid:0': host 'nosuchhost\.invalid' does not resolve"),
])
def test_a_host_name_that_does_not_resolve_is_refused_at_once_naming_the_flag(argv, message, capsys, monkeypatch):
    reached = _stop_before_opening(monkeypatch)
    from cli.main import main

    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(message, err), err
    assert reached == []  # refused before any session: it waited 10 s for one before


@pytest.mark.parametrize("key", ["connect", "listen"])
def test_a_host_name_in_a_zenoh_config_that_does_not_resolve_is_refused(key, tmp_path, monkeypatch, capsys):
    file = tmp_path / "names.json5"
    file.write_text(f'{{ {key}: {{ endpoints: ["tcp/nosuchhost.invalid:7447"] }} }}')
    reached = _stop_before_opening(monkeypatch)
    from cli.main import main

    assert main(["local", "--zenoh-config", str(file), "--insecure"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(
        rf"zenoh config \S+: {key} endpoint 'tcp/nosuchhost\.invalid:7447': host 'nosuchhost\.invalid' does not "
        rf"resolve", err), err
    assert reached == []


@pytest.mark.parametrize(("addresses", "exposed"), [
    (["127.0.0.1"], False), (["127.0.1.1"], False), (["::1", "127.0.0.1"], False),  # /etc/hosts' own names
    (["192.0.2.7"], True), (["127.0.0.1", "192.0.2.7"], True), (["2001:db8::7"], True),
])
def test_a_listen_host_name_is_judged_by_the_addresses_it_resolves_to(addresses, exposed, monkeypatch, capsys):
    from sync.zenoh_transport import exposed_without_tls

    _fake_dns(monkeypatch, {"twin-host.test": addresses, "localhost": addresses})
    for endpoint in ("tcp/twin-host.test:7447", "tcp/localhost:7447"):  # "localhost" is a name like any other
        assert bool(exposed_without_tls([endpoint])) is exposed, endpoint
    reached = _stop_before_opening(monkeypatch)
    from cli.main import main

    assert main(["remote", SMALL_SCENE, "--listen", "tcp/twin-host.test:0"]) == 2
    err = capsys.readouterr().err
    if exposed:
        assert reached == [] and re.search(r"--listen 'tcp/twin-host\.test:0' is reachable from other machines in "
                                           r"plain text; .* or pass --insecure", err), err
    else:
        assert "stopped before opening (test)" in err and len(reached) == 1, err


def test_each_endpoint_is_resolved_once(monkeypatch, capsys):
    asked = _fake_dns(monkeypatch, {"twin-host.test": ["127.0.0.1"], "remote-host.test": ["127.0.0.1"]})
    reached = _stop_before_opening(monkeypatch)
    from cli.main import main

    assert main(["local", "--listen", "tcp/twin-host.test:0", "--connect", "tcp/remote-host.test:7447"]) == 2
    assert len(reached) == 1, capsys.readouterr().err
    assert sorted(asked) == ["remote-host.test", "twin-host.test"]


def test_resolving_a_host_name_is_bounded(monkeypatch):
    import sync.zenoh_transport as zt

    monkeypatch.setattr(zt, "RESOLVE_TIMEOUT", 0.2)
    # A DNS server that answers only after 2 s: unbounded, the name would resolve and no error come.
    _fake_dns(monkeypatch, {"slow.test": ["127.0.0.1"]}, delay=2.0)
    with pytest.raises(zt.SessionError, match=r"^--connect 'tcp/slow\.test:7447': host 'slow\.test' did not "
                                              r"resolve within 0\.2 s$"):
        zt.make_config(connect=["tcp/slow.test:7447"], connect_name="--connect")


def test_a_bad_zenoh_config_is_one_line_with_its_position(tmp_path, capsys):
    from cli.main import main

    bad = tmp_path / "bad.json5"
    bad.write_text("{{{ not json\n")
    assert main(["local", "--zenoh-config", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "at line 1, column 2" in err and ".rs:" not in err, err


@pytest.mark.parametrize("text", ["[]", "// nothing but a comment\n", ""])
def test_a_json5_zenoh_config_that_is_not_an_object_is_refused(text, tmp_path, capsys):
    """Zenoh read "[]" as an empty config: whatever the user meant to set was dropped without a word."""
    from cli.main import main

    path = tmp_path / "z.json5"
    path.write_text(text)
    assert main(["local", "--zenoh-config", str(path), "--duration", "0.1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a JSON5 object ({ ... }) at the top level" in err, err


@pytest.mark.parametrize("make", ["deep", "huge", "folder", "fifo", "tls fifo", "tls device", "dictionary fifo",
                                  "pubkey device"])
def test_a_zenoh_config_or_a_file_it_names_that_cannot_be_a_config_is_refused_in_one_line(make, tmp_path, capsys):
    """A config nested 30,000 deep crashed Zenoh's parser (a segmentation fault); a TLS key that was a FIFO hung
    the session's opening, /dev/zero ate memory; a 200 MB config took 16 GB; a folder was 'no such file'. An
    authentication dictionary that was a FIFO hung it too, ignoring Ctrl-C."""
    import os

    from cli.main import main

    path = tmp_path / "z.json5"
    said = {"deep": "nested more than 64 levels deep", "huge": "more than the 1,048,576 such a file may hold",
            "folder": "is a folder, not a file", "fifo": "is a device or a pipe, not a file",
            "tls fifo": "transport/link/tls/listen_private_key", "tls device": "/dev/zero: is a device or a pipe",
            "dictionary fifo": "transport/auth/usrpwd/dictionary_file",
            "pubkey device": "transport/auth/pubkey/public_key_file /dev/zero: is a device or a pipe"}[make]
    if make == "deep":
        path.write_text("{ metadata: " + "{a:" * 30_000 + "1" + "}" * 30_000 + " }")
    elif make == "huge":
        path.write_text('{ metadata: { note: "' + "x" * (2 << 20) + '" } }')
    elif make == "folder":
        path.mkdir()
    elif make == "fifo":
        os.mkfifo(path)
    elif make == "dictionary fifo":
        os.mkfifo(tmp_path / "dict.fifo")
        path.write_text('{ transport: { auth: { usrpwd: { user: "a", password: "b", dictionary_file: "'
                        + str(tmp_path / "dict.fifo") + '" } } } }')
    elif make == "pubkey device":
        path.write_text('{ transport: { auth: { pubkey: { public_key_file: "/dev/zero" } } } }')
    else:
        key = str(tmp_path / "key.fifo") if make == "tls fifo" else "/dev/zero"
        if make == "tls fifo":
            os.mkfifo(key)
        tls = f'listen_private_key: "{key}", listen_certificate: "{key}"'
        path.write_text("{ transport: { link: { tls: { " + tls + " } } } }")
    assert main(["local", "--zenoh-config", str(path), "--duration", "0.1"]) == 2
    err = capsys.readouterr().err
    assert said in err and err.count("\n") == 1, err


# -- what a zenoh config leaves open ------------------------------------------------------------------

def _own_sockets() -> list[tuple[str, str]]:
    """This process's listening TCP and bound UDP sockets, as (table, hex local address) from /proc/net."""
    import os

    inodes = set()
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:  # closed since listed
            continue
        if target.startswith("socket:["):
            inodes.add(target[len("socket:["):-1])
    found = []
    for table in ("tcp", "tcp6", "udp", "udp6"):
        for line in Path(f"/proc/net/{table}").read_text().splitlines()[1:]:
            fields = line.split()
            if fields[9] in inodes and (table.startswith("udp") or fields[3] == "0A"):  # 0A: LISTEN
                found.append((table, fields[1]))
    return found


def _stop_before_opening(monkeypatch) -> list:  # type: ignore[no-untyped-def]
    """Make the CLI stop where it would open its session (exit 2): the configs it got that far with."""
    import sync.zenoh_transport as zt

    reached = []

    def stop(conf):  # type: ignore[no-untyped-def]
        reached.append(conf)
        raise zt.SessionError("stopped before opening (test)")

    monkeypatch.setattr(zt, "open_session", stop)
    return reached


def _effective(conf) -> tuple:  # type: ignore[no-untyped-def]
    return tuple(json.loads(conf.get_json(key)) for key in ("listen/endpoints", "connect/endpoints",
                                                            "scouting/multicast/enabled", "scouting/gossip/enabled"))


@pytest.mark.parametrize("text", [
    "{}",
    '{ mode: "router" }',  # Zenoh's router default is tcp/[::]:7447
    '{ listen: { endpoints: { router: ["tcp/[::]:7447"], peer: ["tcp/[::]:0"] } } }',  # Zenoh's defaults, written out
    # docs/sync.md's TLS example for the twin: no listen key
    '{ mode: "peer", transport: { link: { tls: { root_ca_certificate: "ca.pem" } } } }',
])
def test_a_zenoh_config_that_does_not_say_listens_on_loopback_only_with_scouting_off(text, tmp_path):
    """Zenoh's own defaults listen on every interface and join multicast scouting (224.0.0.224:7446)."""
    file = tmp_path / "said-nothing.json5"
    file.write_text(text)
    conf = make_config(config_file=file)
    # Checked before the session opens, so that even failing this test never listens beyond loopback.
    assert _effective(conf) == (["tcp/127.0.0.1:0"], [], False, False)
    assert _effective(make_config(config_file=file, listen_default="tcp/127.0.0.1:7447",
                                  connect_default="tcp/127.0.0.1:7448")) == (
        ["tcp/127.0.0.1:7447"], ["tcp/127.0.0.1:7448"], False, False)  # the CLI's defaults, as without a file
    if "tls" in text:
        return  # its certificate file does not exist
    before = set(_own_sockets())
    session = open_session(conf)
    try:
        opened = set(_own_sockets()) - before
        assert opened == {(table, address) for table, address in opened if address.startswith("0100007F:")}, opened
        assert len(opened) == 1 and next(iter(opened))[0] == "tcp"  # one TCP listener on 127.0.0.1, no UDP
    finally:
        session.close()


def test_the_cli_with_a_zenoh_config_that_does_not_say_keeps_its_loopback_defaults(tmp_path, monkeypatch, capsys):
    empty = tmp_path / "empty.json5"
    empty.write_text("{}\n")
    reached = _stop_before_opening(monkeypatch)
    from cli.main import main

    assert main(["remote", SMALL_SCENE, "--zenoh-config", str(empty)]) == 2
    assert main(["local", "--zenoh-config", str(empty)]) == 2
    assert capsys.readouterr().err.count("stopped before opening (test)") == 2
    assert [_effective(conf) for conf in reached] == [(["tcp/127.0.0.1:7447"], [], False, False),
                                                      (["tcp/127.0.0.1:0"], ["tcp/127.0.0.1:7447"], False, False)]


@pytest.mark.parametrize(("text", "message", "warning"), [
    ('{ listen: { endpoints: ["tcp/0.0.0.0:7447"] } }',
     r"zenoh config \S+: listen endpoint 'tcp/0\.0\.0\.0:7447' is reachable from other machines in plain text; "
     r"listen on a tls/ endpoint \(certificates in a zenoh config\) or pass --insecure",
     "listening on tcp/0.0.0.0:7447 without TLS"),
    ('{ mode: "peer", listen: { endpoints: { peer: ["tls/[::1]:7447", "udp/[::]:7447"] } } }',
     r"zenoh config \S+: listen endpoint 'udp/\[::\]:7447' is reachable", "listening on udp/[::]:7447 without TLS"),
    ('{ scouting: { multicast: { enabled: true } } }',
     r"zenoh config \S+: scouting/multicast/enabled is true: it announces this session to every machine on the "
     r"network in plain text; remove it or pass --insecure", "multicast scouting on"),
])
def test_a_zenoh_config_exposing_the_session_needs_insecure(text, message, warning, tmp_path, monkeypatch, capsys,
                                                            caplog):
    file = tmp_path / "exposed.json5"
    file.write_text(text)
    reached = _stop_before_opening(monkeypatch)  # and so no test here listens beyond loopback, even failing
    from cli.main import main

    assert main(["local", "--zenoh-config", str(file)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(message, err), err
    assert reached == []  # refused before any session
    assert not any(warning in r.getMessage() for r in caplog.records)

    assert main(["local", "--zenoh-config", str(file), "--insecure"]) == 2  # let through to the stop, warned
    assert "stopped before opening (test)" in capsys.readouterr().err and len(reached) == 1
    assert any(r.levelname == "WARNING" and warning in r.getMessage() for r in caplog.records)
    if "listen" in text:  # --listen replaces the file's endpoints: nothing exposed then
        assert main(["local", "--zenoh-config", str(file), "--listen", "tcp/127.0.0.1:0"]) == 2
        assert "stopped before opening (test)" in capsys.readouterr().err and len(reached) == 2
        assert _effective(reached[1])[0] == ["tcp/127.0.0.1:0"]


@pytest.mark.parametrize(("text", "message"), [
    ('{ listen: { endpoints: ["tcp/999.0.0.1:1"] } }',
     r"zenoh config \S+: listen endpoint 'tcp/999\.0\.0\.1:1': '999\.0\.0\.1' is not an IPv4 address"),
    ('{ listen: { endpoints: ["tcp/::1:7447"] } }',  # not "exposed": malformed
     r"listen endpoint 'tcp/::1:7447': '::1' is not a host; an IPv6 address goes in brackets"),
    ('{ connect: { endpoints: ["tcp/127.0.0.1:0"] } }',
     r"zenoh config \S+: connect endpoint 'tcp/127\.0\.0\.1:0': port 0 means any free port"),
    ('{ connect: { endpoints: { peer: ["tcp/bad host:7447"] } } }', r"connect endpoint .*'bad host' is not a host name"),
])
def test_bad_endpoints_in_a_zenoh_config_are_one_line_errors_naming_them(text, message, tmp_path, monkeypatch,
                                                                         capsys):
    file = tmp_path / "bad-endpoint.json5"
    file.write_text(text)
    reached = _stop_before_opening(monkeypatch)
    from cli.main import main

    assert main(["local", "--zenoh-config", str(file), "--insecure"]) == 2  # malformed, whatever --insecure says
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(message, err) and str(file) in err, err
    assert reached == []


def test_a_peer_asking_for_the_state_in_a_loop_gets_a_burst_then_one_answer_a_second(tmp_path_factory):
    from scenes.remote import STATE_QUERY_BURST, STATE_QUERY_RATE
    from sync.zenoh_transport import ZenohTransport

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with running_remote(endpoint, tmp_path_factory.getbasetemp() / "coacd") as runner:
        asker = open_session(make_config(connect=[endpoint]))
        try:
            transport = ZenohTransport(asker)
            wait_until(lambda: transport.get(KEYS.info, 1.0) != [], what="the remote's queryables")
            t0, answered, asked = time.monotonic(), 0, 30
            for _ in range(asked):
                replies = transport.get(KEYS.state, 1.0)
                # An answer is the whole state (both clouds first); a refused query is answered with nothing.
                assert replies == [] or sum(k.endswith("/cloud") for k, _ in replies) == 2
                answered += replies != []
            elapsed = time.monotonic() - t0
            assert STATE_QUERY_BURST <= answered <= STATE_QUERY_BURST + STATE_QUERY_RATE * elapsed + 1
            assert runner.remote.link.counters.queries_refused == asked - answered
        finally:
            asker.close()


def test_a_peer_answering_without_end_is_read_only_up_to_the_caps(monkeypatch):
    import sync.zenoh_transport as zt

    port = free_port()
    server = open_session(make_config(listen=[f"tcp/127.0.0.1:{port}"]))
    client = open_session(make_config(connect=[f"tcp/127.0.0.1:{port}"]))
    try:
        def flood(query) -> None:  # type: ignore[no-untyped-def]
            for i in range(300):
                query.reply(f"twin/x/{i}", bytes(1000))

        queryable = server.declare_queryable("twin/x/**", flood)
        transport = zt.ZenohTransport(client)
        wait_until(lambda: len(transport.get("twin/x/**", 2.0)) == 300, what="the hostile queryable")
        monkeypatch.setattr(zt, "MAX_REPLIES", 50)
        assert len(transport.get("twin/x/**", 2.0)) == 50
        monkeypatch.setattr(zt, "MAX_REPLIES", 10_000)
        monkeypatch.setattr(zt, "MAX_REPLY_BYTES", 20_500)
        assert len(transport.get("twin/x/**", 2.0)) == 20
        queryable.undeclare()
    finally:
        client.close()
        server.close()


@pytest.mark.parametrize(("text", "said"), [
    # The twin's side refused it after the remote had started: the error, then a demo that never exited.
    ('{ listen: { endpoints: ["tcp/0.0.0.0:7450"] } }', "(this command runs on loopback only)"),
    # The remote's side refused it: a child's traceback before the one line.
    ('{ scouting: { multicast: { enabled: true } } }', "scouting/multicast/enabled is true"),
    ("{ unknown_key: 5 }", "unknown field `unknown_key`"),
])
def test_twin_demo_with_a_config_a_side_refuses_is_one_line_and_leaves_no_process(text, said, tmp_path, capfd):
    import multiprocessing

    from cli.main import main

    config = tmp_path / "z.json5"
    config.write_text(text)
    assert main(["demo", "--duration", "0.5", "--zenoh-config", str(config)]) == 2
    err = capfd.readouterr().err
    lines = [line for line in err.splitlines() if "error" in line or "Traceback" in line]
    assert len(lines) == 1 and said in lines[0] and "Traceback" not in err, err
    assert not multiprocessing.active_children()
