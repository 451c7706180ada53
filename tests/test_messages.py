"""The wire format: round trips, size, and every rejection ``decode`` makes before anything is trusted."""

from __future__ import annotations

import logging
import math

import msgspec
import numpy as np
import pytest
import zstandard
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from msgspec.structs import replace

from sync.clock import SimClock
from sync.inprocess import InProcessBus
from sync.keys import Keys, intersects
from sync.link import Link
from sync.messages import (
    MAX_CLOUD_POINTS,
    VERSION,
    Gone,
    Heartbeat,
    MessageError,
    OperatorCommand,
    OperatorForce,
    OperatorTarget,
    Pose,
    SceneInfo,
    as_received,
    cloud_message,
    decode,
    encode,
    unpack_completed,
    unpack_normals,
    unpack_points,
)
from twin.runtime import Local, LocalSettings, SyncError

IDENTITY = np.array([1.0, 0, 0, 0])


def _cloud(n: int = 100, **kw):  # type: ignore[no-untyped-def]
    points = np.random.default_rng(1).random((n, 3))
    kw = {"material": None, "density": 1.0, **kw}
    return cloud_message("o", points, stamp_ns=0, epoch=7, seq=1, frame_position=np.zeros(3), frame_quat=IDENTITY,
                         **kw)


def _pose(**fields) -> Pose:  # type: ignore[no-untyped-def]
    good = Pose(v=VERSION, stamp_ns=0, object_id="crate", epoch=1, seq=3, sim_time=0.5, position=(0.1, 0.2, 0.3),
                quat=(1.0, 0.0, 0.0, 0.0), linvel=(0.0, 0.0, 0.0), angvel=(0.0, 0.0, 0.0))
    return replace(good, **fields)


def test_cloud_codec_round_trip_and_ratio():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(50_000, 3)) * 0.1
    msg = cloud_message("o", points, stamp_ns=0, epoch=0, seq=1, material=None, density=1000.0,
                        frame_position=np.zeros(3), frame_quat=IDENTITY)
    back = unpack_points(decode(encode(msg)))
    assert back.shape == points.shape
    # Order is not kept; the set of points is, to half a quantum per axis.
    assert np.abs(np.sort(back, axis=0) - np.sort(points, axis=0)).max() <= msg.quantum / 2 + 1e-12
    assert len(encode(msg)) < points.size * 4 / 2  # better than half of float32 even for random points


def test_a_cloud_whose_offsets_reach_past_the_coordinate_bound_is_refused():
    # The header's origin is in range; a quantum of 0.9 m stretches 32-bit offsets to 3.9e9 m.
    points = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.0, 0.2, 0.0], [0.0, 0.0, 0.2]])
    msg = cloud_message("o", points, stamp_ns=0, epoch=0, seq=1, material=None, density=1000.0,
                        frame_position=np.zeros(3), frame_quat=IDENTITY)
    stretched = decode(encode(replace(msg, quantum=0.9)))  # the header alone is fine
    with pytest.raises(MessageError, match=r"cloud 'o': points beyond 1000 m of the origin") as caught:
        unpack_points(stretched)
    assert caught.value.reason == "out-of-range"
    back = unpack_points(decode(encode(msg)))  # reordered on the wire
    assert np.abs(np.sort(back, axis=0) - np.sort(points, axis=0)).max() <= msg.quantum


