"""The running twin: a MuJoCo model and its state, and live edits that never take it down."""

from __future__ import annotations

import logging
import math
import numbers
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from estimation.errors import SettingsError, TwinError
from sync.clock import REAL_CLOCK, Clock
from sync.messages import MAX_ANGULAR_SPEED, MAX_COORDINATE, MAX_SPEED
from twin.debuglog import OFF, DebugLog
from twin.loop import LoopStats, run_loop, steps_per_iteration
from twin.model import EE_BODY, EE_TARGET, add_object, free_joint, remove_object, unknown_object
from twin.objects import TwinObject
from twin.tabletop import CHECK_EVERY, TopPlane, top_plane
from twin.trajectory import Trajectory

log = logging.getLogger(__name__)


#: Fastest the end effector's mocap target moves, m/s: a target further than this allows is approached at this
#: speed, step by step. Human hand motion on a haptic device peaks near 1-2 m/s, and collaborative robots are held
#: to about that (ISO/TS 15066 speeds of 1-2 m/s); a script that jumped 0.6 m in a microsecond pulled the soft
#: weld's sphere through the scene at ~30 m/s and flung a crate 0.29 m.
EE_MAX_SPEED = 2.0


class TwinClosedError(TwinError, RuntimeError):
    """A closed :class:`Twin` was asked to step or change."""


class ModelMismatchError(TwinError, ValueError):
    """A :class:`Twin` was given a model not compiled from its spec."""


class DivergedError(TwinError, RuntimeError):
    """A ``strict`` :class:`Twin`'s state became NaN, infinite or huge: the model is not one that simulates."""


#: Largest coordinate or velocity MuJoCo's own check takes as a working state (``mjMAXVAL``, m or m/s): past it,
#: it warns "Nan, Inf or huge value ... The simulation is unstable". A body 1e29 m below the floor is not a result.
MAX_STATE = 1e10
_MAX_SQUARED = MAX_STATE * MAX_STATE


def _good(*values: np.ndarray) -> bool:
    """Whether every value is within :data:`MAX_STATE` (NaN fails the comparison, infinity the bound)."""
    for v in values:
        # A sum of squares within MAX_STATE**2 bounds every entry, in one dot product: the 1 kHz path runs
        # this twice a step (2.5 us of numpy for the two arrays of a 20-object twin, 1.1 us this way). Only
        # past it (or NaN) is each entry looked at.
        if not v @ v <= _MAX_SQUARED and not np.abs(v).max(initial=0.0) <= MAX_STATE:
            return False
    return True


def _check_compiled_from(spec, model) -> None:  # type: ignore[no-untyped-def]
    """Refuse a ``model`` whose bodies are not ``spec``'s, in order, by name: another scene's model ran with no
    objects (``object_ids()`` was empty) and the spec's next edit would have swapped the scene. A few
    microseconds (names only, no compile); a model compiled from ``spec`` always passes.

    Raises:
        ModelMismatchError: naming the first body that differs, or the two counts.
    """
    bodies = spec.bodies
    if len(bodies) != model.nbody:
        raise ModelMismatchError(f"Twin: the model's body count is {model.nbody}, its spec's {len(bodies)}: pass the "
                                 f"model compiled from this spec (or None)")
    # Read from the model's name buffer: a third faster than model.body(i).name (75 against 105 us at 100 bodies).
    names = model.names
    for i, (body, start) in enumerate(zip(bodies, model.name_bodyadr.tolist(), strict=True)):
        name = names[start:names.index(b"\0", start)].decode(errors="replace")
        if body.name != name:
            raise ModelMismatchError(f"Twin: model's body {i} is {name!r}, its spec's {body.name!r}: pass the model "
                                     f"compiled from this spec (or None)")


