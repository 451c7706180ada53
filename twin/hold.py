"""Holding still what the remote says is still.

The remote publishes an object's pose whenever it leaves the deadband, so silence is information: with
no newer message, C's object is still (within the deadband) where the last one put it. The twin's object
may disagree on its own: its shape is an estimate, and a pose at rest on the true shape (the paper's
stack on an edge) need not be at rest on the estimated one. Left alone it falls, and is snapped back
only at the next keyframe.

So an object the operator has not disturbed for a while, and that C reports at rest, is *pinned*: once
it strays past a threshold from C's pose, it is drawn back to it and held there with zero velocity. The
operator disturbs an object by touching it with the end effector or through a chain of touching objects
(:func:`twin.contacts.contact_component`); a disturbed object is released at once and left to the twin's
physics, so a push never feels sticky.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from twin.contacts import contact_component, geom_roots
from twin.model import EE_BODY, free_joint
from twin.poses import blend
from twin.settings import check_number, check_type


@dataclass(frozen=True)
class HoldSettings:
    """When the twin pins an object to the remote's pose.

    Attributes:
        enabled: pin at all.
        distance, angle_deg: how far (metres, degrees) an object strays from C's pose before it is pinned.
        after: seconds (twin time) since the operator last disturbed an object before it may be pinned.
        rest_speed, rest_spin: C's object counts as at rest when its last pose was slower than this
            (m/s, rad/s), or when no pose came for ``quiet`` seconds (it would have left the deadband).
        check_every: seconds (twin time) between two looks at contacts and strays; pinned objects are held
            at every step in between. Each look is some 30 numpy calls (about 0.1 ms for 20 objects on the
            CI machine), too many for every 1 ms step; an end effector's contact lasts longer than 5 ms.
    """

    enabled: bool = True
    distance: float = 0.005
    angle_deg: float = 5.0
    after: float = 0.5
    rest_speed: float = 0.01
    rest_spin: float = 0.1
    quiet: float = 0.1
    check_every: float = 0.005

    def __post_init__(self) -> None:
        """Refuse what the hold cannot mean: NaN compares false, so a NaN threshold pinned nothing without a word.

        Raises:
            SettingsError: ``enabled`` not a bool; a distance, speed or time negative, NaN or infinite; an angle
                outside [0, 180]; ``check_every`` not in (0, :data:`MAX_CHECK_EVERY`].
        """
        check_type(self, "enabled", bool, "True or False")
        # Any finite size or time means something (a large one: never pinned, or pinned at once): no upper bound.
        for name in ("distance", "after", "rest_speed", "rest_spin", "quiet"):
            check_number(self, name)
        check_number(self, "angle_deg", high=180.0)  # two orientations are at most 180 degrees apart
        # 0 looked at every step but never pulled a pinned object back (each look's share of tau was 0).
        check_number(self, "check_every", low_ok=False, high=MAX_CHECK_EVERY)


#: The longest ``check_every``, seconds: a push lasts a fraction of a second, and looks further apart than this
#: miss whole pushes, so the hold would pin an object the operator is moving.
MAX_CHECK_EVERY = 1.0

DEFAULT_HOLD = HoldSettings()

#: A pinned object this close to C's pose (metres, degrees) counts as held: below what an operator sees.
HELD = (0.0005, 0.5)


@dataclass(frozen=True)
class _Target:
    position: np.ndarray  # C's pose mapped onto the twin's body, world frame
    quat: np.ndarray
    moving: bool  # C's last pose was faster than the rest thresholds
    since: float  # twin time it arrived


class _Arrays:
    """The targets of the objects in one model, as arrays: what :meth:`Hold.apply` reads every step."""

    def __init__(self, model, targets: dict[str, _Target], touched: dict[str, float],  # type: ignore[no-untyped-def]
                 pinned: set[str]) -> None:
        import mujoco

        self.model = model
        found = {i: free_joint(model, i) for i in targets}
        self.ids = [i for i, j in found.items() if j >= 0]
        joints = [found[i] for i in self.ids]
        self.body = np.array([model.jnt_bodyid[j] for j in joints], dtype=int)
        q = np.array([model.jnt_qposadr[j] for j in joints], dtype=int)
        d = np.array([model.jnt_dofadr[j] for j in joints], dtype=int)
        self.qpos, self.qvel = q[:, None] + np.arange(7), d[:, None] + np.arange(6)  # (n, 7), (n, 6) indices
        self.want_p = np.array([targets[i].position for i in self.ids]).reshape(-1, 3)
        self.want_q = np.array([targets[i].quat for i in self.ids]).reshape(-1, 4)
        self.moving = np.array([targets[i].moving for i in self.ids], dtype=bool)
        self.since = np.array([targets[i].since for i in self.ids], dtype=float)
        self.touched = np.array([touched.get(i, -np.inf) for i in self.ids], dtype=float)
        self.pinned = np.array([i in pinned for i in self.ids], dtype=bool)
        # qpos indices, their values, qvel indices: what is held between two looks
        self.hold_at: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        ee = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, EE_BODY)
        self.ee_root = np.array([model.body_rootid[ee]] if ee >= 0 else [], dtype=int)
        self.geom_root = geom_roots(model)


class Hold:
    """Pins undisturbed objects to where the remote last reported them at rest. Call :meth:`apply` each step."""

    def __init__(self, settings: HoldSettings = DEFAULT_HOLD, tau: float = 0.02) -> None:
        self.settings = settings
        self.tau = tau  # time constant of the pull back to C's pose, seconds
        self.pins = 0  # times an object was pinned
        self._targets: dict[str, _Target] = {}
        self._arrays: _Arrays | None = None  # rebuilt when the targets or the model change
        self._next_look = -np.inf

    @property
    def pinned(self) -> set[str]:
        """Objects held at C's pose now."""
        a = self._arrays
        return set() if a is None else {i for i, p in zip(a.ids, a.pinned, strict=True) if p}

    def target(self, object_id: str, position: np.ndarray, quat: np.ndarray, linvel, angvel,  # type: ignore[no-untyped-def]
               now: float) -> None:
        """C's latest pose of an object, mapped onto the twin's body (world frame), and its velocity."""
        s = self.settings
        moving = float(np.linalg.norm(linvel)) > s.rest_speed or float(np.linalg.norm(angvel)) > s.rest_spin
        t = self._targets[object_id] = _Target(np.asarray(position, float), np.asarray(quat, float), moving, now)
        a = self._arrays
        if a is not None and object_id in a.ids:  # every pose passes here: update in place
            k = a.ids.index(object_id)
            a.want_p[k], a.want_q[k], a.moving[k], a.since[k] = t.position, t.quat, t.moving, t.since
        else:
            self._rebuild_with(None)

    def disturbed(self, now: float) -> set[str]:
        """Objects the operator touched (directly or through touching objects) less than ``after`` s ago.

        As of the last look (``check_every``); empty when the hold is off.
        """
        a = self._arrays
        if not self.settings.enabled or a is None:
            return set()
        return {i for i, t in zip(a.ids, a.touched, strict=True) if now - t < self.settings.after}

    def holds(self, object_id: str) -> bool:
        """Whether a target of ``object_id`` is held here (what :meth:`forget` drops)."""
        return object_id in self._targets

    def forget(self, object_id: str) -> None:
        if self._targets.pop(object_id, None) is not None:  # a flood of Gones for unknown ids costs nothing here
            self._rebuild_with(None)

    def apply(self, twin) -> list[str]:  # type: ignore[no-untyped-def]
        """Release what the operator disturbs, pin what strays, hold what is pinned. Returns the newly pinned.

        Vectorised over objects. Between two looks (``check_every``) it only re-applies what it holds.
        """
        if not self.settings.enabled or not self._targets:
            return []
        a = self._arrays
        if a is None or a.model is not twin.model:
            a = self._rebuild_with(twin.model)
        if not a.ids:
            return []
        s, now, data = self.settings, twin.time, twin.data
        if now < self._next_look:
            if a.hold_at is not None:
                qpos_idx, values, qvel_idx = a.hold_at
                data.qpos[qpos_idx] = values
                data.qvel[qvel_idx] = 0.0
            return []
        self._next_look = now + s.check_every - 1e-9
        vel = data.qvel[a.qvel]
        # What the operator moved still disturbs what it hits while it moves; at rest, touching, it does not
        # (or two resting neighbours would keep each other disturbed for ever).
        stirring = (now - a.touched < s.after) & ((_sq(vel[:, :3]) > s.rest_speed ** 2) |
                                                  (_sq(vel[:, 3:]) > s.rest_spin ** 2))
        seeds = np.concatenate([a.body[stirring], a.ee_root])
        a.touched[contact_component(twin.model, data, seeds, a.geom_root)[a.body]] = now
        eligible = (now - a.touched >= s.after) & (~a.moving | (now - a.since > s.quiet))
        a.pinned &= eligible
        a.hold_at = None
        if not eligible.any():
            return []
        qpos = data.qpos[a.qpos]
        pos, quat = qpos[:, :3], qpos[:, 3:]
        gap, cos_half = _sq(a.want_p - pos), np.abs(np.einsum("ij,ij->i", a.want_q, quat))  # cos(angle / 2)
        strays = (gap > s.distance ** 2) | (cos_half < np.cos(np.radians(s.angle_deg) / 2))
        newly = eligible & strays & ~a.pinned
        a.pinned |= newly
        self.pins += int(newly.sum())
        # A pinned object within HELD of C's pose is left alone until the next look, so MuJoCo can put it
        # to sleep if it rests there (writing qpos every step would keep it awake and cost every step).
        off = (gap > HELD[0] ** 2) | (cos_half < np.cos(np.radians(HELD[1]) / 2))
        k = np.flatnonzero(a.pinned & off)
        if len(k):
            # Drawn back over tau, one look's worth at a time, and held there until the next look.
            alpha = 1.0 - float(np.exp(-s.check_every / self.tau))
            held = np.concatenate(blend(pos[k], quat[k], a.want_p[k], a.want_q[k], alpha), axis=1)
            a.hold_at = (a.qpos[k].ravel(), held.ravel(), a.qvel[k].ravel())
            data.qpos[a.hold_at[0]] = a.hold_at[1]
            data.qvel[a.hold_at[2]] = 0.0
            twin.moved(a.body[k])  # drawn by a share of its stray: maybe off the table's edge
        return [a.ids[j] for j in np.flatnonzero(newly)]

    def _rebuild_with(self, model) -> _Arrays | None:  # type: ignore[no-untyped-def]
        """New arrays for ``model`` (None: the current one, if any), keeping touch times and pins."""
        old = self._arrays
        if old is None and model is None:
            return None
        touched = {} if old is None else dict(zip(old.ids, old.touched, strict=True))
        pinned = self.pinned
        self._arrays = _Arrays(old.model if model is None else model, self._targets, touched, pinned)
        return self._arrays


def _sq(v: np.ndarray) -> np.ndarray:
    """Squared norms of the rows (cheaper than np.linalg.norm at a few objects, compared to squared limits)."""
    return np.einsum("ij,ij->i", v, v)