def test_normals_travel_with_their_points_and_a_cloud_without_has_none():
    rng = np.random.default_rng(3)
    directions = rng.normal(size=(20_000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    points = 0.05 * directions + [0.3, -0.2, 0.8]  # a 5 cm ball; its normals point away from its centre
    msg = decode(encode(cloud_message("o", points, stamp_ns=0, epoch=0, seq=1, material=None, density=1000.0,
                                      frame_position=np.zeros(3), frame_quat=IDENTITY, normals=directions)))
    back, normals = unpack_points(msg), unpack_normals(msg)
    assert normals is not None and normals.shape == back.shape
    # The points were reordered on the wire; each normal still belongs to its point (one byte per axis).
    out = back - [0.3, -0.2, 0.8]
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    assert np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", out, normals), -1, 1))).max() < 1.0
    assert unpack_normals(_cloud()) is None
    again = as_received(points, directions)  # the benches' shortcut for the same round trip
    assert np.array_equal(again[0], back) and np.array_equal(again[1], normals)
    bad = directions.copy()
    bad[7] = np.nan
    assert unpack_normals(cloud_message("o", points, stamp_ns=0, epoch=0, seq=1, material=None, density=1.0,
                                        frame_position=np.zeros(3), frame_quat=IDENTITY, normals=bad)) is None


def test_normals_that_do_not_match_the_points_are_rejected():
    good = _cloud(100, normals=np.tile([0.0, 0.0, 1.0], (100, 1)))
    short = zstandard.ZstdCompressor().compress(np.zeros(3 * 99, np.int8).tobytes())
    with pytest.raises(MessageError) as err:
        decode(encode(replace(good, normals=short)))
    assert err.value.reason == "bad-payload"
    with pytest.raises(MessageError) as err:
        decode(encode(replace(good, normals=b"not zstd")))
    assert err.value.reason == "bad-payload"
    zero = zstandard.ZstdCompressor().compress(np.zeros(3 * 100, np.int8).tobytes())
    with pytest.raises(MessageError) as err:
        unpack_normals(decode(encode(replace(good, normals=zero))))
    assert err.value.reason == "bad-payload"


def test_completed_flags_travel_with_their_points_and_are_checked():
    rng = np.random.default_rng(4)
    points = rng.uniform(-0.05, 0.05, (1001, 3)) + np.array([0.0, 0.0, 0.8])  # 1001: the last byte holds one flag
    completed = points[:, 2] < 0.78  # the lowest fifth: a base the sender added
    msg = decode(encode(cloud_message("o", points, stamp_ns=0, epoch=0, seq=1, material=None, density=1000.0,
                                      frame_position=np.zeros(3), frame_quat=IDENTITY, completed=completed)))
    back, flags = unpack_points(msg), unpack_completed(msg)
    assert flags is not None and flags.shape == (1001,) and flags.sum() == completed.sum()
    # Reordered with the points (each on the 0.1 mm grid, so within a quantum of the cut).
    assert (back[flags, 2] < 0.78 + 1e-4).all() and (back[~flags, 2] > 0.78 - 1e-4).all()
    # None completed, or no flags: none sent.
    assert unpack_completed(cloud_message("o", points, stamp_ns=0, epoch=0, seq=1, material=None, density=1.0,
                                          frame_position=np.zeros(3), frame_quat=IDENTITY,
                                          completed=np.zeros(1001, bool))) is None
    assert unpack_completed(_cloud()) is None
    with pytest.raises(ValueError, match="completed flags of shape"):
        cloud_message("o", points, stamp_ns=0, epoch=0, seq=1, material=None, density=1.0,
                      frame_position=np.zeros(3), frame_quat=IDENTITY, completed=completed[:-1])
    # A payload of the wrong size, not zstd, or with flags past the last point: dropped as malformed.
    compress = zstandard.ZstdCompressor().compress
    for payload in (compress(bytes(125)), b"not zstd"):
        with pytest.raises(MessageError) as err:
            decode(encode(replace(msg, completed=payload)))
        assert err.value.reason == "bad-payload"
    past = decode(encode(replace(msg, completed=compress(bytes(125) + b"\xff"))))  # 126 bytes: the size is right
    with pytest.raises(MessageError, match="past its 1001 points") as err:
        unpack_completed(past)
    assert err.value.reason == "bad-payload"


def test_a_clouds_support_plane_travels_with_it_and_is_checked():
    tilted = (0.0, 0.6, 0.8, -0.75)  # unit normal, 0.75 m from the origin
    assert decode(encode(_cloud(support=tilted))).support == tilted
    assert decode(encode(_cloud())).support is None  # a cloud closed on nothing (the surface sensor's)
    for support, reason in (((0.0, 0.0, 2.0, -0.75), "out-of-range"),  # the twin would cut at the wrong height
                            ((0.0, 0.0, 1.0, float("nan")), "non-finite"),
                            ((0.0, 0.0, 1.0, float("inf")), "non-finite"),
                            ((0.0, 0.0, 1.0, -2000.0), "out-of-range")):
        with pytest.raises(MessageError) as err:
            decode(encode(replace(_cloud(), support=support)))
        assert err.value.reason == reason, support
    with pytest.raises(ValueError, match="expected 4 numbers"):
        _cloud(support=(0.0, 0.0, 1.0))
    with pytest.raises(MessageError):  # three numbers on the wire: not a Cloud
        decode(encode(replace(_cloud(), support=(0.0, 0.0, 1.0))))
    # A cloud recorded before the field (its array one shorter) decodes as without a plane.
    old = msgspec.msgpack.decode(encode(_cloud()))[:-1]
    assert decode(msgspec.msgpack.encode(old)).support is None


def test_a_good_pose_passes_unchanged():
    assert decode(encode(_pose())) == _pose()
    fast = _pose(linvel=(0.0, 99.0, 0.0), angvel=(999.0, 0.0, 0.0))  # within MAX_SPEED, MAX_ANGULAR_SPEED
    assert decode(encode(fast)) == fast
    assert decode(encode(_pose(seen=False))).seen is False


def test_a_pose_whose_seen_flag_is_not_a_bool_is_rejected():
    with pytest.raises(MessageError) as err:
        decode(encode(_pose(seen="yes")))
    assert err.value.reason == "undecodable"


@pytest.mark.parametrize(("fields", "reason"), [
    ({"position": (float("nan"), 0.0, 0.0)}, "non-finite"),
    ({"linvel": (0.0, float("inf"), 0.0)}, "non-finite"),
    ({"sim_time": float("nan")}, "non-finite"),
    ({"position": (1e9, 0.0, 0.0)}, "out-of-range"),
    ({"quat": (0.0, 0.0, 0.0, 0.0)}, "bad-quaternion"),
    ({"quat": (float("nan"), 0.0, 0.0, 1.0)}, "bad-quaternion"),
    ({"quat": (1.0, 1.0, 0.0, 0.0)}, "bad-quaternion"),
    ({"object_id": "../../etc"}, "bad-id"),
    ({"object_id": "a" * 65}, "bad-id"),
    ({"object_id": ""}, "bad-id"),
    ({"object_id": "obj1\n"}, "bad-id"),  # a regex's $ matches before a final newline: it passed
    ({"seq": -1}, "bad-seq"),
    ({"epoch": -5}, "bad-seq"),
    ({"v": VERSION + 1}, "version"),
    ({"position_sigma": -0.001}, "out-of-range"),
    ({"angle_sigma": float("nan")}, "non-finite"),
    ({"position_sigma": 1e9}, "out-of-range"),
    ({"answers_ns": 2**64 - 1}, "out-of-range"),  # msgpack carries it; the twin's int64 history cannot
    ({"answers_ns": 2**63}, "out-of-range"),
    ({"stamp_ns": 2**64 - 1}, "out-of-range"),
    ({"stamp_ns": -1}, "out-of-range"),
    ({"seq": 2**63}, "out-of-range"),
    ({"epoch": 2**64 - 1}, "out-of-range"),
    ({"linvel": (1e300, 0.0, 0.0)}, "out-of-range"),  # would reach MuJoCo's qvel
    ({"linvel": (60.0, 60.0, 60.0)}, "out-of-range"),  # 104 m/s
    ({"angvel": (0.0, 1e300, 0.0)}, "out-of-range"),
    ({"angvel": (0.0, 0.0, -1001.0)}, "out-of-range"),
])
def test_decode_rejects_poses_no_sender_could_mean(fields, reason):
    with pytest.raises(MessageError) as err:
        decode(encode(_pose(**fields)))
    assert err.value.reason == reason


def test_decode_rejects_other_impossible_messages():
    beat = Heartbeat(v=VERSION, stamp_ns=0, epoch=0, seq=1, sim_time=0.0, objects=-1)
    op = OperatorCommand(v=VERSION, stamp_ns=0, epoch=0, seq=1, position=(0.0, float("nan"), 0.0))
    info = SceneInfo(v=VERSION, stamp_ns=0, name="s", table_size=(1.0, -1.0, 0.1), table_height=0.5,
                     table_material="wood_oak", ee_radius=0.02, ee_position=(0.0, 0.0, 1.0))
    force = OperatorForce(v=VERSION, stamp_ns=0, epoch=0, seq=1, sim_time=0.0, force=(1e308, 0.0, 0.0),
                          position=(0.0, 0.0, 1.0))
    # Found fuzzing: any finite force, time or count passed; a device driver must not be handed 1e308 N.
    for msg, reason in [(beat, "bad-size"), (op, "non-finite"), (info, "bad-size"),
                        (replace(info, name="a/b", table_size=(1.0, 1.0, 0.1)), "bad-id"),
                        (force, "out-of-range"), (replace(force, force=(0.0, 0.0, -2e4)), "out-of-range"),
                        (replace(force, force=(0.0, 0.0, 9e3), sim_time=-0.5), "out-of-range"),
                        (replace(beat, objects=2**64 - 1), "bad-size"), (replace(beat, objects=1, sim_time=1e300), "out-of-range")]:
        with pytest.raises(MessageError) as err:
            decode(encode(msg))
        assert err.value.reason == reason


def test_every_stamp_and_sequence_number_must_fit_an_int64():
    largest = 2**63 - 1
    assert decode(encode(_pose(stamp_ns=largest, epoch=largest, seq=largest, answers_ns=largest))).seq == largest
    messages = [_pose(), _cloud(), Heartbeat(v=VERSION, stamp_ns=0, epoch=0, seq=1, sim_time=0.0, objects=1),
                Gone(v=VERSION, stamp_ns=0, object_id="o", epoch=0, seq=1),
                OperatorCommand(v=VERSION, stamp_ns=0, epoch=0, seq=1, position=(0.0, 0.0, 0.5)),
                OperatorTarget(v=VERSION, stamp_ns=0, device="d", epoch=0, seq=1, position=(0.0, 0.0, 0.5)),
                OperatorForce(v=VERSION, stamp_ns=0, epoch=0, seq=1, sim_time=0.0, force=(0.0,) * 3,
                              position=(0.0,) * 3)]
    for msg in messages:
        decode(encode(msg))
        for field in ("stamp_ns", "epoch", "seq"):
            with pytest.raises(MessageError) as err:
                decode(encode(replace(msg, **{field: 2**64 - 1})))
            assert err.value.reason == "out-of-range", (type(msg).__name__, field)


@pytest.mark.parametrize("msg", [_cloud(material="x" * 1_000_000, density=None),
                                 SceneInfo(v=VERSION, stamp_ns=0, name="s", table_size=(1.0, 0.6, 0.04),
                                           table_height=0.5, table_material="zz" * 1000, ee_radius=0.02,
                                           ee_position=(0.0, 0.0, 0.6))])
def test_a_name_longer_than_an_id_is_refused_and_never_logged_whole(msg):
    with pytest.raises(MessageError) as err:
        decode(encode(msg))
    assert err.value.reason == "bad-material" and len(str(err.value)) < 120


def test_a_cloud_of_a_material_the_twin_does_not_know_is_refused():
    assert decode(encode(_cloud(material="wood_pine", density=None))).material == "wood_pine"
    with pytest.raises(MessageError, match="unknown material 'adamantium'") as err:
        decode(encode(_cloud(material="adamantium", density=None)))
    assert err.value.reason == "bad-material"


def _scene(**fields) -> SceneInfo:  # type: ignore[no-untyped-def]
    good = SceneInfo(v=VERSION, stamp_ns=0, name="s", table_size=(1.0, 0.6, 0.04), table_height=0.5,
                     table_material="wood_pine", ee_radius=0.02, ee_position=(-0.3, 0.0, 0.56))
    return replace(good, **fields)


@pytest.mark.parametrize(("fields", "reason"), [
    ({"table_size": (1e-300, 1e-300, 1e-300)}, "out-of-range"),
    ({"table_size": (1000.0, 1000.0, 1000.0)}, "out-of-range"),  # under 1 km, but no table
    ({"table_height": 1e-9}, "out-of-range"),
    ({"ee_radius": 999.0}, "out-of-range"),
    ({"ee_radius": 1e-300}, "out-of-range"),  # MuJoCo refused the sphere: a ValueError out of Local()
    ({"table_material": "adamantium"}, "bad-material"),  # a MaterialError out of Local()
    ({"ee_radius": float("inf")}, "non-finite"),
])
def test_decode_rejects_scenes_no_twin_could_build(fields, reason):
    with pytest.raises(MessageError) as err:
        decode(encode(_scene(**fields)))
    assert err.value.reason == reason


def test_scenes_without_a_table_or_end_effector_still_decode():
    bare = _scene(table_size=None, table_height=0.0, table_material="", ee_radius=0.0)
    assert decode(encode(bare)) == bare
    assert decode(encode(_scene(table_material="PLA"))).table_material == "PLA"  # aliases too
    with pytest.raises(MessageError) as err:  # a tableless scene's material is unused, but bounded all the same
        decode(encode(_scene(table_size=None, table_height=0.0, table_material="z" * 10_000, ee_radius=0.0)))
    assert err.value.reason == "bad-material"


@pytest.mark.parametrize(("fields", "said"), [
    ({"table_material": "adamantium"}, "table material: unknown material 'adamantium'"),
    ({"ee_radius": 1e-300}, "end-effector radius 1e-300 m outside"),
    ({"name": "other"}, "scene 'other' described on scene 's''s key"),  # on the key asked for, another scene
])
def test_the_twin_refuses_a_scene_reply_it_cannot_use_and_says_so(fields, said, caplog):
    clock, bus = SimClock(), InProcessBus()
    info = _scene(**fields)
    bus.transport("remote").queryable("twin/s/**", lambda _selector: [(Keys("s").info, encode(info))])
    with caplog.at_level(logging.WARNING, logger="sync.link"), \
            pytest.raises(SyncError, match=r"^no remote scene answered on twin/s/scene within 0\.5 s$"):
        Local(bus.transport("twin"), clock=clock, scene="s", settings=LocalSettings(workers=0), wait=0.5)
    assert caplog.records and all(said in r.getMessage() for r in caplog.records)


@pytest.mark.parametrize("data", [b"", b"\x00\xff garbage", b"\x93\x01"])
def test_decode_rejects_garbage(data):
    with pytest.raises(MessageError):
        decode(data)


def test_a_cloud_whose_header_and_payload_disagree_is_rejected_before_inflating():
    msg = _cloud()
    with pytest.raises(MessageError, match="header claims 101 points") as err:
        decode(encode(replace(msg, count=101)))
    assert err.value.reason == "bad-payload"
    with pytest.raises(MessageError, match="not a zstd frame"):
        decode(encode(replace(msg, data=b"not zstd")))


def test_a_small_cloud_claiming_a_huge_size_is_refused_without_allocating():
    # 61 KB of zeros compress to a few bytes but claim billions of points: refused from the header alone.
    bomb = zstandard.ZstdCompressor().compress(bytes(61_000))
    msg = replace(_cloud(), count=MAX_CLOUD_POINTS + 1, data=bomb)
    with pytest.raises(MessageError) as err:
        decode(encode(msg))
    assert err.value.reason == "too-large"


@pytest.mark.parametrize(("fields", "reason"), [
    ({"frame_quat": (0.0, 0.0, 0.0, 0.0)}, "bad-quaternion"),
    ({"frame_position": (float("nan"), 0.0, 0.0)}, "non-finite"),
    ({"origin": (0.0, float("inf"), 0.0)}, "non-finite"),
    ({"density": -3.0}, "non-finite"),
    ({"density": 1e300}, "out-of-range"),  # a 4.8e296 kg crate
    ({"density": 1e-300}, "out-of-range"),
    ({"density": 0.09}, "out-of-range"),
    ({"density": 1.01e5}, "out-of-range"),
    ({"bits": 12}, "bad-header"),
    ({"quantum": float("nan")}, "bad-header"),
])
def test_decode_rejects_clouds_with_impossible_headers(fields, reason):
    with pytest.raises(MessageError) as err:
        decode(encode(replace(_cloud(), **fields)))
    assert err.value.reason == reason


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=400), st.integers(0, 399), st.binary(min_size=1, max_size=8))
def test_random_and_mutated_bytes_never_escape_as_anything_but_message_error(noise, at, patch):
    for data in (noise, (encode(_pose()) + noise)[:at] + patch + encode(_pose())[at:]):
        try:
            msg = decode(data)
        except MessageError:
            continue
        assert msg.v == VERSION  # what passes is a checked message