class Twin:
    """The local simulation C'. The caller owns the loop: ``step()`` advances one physics step.

    Use as a context manager. Live edits (:meth:`add`, :meth:`remove`, :meth:`replace`,
    :meth:`edit_async`) change a copy of the spec and compile it; only a model that compiled is swapped
    in, carrying every body's state over. An edit that fails (a bad hull, a name clash) is logged and
    counted in :attr:`failed_edits`, and the twin runs on with the model and spec it had.

    ``background``: compile asynchronous edits in a thread while the loop steps the old model (live
    runs); without it they compile in the caller's thread, so a headless run is deterministic.

    Not thread-safe: MuJoCo releases the GIL inside ``mj_step``, so a ``set_pose`` (``mj_forward``) from a
    second thread runs on the same ``mjData`` at the same time and corrupts it (a segfault in practice).
    One thread steps and edits a twin; others hand it work (:meth:`edit_async`, or a queue drained by the
    loop as :class:`scenes.remote.Remote` and :class:`twin.runtime.Local` do).

    After :meth:`close`, stepping, editing and the setters raise :class:`TwinClosedError`; reading (poses,
    time) still works, and closing again does nothing.
    """

    def __init__(self, spec, model=None, *, background: bool = True,  # type: ignore[no-untyped-def]
                 strict: bool = False) -> None:
        """
        Args:
            spec: the scene's ``mujoco.MjSpec``; later edits copy it.
            model: ``spec`` compiled (None: compiled here). The twin steps it and switches its objects'
                contact bits between the table's box and its top plane (:mod:`twin.tabletop`).
            background: compile :meth:`edit_async` edits in a thread (see the class).
            strict: a state gone bad raises :class:`DivergedError` from :meth:`step` instead of being put back
                and counted: for a run that checks a model (``twin run``), where a divergence is the answer,
                not a glitch for a live twin to ride out.

        Raises:
            TypeError: ``spec`` not an ``MjSpec``, or ``model`` neither None nor an ``MjModel``.
            ModelMismatchError: ``model``'s bodies are not ``spec``'s (another scene's model).
        """
        import mujoco

        # Checked here: None was an AttributeError ('compile'), a wrong model a multi-line pybind TypeError.
        if not isinstance(spec, mujoco.MjSpec):
            raise TypeError(f"Twin: spec must be a mujoco.MjSpec, got {type(spec).__name__}")
        if model is not None and not isinstance(model, mujoco.MjModel):
            raise TypeError(f"Twin: model must be a mujoco.MjModel or None, got {type(model).__name__}")
        if model is not None:
            _check_compiled_from(spec, model)
        self._closed = False
        self.spec = spec
        self.model = model if model is not None else spec.compile()
        self.data = mujoco.MjData(self.model)
        mujoco.mj_forward(self.model, self.data)
        self.background = background
        self.failed_edits = 0
        self.strict = strict
        self.recovered = 0  # objects put back after their state became non-finite
        self._good: tuple[np.ndarray, np.ndarray] | None = None  # last finite (qpos, qvel)
        self._mocap = self._mocap_id()
        self._editor: ThreadPoolExecutor | None = None
        self._head = spec  # the spec the next edit starts from: the last one that compiled, pending included
        self._pending: deque[tuple[Future, Callable[[], None] | None, Callable[[Exception], None] | None]] = deque()
        self._ids_of, self._ids = None, []  # object_ids() of this model
        self._index_of, self._index = None, {}  # joint() look-ups of this model
        self._top_of, self._top, self._over = None, None, None  # twin.tabletop of this model, its switches
        self._top_wait, self._top_forced = 0, True  # steps until the next twin.tabletop decision; decide even asleep
        self._ee_max_speed = EE_MAX_SPEED
        self._ee_goal: np.ndarray | None = None  # where the mocap target is headed, further than one step moves it

    def __enter__(self) -> Twin:
        self._check_open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop the background compiler (pending edits are dropped); from now on the twin only reads. Idempotent."""
        self._closed = True
        if self._editor is not None:
            self._editor.shutdown(wait=True, cancel_futures=True)
            self._editor = None
        self._pending.clear()

    @property
    def closed(self) -> bool:
        return self._closed

    def _check_open(self) -> None:
        """Raises: TwinClosedError: :meth:`close` was called."""
        if self._closed:
            raise TwinClosedError("twin is closed")

    @property
    def time(self) -> float:
        return float(self.data.time)

    def step(self, n: int = 1) -> None:
        """Advance ``n`` physics steps; an object whose state became NaN, infinite or huge is put back.

        MuJoCo's own answer to a bad state (NaN, infinite, or past :data:`MAX_STATE`) is to reset the whole
        model (its auto-reset, which the twin's models disable): every object would jump to its start. Here
        only the objects with bad values return to their last good pose, at rest, and are counted in
        :attr:`recovered` and logged; a ``strict`` twin puts them back and raises instead.

        Raises:
            ValueError: ``n`` is not a whole number >= 0 (0 steps nothing).
            TwinClosedError: the twin is closed.
            DivergedError: a ``strict`` twin's state went bad, naming the time and the objects.
        """
        import mujoco

        if self._closed:  # the 1 kHz path: one attribute test, not a call
            raise TwinClosedError("twin is closed")
        # bool is an int to Python, and mj_step takes -1 or 2.5 without a word and steps nothing. A plain int
        # is asked about first: this is the 1 kHz path.
        if (type(n) is not int and (not isinstance(n, numbers.Integral) or isinstance(n, bool))) or not 0 <= n <= MAX_STEPS:
            raise SettingsError(f"step count n must be a whole number from 0 to {MAX_STEPS}, got {str(n)[:40]}")
        d = self.data
        if not self._finite():  # a bad write since the last step: catch it before the solver spreads it
            self._recover()
        if self._top_of is not self.model:
            self._top_of, self._top = self.model, top_plane(self.model, exclude=self._ee_body())
            self._over = None if self._top is None else np.zeros(len(self._top.bodies), bool)
            if self._top is not None:  # a model another Twin stepped may hold plane bits: every object on the box
                self._top.switch(self.model, self._over)
            self._decide_next_step()
        top = self._top
        if top is None and self._ee_goal is None:
            mujoco.mj_step(self.model, d, n)
        else:
            for k in range(n):
                if self._ee_goal is not None:
                    self._approach_goal()
                elif top is None:  # the goal reached: the rest in one call, as without one
                    mujoco.mj_step(self.model, d, n - k)
                    break
                if top is not None:
                    self._switch_top(top)
                mujoco.mj_step(self.model, d)
        if not self._finite():  # the step itself blew up: put back what it touched
            self._recover()
        elif self._good is None:
            self._good = (d.qpos.copy(), d.qvel.copy())
        else:
            self._good[0][:] = d.qpos
            self._good[1][:] = d.qvel

    def _switch_top(self, top: TopPlane) -> None:
        """Objects wholly over the table collide with its top plane (:mod:`twin.tabletop`), decided every
        :data:`~twin.tabletop.CHECK_EVERY` steps and at the step after :meth:`set_pose` or
        :meth:`set_velocity`. A sleeping object does not move: nothing to decide while every object sleeps."""
        self._top_wait -= 1
        if self._top_wait > 0:
            return
        self._top_wait = CHECK_EVERY
        d = self.data
        # A body a write woke wakes only in the next mj_step: a forced decision does not wait for it.
        if not self._top_forced and not d.body_awake[top.bodies].any():
            return
        self._top_forced = False
        over = top.over(d.qpos, d.qvel, self.model.opt.timestep)
        if not np.array_equal(over, self._over):
            top.switch(self.model, over)
            self._over = over

    def _decide_next_step(self) -> None:
        """The next step decides which objects are over the table (:mod:`twin.tabletop`), asleep or not."""
        self._top_wait, self._top_forced = 0, True

    def moved(self, bodies: Sequence[int] | np.ndarray) -> None:
        """Say that ``bodies`` (body ids) were moved by a write to ``data.qpos``, not by a step: each goes back
        to colliding with the table's box at once, and the next step decides again (:mod:`twin.tabletop`).

        A write can carry an object off the table (a snapped correction, a hold); left on the top's plane, it
        would meet that plane wherever it landed, under the table too, until the next decision.
        :meth:`set_pose` calls it itself.
        """
        self._decide_next_step()
        top, over = self._top, self._over
        if top is None or over is None or self._top_of is not self.model:
            return
        off = over & np.isin(top.bodies, np.asarray(bodies, int))
        if off.any():
            self._over = over & ~off
            top.switch(self.model, self._over)

    def _ee_body(self) -> int:
        import mujoco

        return mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, EE_BODY)

    def _finite(self) -> bool:
        """Whether the state is finite and within :data:`MAX_STATE` (NaN fails the comparison too)."""
        return _good(self.data.qpos, self.data.qvel)

    def _recover(self) -> None:
        """Put every free body with a bad coordinate (:meth:`_finite`) back where it last was good, at rest.

        Raises:
            DivergedError: the twin is ``strict``; the state is put back first.
        """
        import mujoco

        m, d = self.model, self.data
        good_q, _ = self._good if self._good is not None else (m.qpos0, None)
        bad = []
        for j in range(m.njnt):
            if m.jnt_type[j] != mujoco.mjtJoint.mjJNT_FREE:
                continue
            q, v = m.jnt_qposadr[j], m.jnt_dofadr[j]
            if _good(d.qpos[q:q + 7], d.qvel[v:v + 6]):
                continue
            d.qpos[q:q + 7] = good_q[q:q + 7]
            d.qvel[v:v + 6] = 0.0
            self.moved([int(m.jnt_bodyid[j])])
            bad.append((mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint {j}").removesuffix("/free"))
        rest = ~(np.abs(d.qvel) <= MAX_STATE)  # anything else (not a free body): stop it
        d.qvel[rest] = 0.0
        d.qacc_warmstart[:] = 0.0
        self.recovered += len(bad)
        mujoco.mj_forward(m, d)
        where = ", ".join(bad) or "the model"
        if self.strict:
            raise DivergedError(f"the simulation diverged at t={d.time:.4g} s (a NaN, infinite or huge state in "
                                f"{where}): check the model's options, masses and positions")
        log.error("non-finite or huge state in %s; put back to the last good pose", where)

    @property
    def has_end_effector(self) -> bool:
        return self._mocap is not None

    def set_end_effector(self, position: np.ndarray) -> None:
        """Move the operator's mocap target (world frame, metres): at once when one step at :attr:`ee_max_speed`
        reaches it, else at that speed over the next steps (:attr:`end_effector_goal`), as a robot's speed limit
        would: a jump of the operator's target pulls the end effector through the scene no faster.

        Raises:
            LookupError: the scene has no end effector. ValueError: not 3 finite numbers within
                :data:`sync.messages.MAX_COORDINATE` of the origin. TwinClosedError: the twin is closed.
        """
        self._check_open()
        if self._mocap is None:
            raise LookupError("this scene has no end effector")
        goal = _vector(position, 3, MAX_COORDINATE, "end-effector target", "m")
        here = self.data.mocap_pos[self._mocap]
        # Not "further than a step" (NaN compares false): a target written non-finite is put right at once.
        if not math.dist(goal.tolist(), here.tolist()) > self._ee_max_speed * self.model.opt.timestep:
            here[:] = goal
            self._ee_goal = None
        else:  # approached at ee_max_speed, a step at a time (step())
            self._ee_goal = goal

    @property
    def ee_max_speed(self) -> float:
        """Fastest the end effector's target moves, m/s (:data:`EE_MAX_SPEED`; inf: it jumps to each target)."""
        return self._ee_max_speed

    @ee_max_speed.setter
    def ee_max_speed(self, speed: float) -> None:
        """Raises: SettingsError: not a number above 0 (NaN froze the target at NaN for good, 0 froze it, a
        negative speed drove it away from its goal)."""
        if isinstance(speed, bool) or not isinstance(speed, numbers.Real) or not speed > 0:
            raise SettingsError(f"ee_max_speed must be a number of m/s above 0, got {str(speed)[:40]}")
        try:
            self._ee_max_speed = float(speed)
        except OverflowError:  # an int past the float range
            self._ee_max_speed = math.inf

    @property
    def end_effector_goal(self) -> np.ndarray:
        """Where the end effector's target is headed (world, metres): the last :meth:`set_end_effector`, which the
        target reaches at :attr:`ee_max_speed` (it is there already when this equals ``data.mocap_pos``).

        Raises:
            LookupError: the scene has no end effector.
        """
        if self._mocap is None:
            raise LookupError("this scene has no end effector")
        return (self.data.mocap_pos[self._mocap] if self._ee_goal is None else self._ee_goal).copy()

    def _approach_goal(self) -> None:
        """Move the mocap target one step's worth of :attr:`ee_max_speed` towards :attr:`_ee_goal`."""
        here = self.data.mocap_pos[self._mocap]
        gap = self._ee_goal - here
        distance, most = float(np.linalg.norm(gap)), self._ee_max_speed * self.model.opt.timestep
        if not distance > most:  # NaN too: a target written non-finite meanwhile goes to its goal
            here[:] = self._ee_goal
            self._ee_goal = None
        else:
            here += gap * (most / distance)

    def end_effector_force(self) -> np.ndarray:
        """Net contact force the scene exerts on the end effector, world axes, newtons, (3,).

        The sum over the sphere's contacts: what a haptic device should render (zero in free space). A
        force sensor at the sphere would also read its own weight, which gravity compensation cancels
        in the dynamics but not in the sensor (a constant 1.96 N at rest).
        """
        import mujoco

        if self._mocap is None:
            raise LookupError("this scene has no end effector")
        m, d = self.model, self.data
        ee = self._ee_body()
        total, f6 = np.zeros(3), np.zeros(6)
        for i in range(d.ncon):
            c = d.contact[i]
            b1, b2 = m.geom_bodyid[c.geom1], m.geom_bodyid[c.geom2]
            if ee not in (b1, b2) or c.efc_address < 0:
                continue
            mujoco.mj_contactForce(m, d, i, f6)
            force = c.frame.reshape(3, 3).T @ f6[:3]  # contact frame -> world; acts on geom2, from geom1
            total += force if b2 == ee else -force
        return total

    def pose(self, object_id: str) -> tuple[np.ndarray, np.ndarray]:
        """(position, quaternion w x y z) of an object's centre of mass, world frame.

        Raises:
            TypeError: ``object_id`` is not a string. UnknownObjectError: no such object (:meth:`joint`).
        """
        body, _, _ = self.joint(object_id)
        return self.data.xpos[body].copy(), self.data.xquat[body].copy()

    def joint(self, object_id: str) -> tuple[int, int, int]:
        """(body id, qpos address, dof address) of an object's free joint in the running model.

        Looked up by name once per model: a name look-up costs more than the arithmetic every caller does
        with it, and the loops ask for every object at every step.

        Raises:
            TypeError: ``object_id`` is not a string (None was "no object None", a list an unhashable-type error).
            UnknownObjectError: no such object in the model (a KeyError too); the message names the closest
                ids or the ones there are.
        """
        if self._index_of is not self.model:
            self._index, self._index_of = {}, self.model
        found = self._index.get(_checked_id(object_id))
        if found is None:
            jid = free_joint(self.model, object_id)
            if jid < 0:
                raise unknown_object(object_id, self.object_ids())
            m = self.model
            found = self._index[object_id] = (int(m.jnt_bodyid[jid]), int(m.jnt_qposadr[jid]), int(m.jnt_dofadr[jid]))
        return found

    def object_ids(self) -> list[str]:
        """The objects in the running model (not in a spec edit still compiling)."""
        if self._ids_of is not self.model:
            # Objects are the bodies with a free joint named "<id>/free" (twin.model.free_joint).
            import mujoco

            m = self.model
            names = (mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) or "" for j in range(m.njnt))
            self._ids = [n.removesuffix("/free") for n in names if n.endswith("/free")]
            self._ids_of = self.model
        return list(self._ids)

    def add(self, obj: TwinObject) -> None:
        """Add an object without disturbing the others.

        Raises:
            TypeError: ``obj`` is not a :class:`~twin.objects.TwinObject`.
            ValueError: MuJoCo refused the edited model (the twin is unchanged).
        """
        _check_object(obj, "add")
        self.edit(lambda spec: add_object(spec, obj))

    def remove(self, object_id: str) -> None:
        """Remove an object.

        Raises:
            TypeError: ``object_id`` is not a string. UnknownObjectError: no such object (the twin is unchanged).
        """
        if not isinstance(object_id, str):  # MuJoCo's own message spanned lines ("incompatible function arguments")
            raise TypeError(f"Twin.remove takes an object id (str), got {type(object_id).__name__}")
        self.edit(lambda spec: remove_object(spec, object_id))

    def replace(self, obj: TwinObject) -> None:
        """Swap an object's geometry and inertia, keeping its current pose and velocity."""
        _check_object(obj, "replace")
        pos, quat = self.pose(obj.id)

        def swap(spec) -> None:  # type: ignore[no-untyped-def]
            remove_object(spec, obj.id)
            add_object(spec, obj)

        self.edit(swap)
        self.set_pose(obj.id, pos, quat)

    def edit(self, edit: Callable[[object], None]) -> None:
        """Apply ``edit(spec)`` and swap the compiled model in now. Do not call while edits are pending.

        Raises:
            TwinClosedError: the twin is closed.
            whatever ``edit`` or the compiler raised; the twin keeps its model and spec.
        """
        self._check_open()
        spec, model = self._compile_edit(edit)
        self.spec = spec
        self._swap(model)

    def edit_async(self, edit: Callable[[object], None], then: Callable[[], None] | None = None,
                   failed: Callable[[Exception], None] | None = None) -> Future:
        """Apply ``edit(spec)`` to a copy of the spec and compile it, off the loop when ``background``.

        :meth:`poll`, called from the loop, swaps the new model in between two steps, carrying over every
        body's state as it is at that moment; ``then()`` runs right after the swap (e.g. to set a pose).
        If the edit or the compile fails, nothing is swapped, ``failed(exc)`` is called from :meth:`poll`,
        and later edits start from the last spec that compiled. Edits apply in submission order.

        Raises:
            TwinClosedError: the twin is closed (a new compile thread would outlive it).
        """
        self._check_open()
        if not self.background:
            future: Future = Future()
            try:
                future.set_result(self._compile_edit(edit))
            except Exception as exc:
                future.set_exception(exc)
        else:
            if self._editor is None:
                self._editor = ThreadPoolExecutor(1, thread_name_prefix="twin-compile")
            future = self._editor.submit(self._compile_edit, edit)
        self._pending.append((future, then, failed))
        return future

    @property
    def edits_pending(self) -> int:
        return len(self._pending)

    def poll(self) -> int:
        """Swap in every finished edit (in order); returns how many were applied.

        A failed edit is logged, counted in :attr:`failed_edits` and reported to its ``failed`` callback.
        """
        applied = 0
        while self._pending and self._pending[0][0].done():
            future, then, failed = self._pending.popleft()
            try:
                spec, model = future.result()
            except Exception as exc:
                self.failed_edits += 1
                log.error("a live edit of the twin failed; keeping the model it had: %s", exc)
                if failed is not None:
                    failed(exc)
                continue
            self.spec = spec
            self._swap(model)
            if then is not None:
                then()
            applied += 1
        return applied

    def _compile_edit(self, edit: Callable[[object], None]):  # type: ignore[no-untyped-def]
        """(spec, model) of ``edit`` applied to a copy of the newest good spec; that spec is left as it was."""
        spec = self._head.copy()
        edit(spec)
        model = spec.compile()
        self._head = spec
        return spec, model

    def _swap(self, model) -> None:  # type: ignore[no-untyped-def]
        import mujoco

        data = mujoco.MjData(model)
        data.time = self.data.time
        self._good = None  # indices change with the model; the next finite step records it again
        _copy_free_bodies(self.model, self.data, model, data)
        old_mocap = self.data.mocap_pos.copy()
        self.model, self.data = model, data
        self._mocap = self._mocap_id()
        if self._mocap is None:
            self._ee_goal = None
        if self._mocap is not None and len(old_mocap) == len(data.mocap_pos):
            data.mocap_pos[:] = old_mocap
        mujoco.mj_forward(model, data)

    def velocity(self, object_id: str) -> tuple[np.ndarray, np.ndarray]:
        """(linear m/s, angular rad/s) of an object's free joint, both in world axes.

        Raises:
            TypeError: ``object_id`` is not a string. UnknownObjectError: no such object (:meth:`joint`).
        """
        adr, xmat = self._dof(object_id)
        return self.data.qvel[adr:adr + 3].copy(), xmat @ self.data.qvel[adr + 3:adr + 6]

    def set_velocity(self, object_id: str, linear: np.ndarray, angular: np.ndarray) -> None:
        """Set an object's free-joint velocity (linear m/s and angular rad/s, both in world axes).

        Raises:
            TypeError: ``object_id`` is not a string. UnknownObjectError: no such object (a KeyError too).
            ValueError: ``linear`` or ``angular`` not 3 finite numbers, or faster
                than :data:`sync.messages.MAX_SPEED` m/s or :data:`~sync.messages.MAX_ANGULAR_SPEED` rad/s
                (what the wire takes: 1e300 m/s went into MuJoCo's state and blew the step up).
            TwinClosedError: the twin is closed.
        """
        self._check_open()
        adr, xmat = self._dof(object_id)
        what = f"object {object_id!r}: "
        linear = _vector(linear, 3, MAX_SPEED, what + "linear velocity", "m/s", norm=True)
        angular = _vector(angular, 3, MAX_ANGULAR_SPEED, what + "angular velocity", "rad/s", norm=True)
        self.data.qvel[adr:adr + 3] = linear
        self.data.qvel[adr + 3:adr + 6] = xmat.T @ angular  # MuJoCo keeps it in body axes
        self._decide_next_step()  # its travel to the next decision is at this speed

    def _dof(self, object_id: str) -> tuple[int, np.ndarray]:
        body, _, dof = self.joint(object_id)
        return dof, self.data.xmat[body].reshape(3, 3)

    def has(self, object_id: str) -> bool:
        """Whether the running model holds the object ``object_id``.

        Raises:
            TypeError: ``object_id`` is not a string (as every accessor taking an id).
        """
        object_id = _checked_id(object_id)
        if self._index_of is self.model and object_id in self._index:
            return True
        # Not through joint(): its error for an unknown id suggests the closest ids (difflib, ~25 us), and a
        # flood of Gones for ids the twin never had asked this for each one (65,536 of them: 1.1 s in one step).
        return free_joint(self.model, object_id) >= 0

    def set_pose(self, object_id: str, position: np.ndarray, quat: np.ndarray, *, forward: bool = True) -> None:
        """Teleport an object's free joint (world frame, metres; quaternion w x y z, normalised here).

        ``forward=False`` skips recomputing positions (the next step does it): for several poses at once.

        Raises:
            TypeError: ``object_id`` is not a string. UnknownObjectError: no such object (a KeyError too).
            ValueError: ``position`` not 3 finite numbers within
                :data:`sync.messages.MAX_COORDINATE` of the origin, or ``quat`` not 4 finite numbers with a
                non-zero norm.
            TwinClosedError: the twin is closed.
        """
        import mujoco

        self._check_open()
        body, adr, _ = self.joint(object_id)
        position = _vector(position, 3, MAX_COORDINATE, f"object {object_id!r}: position", "m")
        quat = np.asarray(quat, dtype=np.float64)
        biggest = float(np.abs(quat).max()) if quat.shape == (4,) else math.nan
        if not 0 < biggest < math.inf:  # NaN fails too
            raise SettingsError(f"object {object_id!r}: pose must be finite with a non-zero quaternion, "
                             f"got {_short(quat)}")
        # Scaled first: the norm of 1e300s overflows to inf and that of 1e-200s underflows to 0, and MuJoCo's
        # own normalisation then made a zero (NaN) or identity rotation of a quaternion that has a direction.
        quat = quat / biggest
        self.data.qpos[adr:adr + 3] = position
        self.data.qpos[adr + 3:adr + 7] = quat / np.linalg.norm(quat)
        self.moved([body])
        if forward:
            mujoco.mj_forward(self.model, self.data)

    def _mocap_id(self) -> int | None:
        import mujoco

        bid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, EE_TARGET)
        return None if bid < 0 else int(self.model.body_mocapid[bid])


