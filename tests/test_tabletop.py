"""The table's top as a plane (twin.tabletop): objects wholly over the table collide with it as with the box,
and nothing else does: an object that slides off the edge falls, one under the table stays under it.

Real MuJoCo models with exact meshes (a box collides as its primitive; a cylinder, which no primitive fits,
as its convex hull).
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest
import trimesh

from estimation import from_mesh
from twin.model import PhysicsSettings, TableSpec, add_object, new_spec
from twin.objects import object_at_estimate
from twin.sim import Twin
from twin.tabletop import BOX_BIT, PLANE_BIT

TABLE = TableSpec(size=(0.6, 0.4, 0.04), height=0.75)
TOP = TABLE.height


def _object(tmp_path, name: str, mesh: trimesh.Trimesh, position) -> object:  # type: ignore[no-untyped-def]
    est = from_mesh(np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64), 700.0)
    obj = object_at_estimate(name, est, 0.5, cache_dir=tmp_path)
    return dataclasses.replace(obj, position=np.asarray(position, float), quat=np.array([1.0, 0, 0, 0]))


def _twin(objects, *, plane: bool = True, sleep: bool = False) -> Twin:  # type: ignore[no-untyped-def]
    spec = new_spec("t", table=TABLE, physics=PhysicsSettings(table_plane=plane, sleep=sleep))
    for obj in objects:
        add_object(spec, obj)
    return Twin(spec)


def _contype(twin: Twin, name: str) -> set[int]:
    body = twin.model.body(name).id
    geoms = [g for g in np.flatnonzero(twin.model.geom_bodyid == body) if twin.model.geom_contype[g] != 0]
    return {int(twin.model.geom_contype[g]) & (BOX_BIT | PLANE_BIT) for g in geoms}


@pytest.fixture(scope="module")
def shapes(tmp_path_factory):  # type: ignore[no-untyped-def]
    cache = tmp_path_factory.mktemp("coacd")
    box = trimesh.creation.box(extents=(0.08, 0.06, 0.04))
    can = trimesh.creation.cylinder(radius=0.03, height=0.1, sections=32)
    return cache, box, can


@pytest.mark.parametrize("kind", ["box", "can"])
def test_an_object_over_the_table_rests_on_the_plane_as_on_the_box(shapes, kind):
    cache, box, can = shapes
    mesh = box if kind == "box" else can
    z = TOP + float(-mesh.bounds[0][2]) + 0.002
    rest = {}
    for plane in (True, False):
        with _twin([_object(cache, "a", mesh, (0.05, -0.03, z))], plane=plane) as twin:
            twin.step(500)
            rest[plane] = twin.pose("a")[0]
            if plane:
                assert _contype(twin, "a") == {PLANE_BIT}
            else:
                assert _contype(twin, "a") == {BOX_BIT}
    # Same height on either; both on the table's top (the box's bottom face 1-2 mm into it: soft contacts).
    np.testing.assert_allclose(rest[True], rest[False], atol=2e-4)
    assert abs(rest[True][2] + float(mesh.bounds[0][2]) - TOP) < 2e-3


def test_an_object_sliding_off_the_edge_falls_and_one_at_the_edge_collides_with_the_box(shapes):
    cache, box, _ = shapes
    z = TOP + 0.02 + 0.001
    sliding = _object(cache, "sliding", box, (0.2, 0.0, z))
    edge = _object(cache, "edge", box, (0.0, 0.19, z))  # its outline over the long edge
    with _twin([sliding, edge]) as twin:
        twin.step(50)
        assert _contype(twin, "edge") == {BOX_BIT}
        assert _contype(twin, "sliding") == {PLANE_BIT}
        twin.set_velocity("sliding", np.array([1.5, 0.0, 0.0]), np.zeros(3))
        twin.step(600)
        # Off the table (x beyond 0.3 m) and falling: a plane would have held it at the table's height.
        position = twin.pose("sliding")[0]
        assert position[0] > 0.35 and position[2] < TOP - 0.1, position
        assert _contype(twin, "sliding") == {BOX_BIT}
        # The one at the edge rests on the box's top, as on the plane.
        assert abs(twin.pose("edge")[0][2] - 0.02 - TOP) < 2e-3


def test_an_object_under_the_table_stays_under_it(shapes):
    cache, box, _ = shapes
    # On the floor below the table's middle: its outline is inside the top's, but it is not above it.
    with _twin([_object(cache, "under", box, (0.0, 0.0, 0.021))]) as twin:
        twin.step(300)
        assert _contype(twin, "under") == {BOX_BIT}
        assert twin.pose("under")[0][2] < 0.05


def test_a_geom_out_of_every_collision_stays_out(shapes):
    cache, box, _ = shapes
    with _twin([_object(cache, "a", box, (0.0, 0.0, TOP + 0.021)), _object(cache, "b", box, (0.1, 0.0, TOP + 0.021))]) as twin:
        twin.step(20)
        geoms = np.flatnonzero(twin.model.geom_bodyid == twin.model.body("b").id)
        twin.model.geom_contype[geoms] = 0  # as scenes.remote.Remote._refuse takes an object out
        twin.model.geom_conaffinity[geoms] = 0
        twin.set_pose("a", np.array([-0.1, 0.0, TOP + 0.021]), np.array([1.0, 0, 0, 0]))  # a decision at once
        twin.step(200)
        assert (twin.model.geom_contype[geoms] == 0).all()
        # It falls through the table (0.2 m in 0.2 s): nothing holds it.
        assert twin.pose("b")[0][2] < TOP - 0.1


def test_plain_mj_step_collides_with_the_box_only(shapes):
    """A model stepped without Twin.step (a viewer, a script) never meets the plane: every object starts on
    the box."""
    cache, box, _ = shapes
    with _twin([_object(cache, "a", box, (0.0, 0.0, TOP + 0.021))]) as twin:
        m, d = twin.model, mujoco.MjData(twin.model)
        mujoco.mj_step(m, d, 200)
        plane = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "table/top")
        table = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "table")
        touched = {int(g) for g in d.contact.geom[:d.ncon].ravel()}
        assert table in touched and plane not in touched


def test_sleeping_objects_keep_their_plane(shapes):
    cache, box, _ = shapes
    with _twin([_object(cache, "a", box, (0.0, 0.0, TOP + 0.021))], sleep=True) as twin:
        twin.step(2000)
        assert not twin.data.body_awake[twin.model.body("a").id]
        assert _contype(twin, "a") == {PLANE_BIT}
        z = twin.pose("a")[0][2]
        twin.step(500)
        assert twin.pose("a")[0][2] == z


def test_a_plane_with_a_table_and_none_without_or_when_turned_off():
    def plane(spec) -> int:  # type: ignore[no-untyped-def]
        return mujoco.mj_name2id(spec.compile(), mujoco.mjtObj.mjOBJ_GEOM, "table/top")

    assert plane(new_spec("t", table=TABLE)) >= 0
    assert plane(new_spec("t")) < 0
    assert plane(new_spec("t", table=TABLE, physics=PhysicsSettings(table_plane=False))) < 0


def test_an_object_teleported_off_the_table_leaves_the_plane_at_once(shapes):
    """A write that carries an object under the table (a snapped correction, Remote.move) must not leave it on
    the top's plane until the next decision: the plane has no depth limit and would launch it up through the
    table."""
    cache, box, _ = shapes
    with _twin([_object(cache, "a", box, (0.0, 0.0, TOP + 0.021))]) as twin:
        twin.step(20)
        assert _contype(twin, "a") == {PLANE_BIT}
        twin.set_pose("a", np.array([0.0, 0.0, 0.021]), np.array([1.0, 0, 0, 0]))  # on the floor, under the table
        assert _contype(twin, "a") == {BOX_BIT}
        assert not {int(g) for g in twin.data.contact.geom[:twin.data.ncon].ravel()} & {twin.model.geom("table/top").id}
        twin.step(100)
        assert twin.pose("a")[0][2] < 0.05


def test_a_sleeping_object_set_moving_is_decided_at_the_next_step(shapes):
    cache, box, _ = shapes
    with _twin([_object(cache, "a", box, (0.2, 0.0, TOP + 0.021))], sleep=True) as twin:
        twin.step(2000)
        assert not twin.data.body_awake[twin.model.body("a").id] and _contype(twin, "a") == {PLANE_BIT}
        # 5 m/s towards the edge 0.1 m away: its outline would pass it before the next decision.
        twin.set_velocity("a", np.array([5.0, 0.0, 0.0]), np.zeros(3))
        twin.step()
        assert _contype(twin, "a") == {BOX_BIT}


def test_a_model_another_twin_stepped_starts_on_the_box(shapes):
    cache, box, _ = shapes
    spec = new_spec("t", table=TABLE, physics=PhysicsSettings(sleep=False))
    add_object(spec, _object(cache, "a", box, (0.0, 0.0, TOP + 0.021)))
    model = spec.compile()
    with Twin(spec, model) as first:
        first.step(20)
        assert _contype(first, "a") == {PLANE_BIT}
    with Twin(spec, model) as second:
        second.step(0)
        assert _contype(second, "a") == {BOX_BIT}


def test_a_plane_that_is_not_the_boxs_top_is_not_used(shapes):
    cache, box, _ = shapes
    with _twin([_object(cache, "a", box, (0.0, 0.0, TOP + 0.021))]) as twin:
        twin.model.geom_pos[twin.model.geom("table/top").id][2] += 0.05  # as a hand-edited scene.xml might
        twin.step(20)
        assert _contype(twin, "a") == {BOX_BIT}
        assert abs(twin.pose("a")[0][2] - 0.02 - TOP) < 2e-3
