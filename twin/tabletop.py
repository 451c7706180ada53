"""The table's top as a half-space for the objects wholly over it: MuJoCo's plane collider in place of its box.

MuJoCo collides a mesh or a primitive with a box through its general convex routine (GJK/EPA), and with a
plane through a dedicated one that reads a few support vertices. On clutter20 with every body awake, the
objects' contacts with the table box were most of the narrow phase; with the table's top as a plane the same
states collide in 19 us instead of 50 (a /tmp timing of session 45; docs/twin.md). A plane is infinite, so it
may stand in for the box only where the two agree: for an object whose every colliding geom lies, wherever it
turns, inside the top's outline (less a margin for its travel until the next decision) and whose centre of
mass is above the top. Such an object can touch the box only on its top face, which is the plane there.
Every other object (straddling an edge, beside or under the table, falling off it) collides with the box.

Which of the two an object collides with is a contact-type bit of its colliding geoms (:data:`BOX_BIT` or
:data:`PLANE_BIT`; the table box and the plane have matching affinities and no contact type of their own),
switched by :meth:`TopPlane.switch` when :class:`twin.sim.Twin` decides, every :data:`CHECK_EVERY` steps.
An object whose pose is written rather than stepped goes back to the box at once (:meth:`twin.sim.Twin.moved`).
A model as compiled has every object on the box, so stepped by plain ``mj_step`` it collides as without
the plane; a Twin that steps a model switches its bits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The contact-type bit of a geom that collides with the table box, and of one that collides with its top
#: plane instead. Bit 1 (MuJoCo's default) is everything else: objects, the end effector, the floor.
BOX_BIT, PLANE_BIT = 2, 4

#: The plane geom's name: the table box's, with the face it stands for.
PLANE_NAME = "table/top"

#: Steps a decision holds: deciding costs some 5-10 us of numpy, a clutter step with every body awake ~100 us.
CHECK_EVERY = 10

#: Metres an object's outline keeps from the top's edges, on top of its travel at its current speed until
#: the next decision: what an impact may add to that travel (1 m/s gained within :data:`CHECK_EVERY` steps).
EDGE_MARGIN = 0.01


@dataclass(frozen=True)
class TopPlane:
    """What :meth:`switch` needs of one compiled model, read once by :func:`top_plane`.

    Attributes:
        bodies: object body ids (free bodies other than the end effector), shape (n,).
        reach: each body's outline radius about its frame origin, metres: the farthest its colliding geoms reach.
        coords: each body's free joint's first coordinate (its position, world frame, is ``qpos[c:c + 3]``:
            current even after a write that did not run ``mj_forward``); ``dofs``: its first dof (its linear
            velocity, world axes, is ``qvel[dof:dof + 3]``).
        geoms: every colliding geom of those bodies, and ``owner[k]``: the index into ``bodies`` of ``geoms[k]``.
        centre: the top's centre (x, y), metres, world frame; ``half``: its half extents along x and y.
        height: the top's z, metres.
    """

    bodies: np.ndarray
    reach: np.ndarray
    coords: np.ndarray
    dofs: np.ndarray
    geoms: np.ndarray
    owner: np.ndarray
    centre: np.ndarray
    half: np.ndarray
    height: float

    def over(self, qpos: np.ndarray, qvel: np.ndarray, timestep: float) -> np.ndarray:
        """(n,) bool: which bodies may collide with the plane for the next :data:`CHECK_EVERY` steps
        (``qpos``, ``qvel``: the model's coordinates and velocities; ``timestep``: seconds)."""
        p = qpos[self.coords[:, None] + np.arange(3)]
        v = qvel[self.dofs[:, None] + np.arange(3)]
        travel = (CHECK_EVERY + 1) * timestep * np.sqrt((v * v).sum(axis=1))
        room = self.half - (self.reach + EDGE_MARGIN + travel)[:, None]
        return (np.abs(p[:, :2] - self.centre) <= room).all(axis=1) & (p[:, 2] >= self.height)

    def switch(self, model, over: np.ndarray) -> None:  # type: ignore[no-untyped-def]
        """Set each body's colliding geoms to the plane (``over``) or the box. A geom whose contact type is 0
        (taken out of every collision, as the remote takes out an object it refuses) stays 0."""
        types = model.geom_contype[self.geoms]
        bit = np.where(over[self.owner], PLANE_BIT, BOX_BIT)
        model.geom_contype[self.geoms] = np.where(types != 0, (types & ~(BOX_BIT | PLANE_BIT)) | bit, 0)


def top_plane(model, exclude: int = -1) -> TopPlane | None:  # type: ignore[no-untyped-def]
    """The :class:`TopPlane` of a model built by :func:`twin.model.new_spec` with its table's top plane, or None
    (no plane geom, or a table turned out of the world's axes). ``exclude``: a free body that never switches
    (the end effector: it touches the table by its own cheap sphere-box routine)."""
    import mujoco

    plane = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, PLANE_NAME)
    table = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "table")
    if plane < 0 or table < 0:
        return None
    top = model.geom_pos[table] + np.array([0.0, 0.0, model.geom_size[table][2]])
    # Only a plane that is the box's top face stands in for it (a hand-edited build folder may have moved one).
    if (model.geom_bodyid[plane] != 0 or model.geom_bodyid[table] != 0
            or not np.allclose(model.geom_quat[table], [1, 0, 0, 0]) or not np.allclose(model.geom_quat[plane], [1, 0, 0, 0])
            or not np.allclose(model.geom_pos[plane], top, rtol=0.0, atol=1e-9)):
        return None
    joints = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    bodies, coords, dofs, reach, geoms, owner = [], [], [], [], [], []
    for j in joints:
        body = int(model.jnt_bodyid[j])
        if body == exclude:
            continue
        mine = [g for g in range(model.body_geomadr[body], model.body_geomadr[body] + model.body_geomnum[body])
                if model.geom_contype[g] != 0 or model.geom_conaffinity[g] != 0]
        if not mine:
            continue
        owner += [len(bodies)] * len(mine)
        geoms += mine
        reach.append(max(float(np.linalg.norm(model.geom_pos[g])) + float(model.geom_rbound[g]) for g in mine))
        bodies.append(body)
        coords.append(int(model.jnt_qposadr[j]))
        dofs.append(int(model.jnt_dofadr[j]))
    half = np.asarray(model.geom_size[table][:2], float)
    return TopPlane(np.asarray(bodies, int), np.asarray(reach), np.asarray(coords, int), np.asarray(dofs, int),
                    np.asarray(geoms, int), np.asarray(owner, int), np.asarray(top[:2], float), half, float(top[2]))