def _check_object(obj: object, caller: str) -> None:
    """Raises: TypeError: ``obj`` is not a :class:`~twin.objects.TwinObject` (None was an AttributeError)."""
    if not isinstance(obj, TwinObject):
        raise TypeError(f"Twin.{caller} takes a TwinObject (twin.object_at_estimate makes one), got "
                        f"{type(obj).__name__}")


#: Most physics steps one :meth:`Twin.step` call takes: MuJoCo's C int (2**31 was a multi-line pybind error).
MAX_STEPS = 2**31 - 1


def _vector(value: object, size: int, limit: float, what: str, unit: str, *, norm: bool = False) -> np.ndarray:
    """``value`` as a (size,) float64 array of finite numbers, each (or, with ``norm``, their length) at most
    ``limit`` ``unit``.

    Raises:
        SettingsError: naming ``what``, the bound and the value (a TwinError and a ValueError).
    """
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise SettingsError(f"{what} must be {size} finite numbers, got {_short(value)}") from None
    if v.shape != (size,):
        raise SettingsError(f"{what} must be {size} finite numbers, got {_short(v)}")
    # Python floats, not ufuncs: three numbers are checked several times faster one by one (set_end_effector
    # runs at every step of a 1 kHz loop).
    values = v.tolist()
    if not all(map(math.isfinite, values)):
        raise SettingsError(f"{what} must be {size} finite numbers, got {_short(v)}")
    # The length only under the limit: it is at least the largest component (hypot does not overflow).
    if not (max(map(abs, values), default=0.0) <= limit and (not norm or math.hypot(*values) <= limit)):
        bound = f"at most {limit:g} {unit}" + (" in magnitude" if norm else " in each axis")
        raise SettingsError(f"{what} must be {bound}, got {_short(v)}")
    return v


