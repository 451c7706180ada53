"""Objects a scene file places inside each other, the table, the floor or the end effector are refused before
anything runs them (the remote, ``twin build`` and ``twin run``)."""

from __future__ import annotations

from pathlib import Path

import pytest

from cli.main import main
from scenes.build import build_scene
from scenes.headless import Headless
from scenes.placement import OVERLAP_DEPTH, SUPPORT_DEPTH
from scenes.scenefile import SceneError, parse_scene

TABLE = {"size": [1.0, 0.6, 0.04], "height": 0.5}
CRATE = {"id": "crate", "primitive": {"type": "box", "size": [0.12, 0.08, 0.06]}, "material": "wood_pine"}
CAN = {"id": "can", "primitive": {"type": "cylinder", "size": [0.03, 0.1]}, "density": 700}


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return tmp_path_factory.getbasetemp() / "coacd"


def _scene(can_at: list[float]):  # type: ignore[no-untyped-def]
    return parse_scene({"name": "placed", "table": TABLE, "objects": [{**CRATE, "position": [0.0, 0.0]},
                                                                      {**CAN, "position": can_at}]})


@pytest.mark.parametrize(("can_at", "depth_mm"), [([0.05, 0.01], 40.0), ([0.0, 0.0], 60.0)])
def test_objects_placed_inside_each_other_are_one_scene_error_naming_both(cache, can_at, depth_mm):
    # Before, the remote stepped them apart and went on with another scene: this can came to rest on the crate.
    with pytest.raises(SceneError, match=rf"^placed: objects placed inside each other or the scene: 'can' and 'crate' by "
                                         rf"{depth_mm:.1f} mm; move them apart"):
        Headless(_scene(can_at), cache_dir=cache)


def test_objects_that_touch_or_stack_are_accepted(cache):
    # Side by side with a hair between them, and the can standing on the crate (its top at 0.56 m, the can's
    # centre half its 0.1 m height above that): in contact or close, not inside each other.
    beside = 0.06 + 0.03 + 0.2 * OVERLAP_DEPTH
    for can_at in ([beside, 0.0], [0.0, 0.0, 0.5 + 0.06 + 0.05]):
        with Headless(_scene(can_at), cache_dir=cache) as session:
            assert sorted(session.remote._objects) == ["can", "crate"]