def test_the_link_drops_a_message_filed_under_another_objects_key_and_counts_why():
    bus = InProcessBus()
    rx, tx = Link(bus.transport()), Link(bus.transport())
    got = []
    keys = Keys("s")
    rx.subscribe(keys.objects, lambda k, m: got.append(m))
    tx.put(keys.object("crate", "pose"), _pose(object_id="can"))  # names the can on the crate's key
    tx.put(keys.object("crate", "pose"), _pose(quat=(0.0, 0.0, 0.0, 0.0)))
    tx.put(keys.object("crate", "pose"), _pose())
    assert [m.object_id for m in got] == ["crate"]
    assert rx.counters.dropped_malformed == 2
    assert dict(rx.counters.dropped_by_reason) == {"wrong-key": 1, "bad-quaternion": 1}


def _every_message() -> dict[str, tuple[str, object]]:
    """One good message of each type, by the key (of scene "s", object "crate") it travels on."""
    keys = Keys("s")
    return {keys.info: _scene(), keys.object("crate", "cloud"): replace(_cloud(), object_id="crate"),
            keys.object("crate", "pose"): _pose(), keys.object("crate", "gone"): Gone(
                v=VERSION, stamp_ns=0, object_id="crate", epoch=0, seq=1),
            keys.heartbeat: Heartbeat(v=VERSION, stamp_ns=0, epoch=0, seq=1, sim_time=0.0, objects=1),
            keys.operator: OperatorCommand(v=VERSION, stamp_ns=0, epoch=0, seq=1, position=(0.0, 0.0, 0.5)),
            keys.operator_target: OperatorTarget(v=VERSION, stamp_ns=0, device="d", epoch=0, seq=1,
                                                 position=(0.0, 0.0, 0.5)),
            keys.operator_force: OperatorForce(v=VERSION, stamp_ns=0, epoch=0, seq=1, sim_time=0.0,
                                               force=(0.0,) * 3, position=(0.0,) * 3)}