def _short(value: object) -> str:
    """``value`` for an error message: an array's first numbers, not a megabyte of them."""
    if isinstance(value, np.ndarray):
        return np.array2string(value.ravel()[:8], precision=4, threshold=8) + (" ..." if value.size > 8 else "")
    return repr(value)[:200]


def _copy_free_bodies(m_old, d_old, m_new, d_new) -> None:  # type: ignore[no-untyped-def]
    """Copy qpos/qvel of every free-jointed body present (by name) in both models."""
    import mujoco

    free = mujoco.mjtJoint.mjJNT_FREE
    for j in range(m_new.njnt):
        if m_new.jnt_type[j] != free:
            continue
        name = mujoco.mj_id2name(m_new, mujoco.mjtObj.mjOBJ_BODY, m_new.jnt_bodyid[j])
        b_old = mujoco.mj_name2id(m_old, mujoco.mjtObj.mjOBJ_BODY, name) if name else -1
        if b_old < 0 or m_old.body_jntnum[b_old] != 1 or m_old.jnt_type[m_old.body_jntadr[b_old]] != free:
            continue
        j_old = m_old.body_jntadr[b_old]
        qa, qb = m_old.jnt_qposadr[j_old], m_new.jnt_qposadr[j]
        va, vb = m_old.jnt_dofadr[j_old], m_new.jnt_dofadr[j]
        d_new.qpos[qb:qb + 7] = d_old.qpos[qa:qa + 7]
        d_new.qvel[vb:vb + 6] = d_old.qvel[va:va + 6]