def test_the_cli_says_it_in_one_line_and_exits_2(tmp_path, capsys):
    scene = tmp_path / "overlap.toml"
    scene.write_text('name = "overlap"\n[table]\nsize = [1.0, 0.6, 0.04]\nheight = 0.5\n'
                     '[[objects]]\nid = "crate"\nprimitive = { type = "box", size = [0.12, 0.08, 0.06] }\n'
                     'material = "wood_pine"\nposition = [0.0, 0.0]\n'
                     '[[objects]]\nid = "can"\nprimitive = { type = "cylinder", size = [0.03, 0.1] }\n'
                     'density = 700\nposition = [0.0, 0.0]\n')
    assert main(["remote", str(scene), "--duration", "0.1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("twin remote: error: overlap: objects placed inside each other or the scene: 'can' and "
                              "'crate'")


def _alone(position: list[float], **scene):  # type: ignore[no-untyped-def]
    return parse_scene({"name": "placed", "table": TABLE, **scene, "objects": [{**CRATE, "position": position}]})


@pytest.mark.parametrize(("z", "what", "depth_mm"), [
    (0.5 + 0.03 - 0.02, "the table", 20.0),  # its bottom 2 cm into the table top: MuJoCo lifts it out
    (0.47, "the table", 40.0),  # across the whole 4 cm slab: MuJoCo pushed it down through, onto the floor
    (0.01, "the floor", 20.0),
])
def test_an_object_inside_the_table_or_the_floor_is_refused(cache, z, what, depth_mm):
    with pytest.raises(SceneError, match=rf"^placed: objects placed inside each other or the scene: 'crate' and "
                                         rf"{what} by {depth_mm:.1f} mm"):
        build_scene(_alone([0.0, 0.0, z]), cache_dir=cache, progress=False, workers=1)


def test_an_object_round_the_end_effector_is_refused_by_the_remote(cache):
    scene = _alone([-0.3, 0.0], end_effector={"radius": 0.02, "position": [-0.3, 0.0, 0.52]})
    with pytest.raises(SceneError, match=r"'crate' and the end effector \(starting at -0\.300, 0\.000, 0\.520 m\) by "):
        Headless(scene, cache_dir=cache)


def test_the_default_end_effector_is_named_with_where_it_starts(cache):
    # A scene without [end_effector] still has one: the message says where, since the file never placed it.
    from twin.model import EndEffectorSpec

    x, y, z = EndEffectorSpec().position
    with pytest.raises(SceneError, match=rf"'crate' and the end effector \(starting at {x:.3f}, {y:.3f}, {z:.3f} m\)"):
        build_scene(_alone([x, y, z]), cache_dir=cache, progress=False, workers=1)


def test_an_object_sunk_within_the_support_slack_is_accepted(cache):
    # A scan placed by its own frame rests within the sensor's noise of the table it stood on.
    sunk = 0.5 + 0.03 - 0.5 * SUPPORT_DEPTH
    built = build_scene(_alone([0.0, 0.0, sunk]), cache_dir=cache, progress=False, workers=1)
    assert [o.id for o in built.objects] == ["crate"]


def test_the_scenes_parts_are_told_from_objects_by_body_not_by_name(cache):
    # An object may be called 'table': the crate 5 mm into the table top is within the support slack, and the
    # object named 'table' is no part of the scene's table.
    other = {"id": "table", "primitive": {"type": "box", "size": [0.05, 0.05, 0.05]}, "density": 500,
             "position": [0.3, 0.0]}
    scene = parse_scene({"name": "placed", "table": TABLE,
                         "objects": [{**CRATE, "position": [0.0, 0.0, 0.5 + 0.03 - 0.005]}, other]})
    built = build_scene(scene, cache_dir=cache, progress=False, workers=1)
    assert sorted(o.id for o in built.objects) == ["crate", "table"]


def test_scans_placed_by_their_frame_are_held_to_the_support_slack():
    # Two boxes 5 mm into each other: objects overlap, but two scans as noisy as their sensor may touch so.
    import mujoco

    from scenes.placement import overlaps

    spec = mujoco.MjSpec()
    for name, x in (("a", 0.0), ("b", 0.095)):
        body = spec.worldbody.add_body(name=name, pos=[x, 0.0, 1.0])
        body.add_freejoint()
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.05, 0.05, 0.05])
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    found = overlaps(model, data, {"a", "b"})
    assert [(o.first, o.second, round(1000 * o.depth, 1)) for o in found] == [("a", "b", 5.0)]
    assert overlaps(model, data, {"a", "b"}, scanned={"b"}) == []