def test_the_link_takes_each_message_only_on_its_own_key_and_counts_the_rest_as_wrong_key():
    bus = InProcessBus()
    rx, tx = Link(bus.transport()), bus.transport()
    got: list[tuple[str, object]] = []
    rx.subscribe("twin/**", lambda k, m: got.append((k, m)))
    messages = _every_message()
    for key, msg in messages.items():
        tx.put(key, encode(msg))
    assert got == list(messages.items())
    wrong = [(other, msg) for key, msg in messages.items() for other in messages if other != key]
    wrong += [("twin/s/objects/x/y/pose", _pose()),  # deeper than an object key: was applied to the crate
              ("twin/s/objects/crate/pose/x", _pose()), ("twin/s/objects/crate", _pose()),
              ("twin/s/remote/heartbeat/x", messages[Keys("s").heartbeat]), ("twin/s/other", _scene()),
              ("twin/other/scene", _scene()),  # scene "s" described on scene "other"'s key
              (Keys("s").object("can", "pose"), _pose())]
    for key, msg in wrong:
        tx.put(key, encode(msg))
    assert len(got) == len(messages)
    assert dict(rx.counters.dropped_by_reason) == {"wrong-key": len(wrong)}


@pytest.mark.parametrize(("a", "b", "expected"), [
    ("twin/s/objects/a/pose", "twin/s/objects/**", True),
    ("twin/s/objects/a/pose", "twin/s/objects/*/*", True),
    ("twin/s/objects/a/pose", "twin/s/objects/*", False),
    ("twin/*/scene", "twin/s/scene", True),
    ("twin/s/scene", "twin/t/scene", False),
    ("twin/**", "twin", True),
    ("a/**/c", "a/b/x/c", True),
    ("a/**/c", "a/b/x/d", False),
])
def test_key_expressions_intersect_as_zenoh_matches_them(a, b, expected):
    assert intersects(a, b) is expected and intersects(b, a) is expected


