"""A scene's declared [workspace]: from the file, through the remote's SceneInfo, to the twin's scene box."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import msgspec
import numpy as np
import pytest

from scenes.headless import Headless
from scenes.scenefile import SceneError, load_scene, parse_scene
from sync.keys import Keys
from sync.link import Link
from sync.messages import VERSION, MessageError, Pose, SceneInfo, cloud_message, decode, encode

SMALL = Path(__file__).parent / "data" / "small.toml"
#: Around small.toml's table (1.0 x 0.6, top at 0.5 m) and a little beyond: the crate and can start inside.
BOX = ((-0.6, -0.4, 0.0), (0.6, 0.4, 1.0))


def _info(**fields: object) -> SceneInfo:
    return SceneInfo(v=VERSION, stamp_ns=0, name="s", table_size=(1.0, 0.6, 0.04), table_height=0.5,
                     table_material="wood_oak", ee_radius=0.02, ee_position=(0.0, 0.0, 0.6), **fields)


def test_the_file_declares_it():
    scene = parse_scene({"name": "x", "workspace": {"min": list(BOX[0]), "max": list(BOX[1])}})
    assert scene.workspace == BOX
    assert parse_scene({"name": "x"}).workspace is None


@pytest.mark.parametrize(
    ("workspace", "message"),
    [
        ({"min": [0, 0, 0], "max": [1, 0, 1]}, r"^workspace: min must be below max on every axis"),
        ({"min": [0, 0, 0]}, r"^workspace: missing 'max'$"),
        ({"min": [0, 0, 0], "max": [1, 1, float("nan")]}, r"^workspace.max\[2\]: must be finite, got nan$"),
        ({"min": [0, 0], "max": [1, 1, 1]}, r"^workspace.min: expected 3 numbers, got 2$"),
        ({"min": [0, 0, 0], "max": [1, 1, 1], "margin": 1}, r"^workspace: unknown key 'margin'"),
        ([0, 0, 0], r"^workspace: expected a table, got list"),
    ],
)
def test_a_bad_workspace_is_one_scene_error(workspace, message):
    with pytest.raises(SceneError, match=message):
        parse_scene({"name": "x", "workspace": workspace})


def test_scene_info_carries_it_and_an_older_one_still_decodes():
    info = _info(workspace_min=BOX[0], workspace_max=BOX[1])
    assert decode(encode(info)) == info

    class OldSceneInfo(msgspec.Struct, array_like=True, tag_field="t", tag="scene"):
        """SceneInfo as senders before the workspace wrote it."""

        v: int
        stamp_ns: int
        name: str
        table_size: tuple[float, float, float] | None
        table_height: float
        table_material: str
        ee_radius: float
        ee_position: tuple[float, float, float]

    old = OldSceneInfo(VERSION, 0, "s", (1.0, 0.6, 0.04), 0.5, "wood_oak", 0.02, (0.0, 0.0, 0.6))
    assert decode(msgspec.msgpack.encode(old)) == _info()


@pytest.mark.parametrize(
    "fields",
    [
        {"workspace_min": (0.0, 0.0, 0.0), "workspace_max": (1.0, float("inf"), 1.0)},
        {"workspace_min": (0.0, float("nan"), 0.0), "workspace_max": (1.0, 1.0, 1.0)},
        {"workspace_min": (0.0, 0.0, 0.0), "workspace_max": (1.0, 0.0, 1.0)},
        {"workspace_min": (0.0, 0.0, 0.0)},
        {"workspace_min": (0.0, 0.0, 0.0), "workspace_max": (1.0, 1.0, 5e3)},
    ],
)
def test_decode_rejects_a_workspace_no_sender_could_mean(fields):
    with pytest.raises(MessageError) as err:
        decode(encode(_info(**fields)))
    assert err.value.reason in ("non-finite", "bad-size", "out-of-range")


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return tmp_path_factory.getbasetemp() / "coacd"


def _forge(session: Headless, position: tuple[float, float, float], seq: int) -> None:
    remote = session.remote
    pose = Pose(v=VERSION, stamp_ns=0, object_id="crate", epoch=remote.epoch, seq=seq, sim_time=0.0,
                position=position, quat=(1.0, 0.0, 0.0, 0.0), linvel=(0.0,) * 3, angvel=(0.0,) * 3)
    Link(session.bus.transport()).put(Keys("small").object("crate", "pose"), pose)


def test_the_twin_drops_poses_outside_the_declared_workspace_and_applies_those_inside(cache):
    scene = replace(load_scene(SMALL), workspace=BOX)
    with Headless(scene, cache_dir=cache) as session:
        low, high = session.local.scene_box
        np.testing.assert_array_equal(low, BOX[0])
        np.testing.assert_array_equal(high, BOX[1])
        session.run(0.2)
        assert session.local.report.out_of_scene == 0  # the scene's own clouds and poses are inside
        before = session.local.twin.pose("crate")[0]
        # 0.8 m from the table's centre: inside the default box (10 m around the table), outside this one.
        _forge(session, (0.8, 0.0, 0.56), 10**6)
        session.run(0.2)
        assert session.local.report.out_of_scene == 1
        assert np.linalg.norm(session.local.twin.pose("crate")[0] - before) < 0.002
        # Inside it, on the table 8 cm along x: applied (the twin pulls the crate there).
        target = before + np.array([0.08, 0.0, 0.0])
        _forge(session, tuple(target.tolist()), 10**6 + 1)
        session.run(0.2)
        assert session.local.report.out_of_scene == 1
        assert np.linalg.norm(session.local.twin.pose("crate")[0] - before) > 0.04


def test_without_a_declared_workspace_the_default_box_applies(cache):
    with Headless(load_scene(SMALL), cache_dir=cache) as session:
        low, high = session.local.scene_box
        assert low[0] < -10 and high[0] > 10  # SCENE_REACH beyond the table's edges
        session.run(0.2)
        _forge(session, (0.8, 0.0, 0.56), 10**6)
        session.run(0.2)
        assert session.local.report.out_of_scene == 0


def test_a_cloud_placed_inside_whose_points_lie_outside_is_dropped(cache):
    scene = replace(load_scene(SMALL), workspace=BOX)
    with Headless(scene, cache_dir=cache) as session:
        session.run(0.2)
        remote = session.remote
        points = np.random.default_rng(0).normal((2.0, 0.0, 0.6), 0.02, (2000, 3))  # 2 m out, past the box
        msg = cloud_message("stray", points, stamp_ns=0, epoch=remote.epoch, seq=10**6, material="abs_plastic",
                            density=None, frame_position=np.array([0.0, 0.0, 0.6]), frame_quat=np.array([1.0, 0, 0, 0]))
        Link(session.bus.transport()).put(Keys("small").object("stray", "cloud"), msg)
        session.run(0.2)
        assert session.local.report.out_of_scene == 1
        assert "stray" not in session.local.objects and "stray" not in session.local.pending


@pytest.mark.parametrize(("table", "position", "ok"), [
    ({"size": [1.0, 0.6, 0.04], "height": 0.75}, [5.4, 0.0], True),       # 10 m beyond the table's edge: in
    ({"size": [1.0, 0.6, 0.04], "height": 0.75}, [999.0, 999.0], False),
    ({"size": [1.0, 0.6, 0.04], "height": 0.75}, [0.0, -10.4], False),
    (None, [9.0, 0.0], True),                                              # no table: 10 m round the hand
    (None, [0.0, 12.0], False),
])
def test_without_a_declared_workspace_an_object_outside_the_default_box_is_refused(table, position, ok):
    """The twin drops poses and clouds outside the default box: such an object was built, then never shown."""
    doc = {"name": "x", "objects": [{"id": "a", "paper": "box", "position": position}]}
    if table is not None:
        doc["table"] = table
    if ok:
        assert parse_scene(doc).objects[0].id == "a"
    else:
        with pytest.raises(SceneError, match=r"^object 'a': position .* lies outside the workspace"):
            parse_scene(doc)


@pytest.mark.parametrize("doc", [
    {"name": "x", "table": {"size": [1.0, 0.6, 0.04], "height": 0.75}, "end_effector": {"position": [0.1, -0.4, 0.9]}},
    {"name": "x", "end_effector": {"position": [0.3, 0.2, 0.4]}},  # no table: around the end effector
])
def test_a_scene_specs_boxes_are_the_ones_the_twin_takes_from_the_remotes_announcement(doc):
    """The operator's reach (a replay's targets) and the scene's box (a scene file's objects) come from the scene
    spec (twin.model.scene_reach_corners, once copied in cli/record.py and scenes/scenefile.py); the twin computes
    them from the SceneInfo the remote announces (twin.runtime.reach_box). They must be one box."""
    from types import SimpleNamespace

    from scenes.remote import Remote
    from sync.clock import SimClock
    from twin.model import OPERATOR_REACH, SCENE_REACH, scene_reach_corners
    from twin.runtime import reach_box

    scene = parse_scene(doc)
    for spec in (scene, replace(scene, end_effector=None)):  # a spec built in code may have none: the origin
        info = Remote._scene_info(SimpleNamespace(scene=spec, clock=SimClock()))  # type: ignore[arg-type]
        for reach in (OPERATOR_REACH, SCENE_REACH):
            for mine, twins in zip(scene_reach_corners(spec.table, spec.end_effector, reach), reach_box(info, reach),
                                   strict=True):
                np.testing.assert_array_equal(mine, twins)


def _tight(size_z: float, **extra: object) -> dict:
    """A small table in a declared box whose top is 10 cm above the table: a box of height ``size_z`` on it."""
    return {"name": "tight", "table": {"size": [1.0, 0.6, 0.04], "height": 0.5},
            "end_effector": {"radius": 0.02, "position": [-0.3, 0.0, 0.56]},
            "workspace": {"min": [-0.8, -0.6, 0.0], "max": [0.8, 0.6, 0.6]},
            "objects": [{"id": "tall", "primitive": {"type": "box", "size": [0.05, 0.05, size_z]}, "position": [0.1, 0.0]}],
            **extra}


def test_an_object_whose_surface_reaches_out_of_the_declared_box_is_refused_when_the_remote_builds_it(cache):
    # Its position is inside, so the loader takes it; its top is 8 cm above the box. The twin dropped its cloud,
    # and `twin demo` waited ten minutes for it; now the remote refuses the scene in one line.
    from scenes.remote import Remote
    from sync.clock import SimClock
    from sync.inprocess import InProcessBus

    clock = SimClock()
    scene = parse_scene(_tight(0.18))
    with pytest.raises(SceneError, match=r"^scene 'tight': object 'tall' reaches from .* out of the workspace"):
        Remote(scene, InProcessBus(clock).transport("remote"), clock=clock, cache_dir=cache)
    remote = Remote(parse_scene(_tight(0.08)), InProcessBus(clock).transport("remote"), clock=clock, cache_dir=cache)
    remote.close()  # 8 cm tall: inside


def test_a_scene_mujoco_cannot_compile_is_one_scene_error_from_the_remote(cache):
    # A 1 mm sphere at 0.1 kg/m^3: both in range, but MuJoCo finds no inertia it accepts. `twin build` said so in
    # one line; the remote (twin remote, demo, experiment, replay --scene) raised MuJoCo's ValueError.
    from scenes.remote import Remote
    from sync.clock import SimClock
    from sync.inprocess import InProcessBus

    doc = _tight(0.08)
    doc["objects"] = [{"id": "dust", "primitive": {"type": "sphere", "size": [0.001]}, "density": 0.1,
                       "position": [0.1, 0.0]}]
    clock = SimClock()
    with pytest.raises(SceneError, match=r"^scene 'tight': MuJoCo could not compile it: .*inertia.*dust"):
        Remote(parse_scene(doc), InProcessBus(clock).transport("remote"), clock=clock, cache_dir=cache)


@pytest.mark.parametrize(("end_effector", "message"), [
    # The wire carries radii up to 1 m: a 1.5 m one was loaded, and every twin dropped the scene's announcement.
    ({"radius": 1.5}, r"^end_effector.radius: must be 0.001 to 1 m .*got 1.5$"),
    # Outside the operator's reach the remote drops every command: an experiment ran, all blown up, exit 0.
    ({"position": [0.0, -8.0, 9.0]}, r"^end_effector.position \[0.0, -8.0, 9.0\] lies outside the operator's reach"),
])
def test_an_end_effector_the_remote_could_not_use_is_refused_when_loaded(end_effector, message):
    doc = _tight(0.08)
    doc["end_effector"] = end_effector
    with pytest.raises(SceneError, match=message):
        parse_scene(doc)
    # At the limits: taken.
    doc["end_effector"] = {"radius": 1.0, "position": [2.5, 2.3, 2.5]}
    assert parse_scene(doc).end_effector.radius == 1.0
