"""MjSpec model building: the floor, the table, the operator's end effector, and one body per object.

Every object body has a free joint, an explicit inertial (the estimate: MuJoCo must not recompute it
from the hulls, whose union is not the object), a visual mesh that does not collide (group 1), and
its CoACD hulls as colliding meshes (group 3). An object that is nearly a box, capsule or sphere
(:func:`twin.objects.collision_primitive`) collides as that MuJoCo primitive instead; its hulls
stay in group 3 for viewers but collide with nothing. The table is a box, and its top is also a plane
(group 3) that objects wholly over the table collide with instead (:mod:`twin.tabletop`). Each element's
``info`` names the object it came from, so a compile error points back to it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from estimation.contracts import check_number as number
from estimation.contracts import shown
from estimation.errors import MaterialError, SettingsError, UnknownObjectError
from sync.messages import MAX_COORDINATE, MAX_SCENE_SIZE, MIN_SIZE
from twin.objects import MAX_HULL_VERTICES, TwinObject
from twin.settings import check_number, check_type
from twin.tabletop import BOX_BIT, PLANE_BIT, PLANE_NAME

#: Physics step for the haptic loop: 1 kHz.
TIMESTEP = 0.001

#: Visual geoms neither collide nor are collided with.
VISUAL_GROUP, COLLISION_GROUP = 1, 3

#: The contact type of what collides: bit 1 (objects, the end effector, the floor, with each other) and the
#: table box's bit (:mod:`twin.tabletop` swaps it for its top plane's under an object wholly over the table).
COLLIDES = 1 | BOX_BIT

#: Names of the end-effector bodies (the twin's API for operator devices).
EE_TARGET, EE_BODY = "ee_target", "ee"

#: Body names the model gives itself: an object (its body is named by its id) may not take one. MuJoCo
#: refused the second body, and 'twin build' ended in a traceback.
RESERVED_IDS = frozenset({"world", EE_BODY, EE_TARGET})

#: Weld solref of the end effector to its mocap target: stiff (20 ms) but not rigid, so pushing into an
#: object yields a force a haptic device can render instead of an impulse.
EE_WELD_SOLREF = (0.02, 1.0)

#: The most solver iterations :class:`PhysicsSettings` takes: MuJoCo keeps the count in a C int, and 2**31 was
#: a multi-line pybind TypeError in :func:`new_spec`.
MAX_ITERATIONS = 2**31 - 1


@dataclass(frozen=True)
class PhysicsSettings:
    """Solver options of the twin; bench/twin_step.py measures what each costs and buys.

    Attributes:
        timestep: seconds per physics step (1 kHz: the haptic rate).
        sleep: let resting objects sleep (MuJoCo skips them until something touches or moves them).
            Resting clutter is most of a tabletop, so this is the largest speed lever (~5x at 20 objects).
        elliptic: elliptic friction cones (pyramidal ones let resting stacks creep at 1 kHz).
        multiccd: several contact points per convex pair, so a box rests on its face, not a corner.
        iterations: constraint solver iterations (MuJoCo's default 100; resting scenes converge in 1-3).
        table_plane: objects wholly over the table collide with its top as a plane, not its box
            (:mod:`twin.tabletop`; the same contacts at a fraction of the cost).
    """

    timestep: float = TIMESTEP
    sleep: bool = True
    elliptic: bool = True
    multiccd: bool = True
    iterations: int = 100
    table_plane: bool = True

    def __post_init__(self) -> None:
        """Refuse what MuJoCo would take and then run wrongly: a timestep of 0 compiled and ended in a
        ZeroDivisionError in :func:`twin.run_paced`, -0.001 s in a loop of "-1000 Hz"; -5 iterations compiled.

        Raises:
            SettingsError: ``timestep`` not a finite number above 0 (seconds); ``sleep``, ``elliptic``,
                ``multiccd`` or ``table_plane`` not True or False; ``iterations`` not a whole number from 1 to
                :data:`MAX_ITERATIONS`.
        """
        check_number(self, "timestep", low_ok=False)
        for name in ("sleep", "elliptic", "multiccd", "table_plane"):
            check_type(self, name, bool, "True or False")
        check_number(self, "iterations", low=1, whole=True)
        if self.iterations > MAX_ITERATIONS:
            raise SettingsError(f"PhysicsSettings.iterations must be at most {MAX_ITERATIONS} (MuJoCo's C int), "
                                f"got {shown(self.iterations)}")


DEFAULT_PHYSICS = PhysicsSettings()


@dataclass(frozen=True)
class TableSpec:
    """The support: a box of full ``size`` (m) whose top surface is ``height`` m above the floor.

    Sizes and height lie in [:data:`sync.messages.MIN_SIZE`, :data:`sync.messages.MAX_SCENE_SIZE`] metres, as in a
    scene file and on the wire.
    """

    size: tuple[float, float, float] = (1.2, 0.8, 0.04)
    height: float = 0.75
    material: str = "wood_oak"

    def __post_init__(self) -> None:
        """Refuse a table MuJoCo cannot build or would build wrong: a negative size was a multi-line MuJoCo
        compile error, ``size=(1, 1)`` an IndexError in :func:`new_spec`.

        Raises:
            SettingsError: ``size`` not three numbers, or a size or ``height`` not a finite number from
                :data:`sync.messages.MIN_SIZE` to :data:`sync.messages.MAX_SCENE_SIZE` (metres); ``material``
                not a string.
            MaterialError: ``material`` names no material (it sets the table's friction).
        """
        _check_three(self, "size", low=MIN_SIZE, high=MAX_SCENE_SIZE)
        check_number(self, "height", low=MIN_SIZE, high=MAX_SCENE_SIZE)
        check_type(self, "material", str, "a material name")
        from estimation.materials import material

        try:
            material(self.material)
        except MaterialError as exc:
            raise MaterialError(f"TableSpec.material: {exc}") from exc


@dataclass(frozen=True)
class EndEffectorSpec:
    """The operator's sphere: ``radius`` m, starting at ``position`` (world frame, m).

    As in a scene file: the radius lies in [:data:`sync.messages.MIN_SIZE`, :data:`sync.messages.MAX_SCENE_SIZE`]
    metres, each coordinate within :data:`sync.messages.MAX_COORDINATE` of 0.
    """

    radius: float = 0.02
    position: tuple[float, float, float] = (0.0, -0.5, 0.9)

    def __post_init__(self) -> None:
        """Refuse a sphere MuJoCo cannot build or run: a NaN position compiled and stepped NaN; a radius of
        0 or less was a multi-line MuJoCo compile error, 1e300 m stepped to a non-finite state.

        Raises:
            SettingsError: ``radius`` not a finite number from :data:`sync.messages.MIN_SIZE` to
                :data:`sync.messages.MAX_SCENE_SIZE` (metres); ``position`` not three finite numbers within
                :data:`sync.messages.MAX_COORDINATE` (metres).
        """
        check_number(self, "radius", low=MIN_SIZE, high=MAX_SCENE_SIZE)
        _check_three(self, "position", low=-MAX_COORDINATE, high=MAX_COORDINATE)


def _check_three(record: object, name: str, *, low: float, high: float) -> None:
    """Refuse ``record.name`` unless it is a sequence of three finite numbers, each from ``low`` to ``high``.

    Raises:
        SettingsError: not three numbers (a string, a scalar, two values), or one of them NaN, infinite or
            outside the range, named by its index.
    """
    label = f"{type(record).__name__}.{name}"
    value = getattr(record, name)
    vector = (isinstance(value, Sequence) and not isinstance(value, str | bytes)) or (
        isinstance(value, np.ndarray) and value.ndim == 1)
    if not vector or len(value) != 3:
        # An array's repr spans lines: its shape says what was wrong.
        got = f"array of shape {value.shape}" if isinstance(value, np.ndarray) else f"{type(value).__name__} {shown(value)}"
        raise SettingsError(f"{label} must be three numbers (x, y, z), got {got}")
    for i, x in enumerate(value):
        number(x, f"{label}[{i}]", low=low, high=high, error=SettingsError)


#: How far beyond the table (and above its top) an object's pose may be, metres: objects fall off tables and
#: roll across floors, but a pose 10 m from the table is no pose of this scene (a forged or corrupt one).
#: The twin drops what lies outside (``twin.runtime``); a scene file may not place an object there.
SCENE_REACH = 10.0

#: How far beyond the table's edges (and above its top) the operator may send the end effector, metres
#: (without a table: around its start): the twin's default for device targets, the remote's bound for the
#: operator commands it takes (:class:`scenes.remote.Remote`), and where a scene file's end effector may start.
OPERATOR_REACH = 2.0


def reach_corners(table_size: Sequence[float] | None, table_height: float, ee_position: Sequence[float],
                  reach: float) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) corners, metres, world frame, of the box ``reach`` beyond the table's edges (full size x y)
    and above its top (``table_height``), down to the floor; without a table, ``reach`` around
    ``ee_position``, the end effector's start."""
    if table_size is None:
        centre = np.asarray(ee_position, dtype=float)
        return centre - reach, centre + reach
    half = np.array([table_size[0] / 2 + reach, table_size[1] / 2 + reach])
    return np.array([-half[0], -half[1], 0.0]), np.array([half[0], half[1], table_height + reach])


def scene_reach_corners(table: TableSpec | None, end_effector: EndEffectorSpec | None,
                        reach: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`reach_corners` of a scene's table and end effector, read as the remote announces them
    (:class:`sync.messages.SceneInfo`, which :func:`twin.runtime.reach_box` takes): without a table, the box
    around the end effector's start; without an end effector, around the origin. The one place a scene spec
    becomes a box: the operator's reach (a replay's targets) and the scene's (a scene file's objects)."""
    return reach_corners(None if table is None else table.size, 0.0 if table is None else table.height,
                         (0.0, 0.0, 0.0) if end_effector is None else end_effector.position, reach)


def model_reach_corners(model, reach: float) -> tuple[np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
    """:func:`reach_corners` of a compiled scene (:func:`new_spec`'s ``table`` geom and :data:`EE_TARGET` body;
    a built folder's scene.xml), the box :class:`twin.runtime.Local` takes from the remote's announcement."""
    import mujoco

    table = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "table")
    ee = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, EE_TARGET)
    start = model.body_pos[ee] if ee >= 0 else np.zeros(3)
    if table < 0:
        return reach_corners(None, 0.0, start, reach)
    size, pos = model.geom_size[table], model.geom_pos[table]
    return reach_corners(2 * size, float(pos[2] + size[2]), start, reach)


def new_spec(name: str, *, table: TableSpec | None = None, end_effector: EndEffectorSpec | None = None,  # type: ignore[no-untyped-def]
             physics: PhysicsSettings = DEFAULT_PHYSICS):
    """An MjSpec with the floor, the table and the end effector, and no objects.

    Raises:
        TypeError: ``name`` is not a string (MuJoCo's own message spanned lines).
    """
    import mujoco

    if not isinstance(name, str):
        raise TypeError(f"new_spec: name must be a string, got {type(name).__name__}")
    spec = mujoco.MjSpec()
    spec.modelname = name
    spec.option.timestep = physics.timestep
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC if physics.elliptic else mujoco.mjtCone.mjCONE_PYRAMIDAL
    spec.option.iterations = physics.iterations
    if physics.sleep:
        spec.option.enableflags |= mujoco.mjtEnableBit.mjENBL_SLEEP
    if not physics.multiccd:
        spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_MULTICCD
    # A non-finite state would make MuJoCo reset the whole model; Twin.step puts back only the bad object.
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET
    spec.compiler.autolimits = True
    spec.worldbody.add_light(pos=[0, 0, 3], dir=[0, 0, -1], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL)
    floor = spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[5, 5, 0.1],
                                    rgba=[0.8, 0.8, 0.8, 1])
    floor.info = "floor"
    if table is not None:
        t = table
        from estimation.materials import material

        friction = [material(t.material).friction, 0.005, 0.0001]
        # Objects collide with the box through BOX_BIT in their contact type, or, wholly over it, with the
        # plane of its top through PLANE_BIT (twin.tabletop switches them); neither has a contact type.
        top = spec.worldbody.add_geom(name="table", type=mujoco.mjtGeom.mjGEOM_BOX,
                                      size=[t.size[0] / 2, t.size[1] / 2, t.size[2] / 2],
                                      pos=[0, 0, t.height - t.size[2] / 2], rgba=[0.55, 0.4, 0.3, 1],
                                      friction=friction, contype=0, conaffinity=BOX_BIT)
        top.info = "table"
        if physics.table_plane:
            plane = spec.worldbody.add_geom(name=PLANE_NAME, type=mujoco.mjtGeom.mjGEOM_PLANE,
                                            size=[t.size[0] / 2, t.size[1] / 2, 0.1], pos=[0, 0, t.height],
                                            friction=friction, contype=0, conaffinity=PLANE_BIT,
                                            group=COLLISION_GROUP, rgba=[0.55, 0.4, 0.3, 0.3])
            plane.info = "table top (plane)"
    if end_effector is not None:
        add_end_effector(spec, end_effector)
    return spec


def add_end_effector(spec, ee: EndEffectorSpec) -> None:  # type: ignore[no-untyped-def]
    """A sphere welded (softly) to a mocap target; :meth:`twin.sim.Twin.end_effector_force` reads its contacts."""
    import mujoco

    target = spec.worldbody.add_body(name=EE_TARGET, mocap=True, pos=list(ee.position))
    target.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[ee.radius * 0.5, 0, 0], contype=0,
                    conaffinity=0, group=VISUAL_GROUP, rgba=[0.2, 0.8, 0.2, 0.4])
    body = spec.worldbody.add_body(name=EE_BODY, pos=list(ee.position))
    # The operator may hold still for a while; a sleeping end effector would not follow the next move.
    body.sleep = mujoco.mjtSleepPolicy.mjSLEEP_NEVER
    body.add_freejoint()
    geom = body.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[ee.radius, 0, 0], mass=0.2,
                         rgba=[0.2, 0.6, 0.9, 1], contype=COLLIDES)
    geom.info = "end effector"
    weld = spec.add_equality(type=mujoco.mjtEq.mjEQ_WELD, name1=EE_TARGET, name2=EE_BODY,
                             objtype=mujoco.mjtObj.mjOBJ_BODY)
    weld.solref = list(EE_WELD_SOLREF)
    # anchor (3), relative pose: position (3) and quaternion w x y z (4), torque scale. Set explicitly:
    # the spec's default is MJCF's "from the initial pose" sentinel, which the compiled model keeps.
    weld.data = [0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 1] + [0] * (len(weld.data) - 11)
    # The sphere would otherwise sag below its target under gravity; gravity compensation makes the weld
    # carry only contact forces.
    body.gravcomp = 1.0


def add_object(spec, obj: TwinObject, *, rgba: tuple[float, float, float, float] | None = None,  # type: ignore[no-untyped-def]
               primitives: bool = True) -> None:
    """Add one object body (free joint, explicit inertia, visual mesh, collision hulls) to ``spec``.

    With ``primitives`` (the default), an object with a :attr:`~twin.objects.TwinObject.primitive` collides
    as that primitive, named ``<id>/primitive``: MuJoCo's analytic colliders cost a fraction of convex
    mesh pairs (``bench/replay.py``). Inertia is the estimate's either way, not the primitive's. Without
    ``primitives`` its hulls collide: for such an object, its convex hull (:func:`twin.objects.collision_shapes`).
    """
    import mujoco

    m = obj.estimate.mass
    body = spec.worldbody.add_body(name=obj.id, pos=obj.position.tolist(), quat=obj.quat.tolist())
    body.info = f"object {obj.id}"
    body.add_freejoint(name=f"{obj.id}/free")
    body.explicitinertial = True
    body.mass = m.mass
    body.ipos = [0.0, 0.0, 0.0]  # the body frame sits at the estimated centre of mass
    i = m.inertia
    body.fullinertia = [i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]]
    colour = list(rgba) if rgba is not None else list(object_colour(obj.id))
    vis_name = f"{obj.id}/visual"
    mesh = spec.add_mesh(name=vis_name, uservert=obj.visual[0].ravel().tolist(),
                         userface=obj.visual[1].ravel().tolist())
    mesh.info = f"object {obj.id} visual mesh"
    geom = body.add_geom(name=vis_name, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=vis_name, contype=0,
                         conaffinity=0, group=VISUAL_GROUP, rgba=colour, mass=0)
    geom.info = f"object {obj.id} visual"
    friction = [obj.friction, 0.005, 0.0001]
    primitive = obj.primitive if primitives else None
    if primitive is not None:
        g = body.add_geom(name=f"{obj.id}/primitive", type=_geom_types()[primitive.kind], size=list(primitive.size),
                          pos=primitive.position.tolist(), quat=primitive.quat.tolist(), group=COLLISION_GROUP,
                          friction=friction, rgba=hull_colour(0), mass=0, contype=COLLIDES)
        g.info = f"object {obj.id} {primitive.kind} (fill {primitive.fill:.3f})"
    for k, (v, f) in enumerate(obj.hulls):
        name = f"{obj.id}/hull{k}"
        hull = spec.add_mesh(name=name, uservert=v.ravel().tolist(), userface=f.ravel().tolist())
        # MuJoCo's cap, above what the hulls have (twin.objects.collision_shapes): it guards hulls made elsewhere.
        hull.maxhullvert = MAX_HULL_VERTICES
        hull.info = f"object {obj.id} hull {k}"
        # Under a primitive the hulls are only to look at: no contact type, no affinity.
        g = body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=name, group=COLLISION_GROUP,
                          friction=friction, rgba=hull_colour(k), mass=0,
                          contype=0 if primitive is not None else COLLIDES, conaffinity=0 if primitive is not None else 1)
        g.info = f"object {obj.id} hull {k}"


def _geom_types() -> dict[str, object]:
    import mujoco

    return {"box": mujoco.mjtGeom.mjGEOM_BOX, "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
            "capsule": mujoco.mjtGeom.mjGEOM_CAPSULE, "sphere": mujoco.mjtGeom.mjGEOM_SPHERE}


def has_object(spec, object_id: str) -> bool:  # type: ignore[no-untyped-def]
    """Whether ``spec`` holds the object ``object_id`` (a body with the free joint ``<id>/free``; the end effector's
    body, say, is not an object whatever its name)."""
    return spec.joint(f"{object_id}/free") is not None


#: Most object ids an unknown-object message lists: a scene of 500 objects would be a line of thousands of characters.
MAX_LISTED_IDS = 10


def unknown_object(object_id: str, known: Sequence[str]) -> UnknownObjectError:
    """The error for ``object_id`` missing from a model holding the objects ``known``: it names the closest ids
    (a typo), else the ids there are, at most :data:`MAX_LISTED_IDS` of them."""
    import difflib

    close = difflib.get_close_matches(object_id, known, n=3, cutoff=0.6)
    if close:
        hint = f"; did you mean {', '.join(map(repr, close))}?"
    elif known:
        more = f", ... ({len(known)} in all)" if len(known) > MAX_LISTED_IDS else ""
        hint = f"; its objects: {', '.join(known[:MAX_LISTED_IDS])}{more}"
    else:
        hint = "; it has no objects"
    return UnknownObjectError(f"no object {object_id!r} in the model{hint}")


def remove_object(spec, object_id: str) -> None:  # type: ignore[no-untyped-def]
    """Delete an object's body and its meshes from ``spec``.

    Raises:
        UnknownObjectError: ``spec`` has no object ``object_id`` (a KeyError too).
    """
    body = spec.body(object_id)
    if body is None or not has_object(spec, object_id):  # "ee" and "world" are bodies, not objects to delete
        raise unknown_object(object_id, [j.name.removesuffix("/free") for j in spec.joints
                                         if j.name.endswith("/free")])
    prefix = f"{object_id}/"
    meshes = [m for m in spec.meshes if m.name.startswith(prefix)]
    spec.delete(body)
    for m in meshes:
        spec.delete(m)


def object_colour(object_id: str) -> tuple[float, float, float, float]:
    """A colour derived from the id: stable across runs (no unseeded randomness in outputs)."""
    import zlib

    h = zlib.crc32(object_id.encode())
    return (0.3 + 0.6 * ((h & 0xFF) / 255), 0.3 + 0.6 * (((h >> 8) & 0xFF) / 255),
            0.3 + 0.6 * (((h >> 16) & 0xFF) / 255), 1.0)


def hull_colour(k: int) -> list[float]:
    """Distinct colours for hull k (golden-ratio hue steps)."""
    import colorsys

    r, g, b = colorsys.hsv_to_rgb((k * 0.618034) % 1.0, 0.7, 0.95)
    return [r, g, b, 0.5]


def free_joint(model, object_id: str) -> int:  # type: ignore[no-untyped-def]
    """The id of an object's free joint in ``model``, -1 if the model has no such object.

    Objects are the bodies with a free joint named ``<id>/free`` (element info is not saved in XML).
    """
    import mujoco

    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{object_id}/free")


def body_pose(model, data, object_id: str) -> tuple[np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
    """(position (3,), quaternion w x y z (4,)) of an object body, world frame."""
    import mujoco

    bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, object_id)
    if bid < 0:
        raise KeyError(f"no object {object_id!r} in the model")
    return data.xpos[bid].copy(), data.xquat[bid].copy()