def test_a_key_of_thousands_of_chunks_is_matched_without_recursion():
    # Matched as one chunk list against another, recursively, a 5,000-chunk key passed Python's recursion limit.
    deep = "twin/s/" + "/".join(["x"] * 5000)
    assert intersects("twin/s/**", deep + "/pose") is True
    assert intersects("twin/**/pose", deep + "/cloud") is False
    assert intersects(deep + "/**", "twin/*/" + "/".join(["*"] * 4999) + "/x/y") is True


def test_the_twin_saturates_the_force_it_sends_at_what_receivers_accept():
    # A contact spike past MAX_FORCE would be dropped by every receiver; sent saturated, its direction kept.
    from sync.messages import MAX_FORCE
    from twin.runtime import _saturated

    rng = np.random.default_rng(3)
    # Random directions and sizes up to 1e200 N: scaled to the limit exactly, one in seven came out a rounding
    # step over it and was refused; np.linalg.norm overflowed past 1e154 and sent zero.
    for spike in rng.normal(size=(2000, 3)) * 10.0 ** rng.uniform(4, 200, (2000, 1)):
        sent = _saturated(spike)
        assert np.linalg.norm(sent) == pytest.approx(MAX_FORCE)
        assert sent / np.linalg.norm(sent) == pytest.approx(spike / math.hypot(*spike))
        assert decode(encode(OperatorForce(v=VERSION, stamp_ns=0, epoch=0, seq=1, sim_time=0.0,
                                           force=tuple(float(f) for f in sent), position=(0.0, 0.0, 1.0)))).seq == 1
    assert np.array_equal(_saturated(np.array([1.0, -2.0, 3.0])), [1.0, -2.0, 3.0])


def _refuse_in_a_worker(reason: str) -> None:
    raise MessageError(reason, "cloud 'x': a zero normal")


def test_a_message_error_raised_in_a_worker_process_comes_back_as_itself():
    """MessageError(reason, detail) could not be unpickled: a cloud whose normals a worker refused (a zero normal)
    broke the twin's estimation pool, and the good clouds queued behind it were dropped with it."""
    import pickle
    from concurrent.futures import ProcessPoolExecutor

    error = pickle.loads(pickle.dumps(MessageError("zero-normal", "cloud 'x': a zero normal")))
    assert (error.reason, str(error)) == ("zero-normal", "cloud 'x': a zero normal")
    with ProcessPoolExecutor(1) as pool:
        future = pool.submit(_refuse_in_a_worker, "zero-normal")
        with pytest.raises(MessageError, match="a zero normal") as raised:
            future.result()
        assert raised.value.reason == "zero-normal"
        assert pool.submit(abs, -3).result() == 3  # the pool still works