def run_paced(twin: Twin, duration: float, rate: float, *, trajectory: Trajectory | None = None,
              clock: Clock = REAL_CLOCK, realtime: bool = True, rlog: DebugLog = OFF) -> LoopStats:
    """Step ``twin`` at ``rate`` Hz for ``duration`` simulated seconds (:func:`twin.loop.run_loop`).

    Each iteration moves the end effector along ``trajectory(t) -> (3,)`` (if given; None from it: no new
    target, as :class:`twin.runtime.Local` takes it), steps the physics 1/rate seconds (a whole number of
    steps: :func:`twin.loop.steps_per_iteration`), and, when ``realtime``, waits for the next deadline, so
    simulated time keeps to the wall clock. A step that ends after its deadline counts as missed. Poses and
    force go to ``rlog`` at its own rate.

    Raises:
        LoopError: a duration that is not a finite number at least 0, or a rate that is not 1 / (k * timestep)
            for a whole k (1000, 500, 333.333 ... Hz at 1 ms).
    """
    rate, substeps = steps_per_iteration(rate, float(twin.model.opt.timestep))

    def body() -> None:
        if trajectory is not None:
            target = trajectory(twin.time)
            if target is not None:
                twin.set_end_effector(target)
        twin.step(substeps)
        if rlog.due(twin.time):
            rlog.frame(twin)

    return run_loop(body, rate=rate, duration=duration, clock=clock,
                    wait=None if realtime else (lambda _left: None))


def _checked_id(object_id: object) -> str:
    """``object_id``, which must be a string (None was "no object None", a list an unhashable-type error)."""
    if not isinstance(object_id, str):
        raise TypeError(f"an object id is a string, got {type(object_id).__name__}")
    return object_id