def test_a_built_folder_edited_into_an_overlap_is_refused_by_run(tmp_path, capsys, monkeypatch, cache):
    import re

    monkeypatch.setenv("TWIN_CACHE_DIR", str(cache))
    scene = tmp_path / "one.toml"
    scene.write_text('name = "one"\n[table]\nsize = [1.0, 0.6, 0.04]\nheight = 0.5\n'
                     '[[objects]]\nid = "crate"\nprimitive = { type = "box", size = [0.12, 0.08, 0.06] }\n'
                     'material = "wood_pine"\nposition = [0.0, 0.0]\n')
    out = tmp_path / "built"
    assert main(["build", str(scene), "--out", str(out)]) == 0
    assert main(["run", str(out), "--duration", "0.01", "--no-realtime"]) == 0
    xml = out / "scene.xml"
    # The crate's body moved 3 cm down, into the table top, by hand.
    text = xml.read_text()
    edited = re.sub(r'(<body name="crate" pos="[^ ]+ [^ ]+ )([^"]+)"', lambda m: f'{m[1]}{float(m[2]) - 0.03}"', text)
    assert edited != text
    xml.write_text(edited)
    capsys.readouterr()
    assert main(["run", str(out), "--duration", "0.01", "--no-realtime"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert re.match(r"twin run: error: .*built: objects placed inside each other or the scene: 'crate' and the table "
                    r"by \d+\.\d mm", err[-1]), err[-1]


def test_an_object_added_at_run_time_inside_another_is_refused_and_nothing_is_pushed(cache):
    import numpy as np

    from scenes.scenefile import ObjectSpec

    with Headless(_scene([0.2, 0.1]), cache_dir=cache) as session:
        session.run(0.05)
        remote = session.remote
        before = remote.twin.pose("crate")[0].copy()
        ball = ObjectSpec(id="ball", source="primitive", value={"type": "sphere", "size": [0.03]}, material="rubber",
                          position=(0.0, 0.0, 0.53), points=3000)  # at the crate's centre
        added = _ticked(session, remote.add(ball))
        with pytest.raises(SceneError, match=r"^placed: 'ball' added at run time: objects placed inside each other or "
                                             r"the scene: 'ball' and 'crate' by "):
            added.result(timeout=0)
        session.run(0.5)
        assert not remote.twin.has("ball") and "ball" not in session.local.objects
        assert np.linalg.norm(remote.twin.pose("crate")[0] - before) < 1e-3  # the crate was not pushed
        # Beside the crate it is taken.
        beside = ObjectSpec(**{**ball.__dict__, "position": (-0.2, -0.15)})
        assert _ticked(session, remote.add(beside)).result(timeout=0) == "ball"


def _ticked(session, future):  # type: ignore[no-untyped-def]
    """``future`` once the headless session has stepped until it is done (the remote adds objects in its step)."""
    for _ in range(20_000):
        if future.done():
            return future
        session.tick()
    raise AssertionError("the remote did not finish adding the object in 20 s of simulated time")


def test_a_move_into_another_object_is_refused_and_leaves_both_where_they_were(cache):
    import numpy as np

    with Headless(_scene([0.2, 0.1]), cache_dir=cache) as session:
        session.run(0.2)
        remote = session.remote
        crate, can = remote.twin.pose("crate"), remote.twin.pose("can")
        into = _ticked(session, remote.move("crate", can[0], crate[1]))  # the crate's centre at the can's
        with pytest.raises(SceneError, match=r"^placed: 'crate' moved at run time: objects placed inside each other "
                                             r"or the scene: 'can' and 'crate' by "):
            into.result(timeout=0)
        session.run(0.3)
        assert np.linalg.norm(remote.twin.pose("crate")[0] - crate[0]) < 1e-3
        assert np.linalg.norm(remote.twin.pose("can")[0] - can[0]) < 1e-3  # nothing was pushed apart
        assert np.linalg.norm(session.local.twin.pose("crate")[0] - crate[0]) < 5e-3
        # Nor into the table; beside it, 10 cm along x, the move is made.
        down = crate[0] - np.array([0.0, 0.0, 0.03])
        with pytest.raises(SceneError, match=r"'crate' and the table by "):
            _ticked(session, remote.move("crate", down, crate[1])).result(timeout=0)
        aside = crate[0] + np.array([-0.1, 0.0, 0.0])
        assert _ticked(session, remote.move("crate", aside, crate[1])).result(timeout=0) == "crate"
        with pytest.raises(SceneError, match=r"cannot move 'mug': no such object"):
            _ticked(session, remote.move("mug", aside, crate[1])).result(timeout=0)
        # A pose no scene holds is the caller's error, told through the Future; the loop that ran it runs on.
        with pytest.raises(SceneError, match=r"cannot move 'crate': object 'crate': position must be 3 finite"):
            _ticked(session, remote.move("crate", np.array([np.nan, 0.0, 0.0]), crate[1])).result(timeout=0)
        with pytest.raises(SceneError, match=r"cannot move 'crate': .*non-zero quaternion"):
            _ticked(session, remote.move("crate", aside, np.zeros(4))).result(timeout=0)
        session.run(0.3)
        assert np.linalg.norm(remote.twin.pose("crate")[0][:2] - aside[:2]) < 2e-3
