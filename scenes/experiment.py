"""Latency experiments: what delay, jitter, loss and a wrong mass do to direct teleoperation and to the twin.

One headless session (:class:`scenes.headless.Headless`, simulated clock, seeded network) per condition
yields both modes, because in both the remote scene C is driven by the operator's commands as they arrive
over the uplink:

- **direct** teleoperation: the operator feels C's end-effector contact force as it arrives over the
  downlink. Each physics step's force sample goes through its own :class:`sync.netem.LinkModel` with the
  downlink's conditions (its own generator, spawned from the seed after the session's two, so it does not
  change the poses' draws); the operator feels the newest sample that has arrived, so a lost sample holds
  the previous one.
- **twin**: the operator feels the twin C' 's force at once; C' is corrected by C's poses as they arrive.

Ground truth is the same task with no delay, no loss and the true mass: C's force ``F_truth(t)``. Direct
teleoperation at zero delay *is* the truth (error exactly 0); the twin at zero delay is not (its shape and
mass are estimates).

Perceived feedback delay counts whole physics steps on the simulated clock, from the step the operator's
target is set to the step its force is felt, plus the one step both modes need to compute a force: the
twin's is one step; the direct one adds the uplink's transit (at least one step: the remote steps before
the operator's command of the same tick) and the force sample's downlink transit (means of the measured
per-packet delays).

Runs go to worker processes (``spawn``) or any :class:`concurrent.futures.Executor`:
:func:`dask_executor` hands them to a Dask distributed cluster (the optional ``dask`` extra), a running one
or a local one. Rows are sorted, so the result does not depend on the number or kind of workers.
"""

from __future__ import annotations

import math
import multiprocessing as mp
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np

from estimation.errors import TwinError
from scenes.scenefile import SceneSpec
from sync.netem import Conditions, LinkModel, Network
from sync.recording import MAX_REPLAY_SECONDS
from twin.runtime import DEFAULT_LOCAL, MASS_SCALE_RANGE, LocalSettings

#: Tasks :func:`run_experiment` knows.
TASKS = ("push", "press")
#: The task of an experiment on a recording: the operator's recorded targets (:class:`RecordedTask`).
RECORDED = "recorded"

#: Modes of each run, in the order rows are written.
MODES = ("direct", "twin")

#: Simulated seconds from the session's start to the task's start: the twin has every object after the
#: first tick (the late-join query is answered at once); the rest lets C' settle on its estimated shapes.
SETUP_S = 0.5

#: How often C'-C divergence is sampled, simulated seconds (as :data:`twin.runtime.DIVERGENCE_EVERY`).
DIVERGENCE_EVERY = 0.01

#: Blow-up: a contact force above this (newtons), an end-effector or object speed above this (m/s), or a
#: spin above this (rad/s) is not a simulation of a hand pushing things on a table. A 2 kg arm pushing at
#: 1 g is 20 N; 1000 rad/s turns a 2 cm ball's surface at 20 m/s (the end effector's sphere, rolling
#: along a pushed box, spun at 21 rad/s in an ordinary push, which the speed limit alone called a blow-up).
ABSURD_FORCE_N = 1e4
ABSURD_SPEED = 20.0
ABSURD_SPIN = 1000.0

#: The truth is "in contact" where its force is above this fraction of its peak: the steps over which the
#: mean felt force is compared with the truth's (a sustained force, what discrimination thresholds are about).
CONTACT_FRACTION = 0.05

#: Gap kept between the end effector and an object's surface at the end of an approach, metres.
APPROACH_GAP = 0.005


class ExperimentError(TwinError, ValueError):
    """A sweep that cannot be run: an unknown task, impossible network conditions, a bad mass scale."""


@dataclass(frozen=True)
class Condition:
    """One run. Delay and jitter in seconds (one way, each direction), loss as a fraction in [0, 1].

    ``speed`` scales the task's timing (2: everything happens twice as fast; tests use it to stay short).
    """

    task: str
    delay: float = 0.0
    jitter: float = 0.0
    loss: float = 0.0
    mass_scale: float = 1.0
    seed: int = 0
    speed: float = 1.0

    def conditions(self) -> Conditions:
        """This run's link, each direction."""
        return Conditions(delay=self.delay, jitter=self.jitter, loss=self.loss)

    def truth(self) -> Condition:
        """The ground truth for this run: same task and timing, no delay, no loss, true mass."""
        return Condition(task=self.task, speed=self.speed)


@dataclass(frozen=True, eq=False)
class RecordedTask:
    """A recorded operator, as an experiment's task: the targets a session applied.

    ``times`` are twin seconds (ascending), ``points`` (n, 3) metres, world frame. Replayed from the first
    target on, each held until the next; the run goes on ``settle`` seconds after the last.
    """

    times: np.ndarray
    points: np.ndarray
    settle: float = 1.0

    def __post_init__(self) -> None:
        t, p = np.asarray(self.times, float), np.asarray(self.points, float)
        if t.ndim != 1 or len(t) == 0 or p.shape != (len(t), 3):
            raise ExperimentError(f"a recorded task needs n times and (n, 3) targets, got {t.shape} and {p.shape}")
        if not (np.isfinite(t).all() and np.isfinite(p).all() and np.all(np.diff(t) >= 0)):
            raise ExperimentError("a recorded task's times and targets must be finite, times ascending")
        if not (math.isfinite(self.settle) and self.settle >= 0):
            raise ExperimentError(f"settle must be a finite number >= 0, got {self.settle!r}")

    def plan(self, speed: float = 1.0):  # type: ignore[no-untyped-def]
        """``(trajectory(t), duration)`` from t = 0, times divided by ``speed`` (as :func:`plan_task`)."""
        from twin.trajectory import HeldTargets

        times = (np.asarray(self.times, float) - float(self.times[0])) / speed
        seconds = float(times[-1]) + self.settle
        if seconds > MAX_REPLAY_SECONDS:  # a 1.4 kB recording of two targets an hour apart, at speed 0.05: 20 h
            raise ExperimentError(f"the recorded targets span {times[-1] * speed:.7g} s, a {seconds:.7g} s session at "
                                  f"speed {speed:g}: more than a replay runs (at most {MAX_REPLAY_SECONDS:g} s)")
        return HeldTargets(times, np.asarray(self.points, float)), seconds


@dataclass(frozen=True)
class Trace:
    """What one session recorded, from the task's start. ``n`` physics steps of ``dt`` seconds.

    Forces are the scene's contact force on the end effector, (n, 3) newtons, world axes; ``felt_direct``
    is C's force as it arrives over the downlink. Energies are joules put into the scene by the end
    effector (integral of -F . dx of the end effector). Object positions are displacements since the task's
    start (metres), so the static offset between an estimated and the true centre of mass does not count.
    Divergence is sampled every :data:`DIVERGENCE_EVERY`: the largest |C' - C| displacement per sample.
    """

    condition: Condition
    dt: float
    force_c: np.ndarray
    force_twin: np.ndarray
    felt_direct: np.ndarray
    energy_c: float
    energy_twin: float
    blowup_c: bool
    blowup_twin: bool
    divergence: np.ndarray
    end_c: dict[str, np.ndarray]
    end_twin: dict[str, np.ndarray]
    uplink_delay: float
    force_delay: float
    messages: dict[str, int]
    bytes: dict[str, int]


#: Columns of ``results.csv``, in order (units in the names).
COLUMNS = (
    "mode", "task", "delay_ms", "jitter_ms", "loss_pct", "mass_scale", "seed",
    "perceived_delay_ms", "force_rms_n", "force_peak_n", "force_rms_pct", "force_peak_pct", "truth_peak_n",
    "contact_force_err_pct",
    "end_err_twin_c_mm", "end_err_c_truth_mm", "end_err_felt_truth_mm",
    "div_p50_mm", "div_p99_mm", "div_max_mm",
    "messages", "bytes", "bytes_per_s", "energy_j", "blowup",
)


@dataclass(frozen=True)
class Row:
    """One line of ``results.csv``: one mode of one run. See :data:`COLUMNS`; NaN (blank in the CSV): not
    defined for this mode or run (direct teleoperation's felt delay when every command or force sample was
    lost)."""

    mode: str
    task: str
    delay_ms: float
    jitter_ms: float
    loss_pct: float
    mass_scale: float
    seed: int
    perceived_delay_ms: float
    force_rms_n: float
    force_peak_n: float
    force_rms_pct: float
    force_peak_pct: float
    truth_peak_n: float
    contact_force_err_pct: float
    end_err_twin_c_mm: float
    end_err_c_truth_mm: float
    end_err_felt_truth_mm: float
    div_p50_mm: float
    div_p99_mm: float
    div_max_mm: float
    messages: int
    bytes: int
    bytes_per_s: float
    energy_j: float
    blowup: bool

    def key(self) -> tuple:
        return (self.task, self.delay_ms, self.jitter_ms, self.loss_pct, self.mass_scale, self.seed,
                MODES.index(self.mode))


assert tuple(f.name for f in fields(Row)) == COLUMNS


#: Task speed factors a condition may ask for: a task runs 1/speed times its length, so 0.05 makes a
#: seconds-long push a minute or two of simulation, while 1e-6 asked for 62 GiB of trace; past 20 the
#: end effector moves tens of metres per second.
SPEED_RANGE = (0.05, 20.0)

#: Runs one sweep may hold (tasks x delays x mass scales x seeds, each run a direct and a twin session of
#: seconds): 10,000 is days of sessions on two cores already; --seeds 99999999999 built its list of runs
#: until memory ran out, with no output.
MAX_RUNS = 10_000


def check_condition(c: Condition) -> None:
    """Refuse a condition before any work.

    Raises:
        ExperimentError: an unknown task, a mass scale outside :data:`MASS_SCALE_RANGE` or a speed outside
            :data:`SPEED_RANGE`, or network conditions :class:`sync.netem.Conditions` refuses (the message
            names the delay).
    """
    if c.task not in (*TASKS, RECORDED):
        raise ExperimentError(f"unknown task {c.task!r} (known: {', '.join(TASKS)})")
    for name, value, (low, high) in (("mass scale", c.mass_scale, MASS_SCALE_RANGE),
                                     ("speed", c.speed, SPEED_RANGE)):
        if not (isinstance(value, int | float) and math.isfinite(value) and low <= value <= high):
            raise ExperimentError(f"{name} must be a number from {low:g} to {high:g}, got {value!r}")
    try:
        c.conditions()
    except TwinError as exc:
        raise ExperimentError(f"delay {c.delay * 1e3:g} ms: {exc}") from None


# -- tasks -----------------------------------------------------------------------------------------------


#: ``_sweep``: metres the end effector is moved at most, at most in one step, the gap that is a touch, and the
#: most steps (each closes the gap to the nearest geom; a face is met in one, an edge in a few dozen).
SWEEP_REACH, SWEEP_STEP, SWEEP_TOUCH, SWEEP_STEPS = 5.0, 0.5, 1e-6, 200


def _ray(model, data, start: np.ndarray, direction: np.ndarray) -> float:  # type: ignore[no-untyped-def]
    """Distance (metres) from ``start`` along the unit ``direction`` to the first movable geom, or inf."""
    import mujoco

    from twin.model import EE_BODY

    ee = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, EE_BODY)
    geom = np.zeros(1, dtype=np.int32)
    dist = mujoco.mj_ray(model, data, np.asarray(start, float), np.asarray(direction, float), None, 0, ee, geom)
    return math.inf if dist < 0 else float(dist)


def _sweep(model, data, start: np.ndarray, direction: np.ndarray) -> float:  # type: ignore[no-untyped-def]
    """How far (metres) the end effector's sphere, centred at ``start``, moves along the unit ``direction`` before it
    touches a movable geom, or inf: advanced by its distance to the nearest (``mj_geomDistance``), which it cannot
    close in less. A ray from its centre missed what lies below it (a rod 8 mm tall under a 20 mm sphere 23 mm up:
    the push went for the box behind, through the rod)."""
    import mujoco

    from twin.model import EE_BODY

    ee = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, EE_BODY)
    (ball,) = [g for g in np.flatnonzero(model.geom_bodyid == ee) if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE]
    collides = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
    movable = np.flatnonzero(collides & (model.body_weldid[model.geom_bodyid] != 0) & (model.geom_bodyid != ee))
    saved = data.geom_xpos[ball].copy()
    try:
        travelled = 0.0
        for _ in range(SWEEP_STEPS):
            if travelled >= SWEEP_REACH:
                break
            data.geom_xpos[ball] = start + travelled * direction
            gap = min((mujoco.mj_geomDistance(model, data, int(ball), int(g), SWEEP_STEP, None) for g in movable),
                      default=SWEEP_STEP)
            if gap <= SWEEP_TOUCH:
                return travelled
            travelled += gap
        return math.inf if travelled >= SWEEP_REACH else travelled
    finally:
        data.geom_xpos[ball] = saved


def _piecewise(times: Sequence[float], points: Sequence[np.ndarray]) -> Callable[[float], np.ndarray]:
    t, p = np.asarray(times, float), np.asarray(points, float)

    def at(s: float) -> np.ndarray:
        return np.array([np.interp(s, t, p[:, i]) for i in range(3)])

    return at


def plan_task(task: str, scene: SceneSpec, model, data, *, speed: float = 1.0):  # type: ignore[no-untyped-def]
    """The operator's trajectory for ``task`` in C's model at rest: ``(trajectory(t), duration)``.

    The object is the one nearest the end effector (in the horizontal plane). ``push``: rise or sink to its
    centre of mass's height, approach to 5 mm from its surface, push it 10 cm, let go (back off 5 cm).
    ``press``: move above it, press 1 cm into its top for 1.5 s, drag 3 cm along while pressing, lift.
    Distances are found by casting rays in C (the operator sees the scene); times are divided by ``speed``.

    Raises:
        ExperimentError: the scene has no end effector or no object, or the rays miss the object.
    """
    import mujoco

    from twin.model import EE_TARGET, body_pose

    if scene.end_effector is None or not scene.objects:
        raise ExperimentError(f"scene {scene.name!r} needs an end effector and an object for the {task} task")
    radius = scene.end_effector.radius
    mocap = model.body_mocapid[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, EE_TARGET)]
    start = data.mocap_pos[mocap].copy()
    centres = {o.id: body_pose(model, data, o.id)[0] for o in scene.objects}
    target = min(sorted(centres), key=lambda i: float(np.linalg.norm((centres[i] - start)[:2])))
    c = centres[target]
    floor = scene.table.height if scene.table is not None else 0.0
    flat = (c - start) * np.array([1.0, 1.0, 0.0])
    d = flat / max(float(np.linalg.norm(flat)), 1e-9)
    times, points = [0.0], [start]

    def go(point: np.ndarray, seconds: float) -> None:
        times.append(times[-1] + seconds / speed)
        points.append(np.asarray(point, float))

    if task == "push":
        h = max(float(c[2]), floor + radius + 0.003)
        a = np.array([start[0], start[1], h])
        touch = _sweep(model, data, a, d)
        if not math.isfinite(touch):
            raise ExperimentError(f"push: nothing in the way of the end effector towards {target!r}")
        go(a, 0.4)
        go(a + d * (touch - APPROACH_GAP), max(0.3, (touch - APPROACH_GAP) / 0.15))
        go(a + d * (touch + 0.10), 1.0)  # 10 cm at 0.1 m/s
        go(points[-1], 0.3)
        go(points[-1] - d * 0.05, 0.3)  # let go
        go(points[-1], 0.5)
    elif task == "press":
        above = np.array([c[0], c[1], c[2] + 0.5])
        top = above[2] - _ray(model, data, above, np.array([0.0, 0.0, -1.0]))
        if not math.isfinite(top):
            raise ExperimentError(f"press: a ray straight down through the centre of mass of {target!r} meets nothing (a ring or "
                                  f"a tube, open there?): press needs a top surface above the centre of mass of the "
                                  f"object nearest the end effector; use --tasks push, or start the end effector nearer "
                                  f"another object")
        clear = top + radius + 0.02
        go(np.array([start[0], start[1], max(clear, start[2])]), 0.3)
        go(np.array([c[0], c[1], max(clear, start[2])]), max(0.3, float(np.linalg.norm(flat)) / 0.2))
        go(np.array([c[0], c[1], top + radius + APPROACH_GAP]), 0.3)
        go(np.array([c[0], c[1], top + radius - 0.01]), 0.5)  # 1 cm into the top
        go(points[-1], 1.5)
        go(points[-1] + d * 0.03, 1.0)  # drag along while pressing
        go(points[-1], 0.3)
        go(points[-1] + np.array([0.0, 0.0, 0.04]), 0.3)
        go(points[-1], 0.3)
    else:
        raise ExperimentError(f"unknown task {task!r} (known: {', '.join(TASKS)})")
    return _piecewise(times, points), times[-1]


# -- one session -----------------------------------------------------------------------------------------


class _EndEffector:
    """Reads the end effector's position in a twin whose model may be swapped (objects added)."""

    def __init__(self, twin) -> None:  # type: ignore[no-untyped-def]
        self.twin, self._model, self._id = twin, None, -1

    def position(self) -> np.ndarray:
        import mujoco

        from twin.model import EE_BODY

        if self.twin.model is not self._model:
            self._model = self.twin.model
            self._id = mujoco.mj_name2id(self._model, mujoco.mjtObj.mjOBJ_BODY, EE_BODY)
        return self.twin.data.xpos[self._id].copy()


def _absurd(twin, force: np.ndarray) -> bool:  # type: ignore[no-untyped-def]
    qvel = twin.data.qvel
    if not (np.isfinite(force).all() and np.isfinite(qvel).all()
            and float(np.abs(force).max(initial=0.0)) < ABSURD_FORCE_N):
        return True
    # Every body here moves on a free joint: 3 linear (m/s) then 3 angular (rad/s) velocities.
    linear, angular = _free_dofs(twin.model)
    return (float(np.abs(qvel[linear]).max(initial=0.0)) >= ABSURD_SPEED
            or float(np.abs(qvel[angular]).max(initial=0.0)) >= ABSURD_SPIN)


def _free_dofs(model) -> tuple[np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
    """Indices into ``qvel`` of the free joints' linear and angular velocities; any other joint's count as
    angular (rad/s). Worked out once per model (asked at every step of both sides)."""
    import mujoco

    cached = _FREE_DOFS.get(id(model))
    if cached is not None and cached[0] is model:  # the model is held, so its id is not reused meanwhile
        return cached[1]
    free = np.flatnonzero(model.jnt_type == mujoco.mjtJoint.mjJNT_FREE)
    linear = (model.jnt_dofadr[free][:, None] + np.arange(3)).ravel()
    dofs = (linear, np.setdiff1d(np.arange(model.nv), linear))
    if len(_FREE_DOFS) > 8:  # a live edit compiles a new model: keep the last few
        _FREE_DOFS.clear()
    _FREE_DOFS[id(model)] = (model, dofs)
    return dofs


_FREE_DOFS: dict[int, tuple[object, tuple[np.ndarray, np.ndarray]]] = {}


def force_sample_bytes() -> int:
    """Bytes of one force sample on the wire: sized as an operator command (stamp, order, three floats)."""
    from sync.messages import VERSION, OperatorCommand, encode

    return len(encode(OperatorCommand(v=VERSION, stamp_ns=2**62, epoch=2**62, seq=2**31,
                                      position=(-1.2345678, 2.3456789, -3.4567891))))


def run_session(scene: SceneSpec, condition: Condition, *, cache_dir: Path | None = None,
                recorded: RecordedTask | None = None, settings: LocalSettings | None = None,
                sensor: str = "surface") -> Trace:
    """One deterministic headless session of ``condition``; see the module docstring. The task
    :data:`RECORDED` replays ``recorded``. ``settings``: the twin's (default :data:`twin.runtime.DEFAULT_LOCAL`),
    its ``mass_scale`` replaced by the condition's. ``sensor``: the remote's, by name
    (:data:`scenes.headless.SENSORS`).

    Raises:
        ExperimentError: as :func:`check_condition` and :func:`plan_task`; the recorded task without a recording.
        ValueError: an unknown ``sensor``.
    """
    from scenes.headless import Headless, sensor_for

    check_condition(condition)
    link = condition.conditions()
    network = Network(uplink=link, downlink=link, seed=condition.seed)
    settings = replace(settings or DEFAULT_LOCAL, mass_scale=condition.mass_scale)
    with Headless(scene, settings=settings, network=network, cache_dir=cache_dir,
                  sensor=sensor_for(sensor, scene)) as session:
        remote, local = session.remote, session.local
        dt = session.dt
        session.run(SETUP_S)
        if local.twin.failed_edits:  # an object MuJoCo refused is missing from C': the run would measure nothing
            raise ExperimentError(f"mass scale {condition.mass_scale:g}: {local.twin.failed_edits} object(s) could "
                                  "not be added to the twin (MuJoCo refused the model; see the log)")
        if condition.task == RECORDED:
            if recorded is None:
                raise ExperimentError(f"the {RECORDED!r} task needs a recording")
            trajectory, duration = recorded.plan(condition.speed)
        else:
            trajectory, duration = plan_task(condition.task, scene, remote.twin.model, remote.twin.data,
                                             speed=condition.speed)
        t0 = local.twin.time
        steps = round(duration / dt)
        # The force samples' own downlink: a third generator from the seed (the session's are the first two).
        force_link = LinkModel(link, np.random.default_rng(np.random.SeedSequence(condition.seed).spawn(3)[2]))
        sample_bytes = force_sample_bytes()
        up0, down0 = _counts(session.uplink), _counts(session.downlink)
        ee_c, ee_twin = _EndEffector(remote.twin), _EndEffector(local.twin)
        x_c, x_twin = ee_c.position(), ee_twin.position()
        force_c, force_twin, felt = (np.zeros((steps, 3)) for _ in range(3))
        arrivals: list[tuple[float, int]] = []  # (arrival time, step) of force samples in flight, FIFO
        newest = -1  # the newest force sample the operator has
        energy_c = energy_twin = 0.0
        blowup_c = blowup_twin = False
        divergence: list[float] = []
        next_sample = 0.0
        objects = [o.id for o in scene.objects if local.twin.has(o.id)]
        # Displacements from the task's start: C' 's body origin is its estimated centre of mass, C's the true
        # one, a static offset of a millimetre or two that is the estimate's, not a divergence.
        start_c = {i: remote.twin.pose(i)[0] for i in objects}
        start_twin = {i: local.twin.pose(i)[0] for i in objects}

        def op(t: float) -> np.ndarray:
            return trajectory(t - t0)

        for k in range(steps):
            now = session.clock.now()
            session.tick(op)
            f_c, f_twin = remote.twin.end_effector_force(), local.twin.end_effector_force()
            force_c[k], force_twin[k] = f_c, f_twin
            y_c, y_twin = ee_c.position(), ee_twin.position()
            energy_c -= float(f_c @ (y_c - x_c))
            energy_twin -= float(f_twin @ (y_twin - x_twin))
            x_c, x_twin = y_c, y_twin
            blowup_c = blowup_c or _absurd(remote.twin, f_c)
            blowup_twin = blowup_twin or _absurd(local.twin, f_twin)
            arrival = force_link.send(now, sample_bytes)
            if arrival is not None:
                arrivals.append((arrival, k))
            while arrivals and arrivals[0][0] <= now + 1e-9:  # felt in the step it arrives (as the bus does)
                newest = max(newest, arrivals.pop(0)[1])
            felt[k] = force_c[newest] if newest >= 0 else 0.0
            if k * dt >= next_sample:
                next_sample += DIVERGENCE_EVERY
                gaps = [float(np.linalg.norm(local.twin.pose(i)[0] - start_twin[i] - remote.twin.pose(i)[0]
                                             + start_c[i])) for i in objects if local.twin.has(i)]
                divergence.append(max(gaps, default=math.nan))
        up1, down1 = _counts(session.uplink), _counts(session.downlink)
        uplink_delay = _mean_delay(up0, up1)
        return Trace(
            condition=condition, dt=dt, force_c=force_c, force_twin=force_twin, felt_direct=felt,
            energy_c=energy_c, energy_twin=energy_twin, blowup_c=blowup_c, blowup_twin=blowup_twin,
            divergence=np.asarray(divergence),
            end_c={i: remote.twin.pose(i)[0] - start_c[i] for i in objects},
            end_twin={i: local.twin.pose(i)[0] - start_twin[i] for i in objects if local.twin.has(i)},
            uplink_delay=uplink_delay, force_delay=_mean_delay((0, 0, 0, 0.0), _counts(force_link)),
            messages={"uplink": up1[0] - up0[0], "downlink": down1[0] - down0[0], "force": force_link.stats.sent},
            bytes={"uplink": up1[1] - up0[1], "downlink": down1[1] - down0[1], "force": force_link.stats.bytes_sent},
        )


def _counts(model: LinkModel | None) -> tuple[int, int, int, float]:
    """(packets sent, bytes sent, packets delivered, total delay) so far on one direction."""
    if model is None:
        return 0, 0, 0, 0.0
    s = model.stats
    return s.sent, s.bytes_sent, s.delivered, s.delay_total


def _mean_delay(before: tuple[int, int, int, float], after: tuple[int, int, int, float]) -> float:
    """Mean delay of the packets delivered between the two counts, seconds; NaN if packets were sent and none
    was delivered (all lost), 0 if none was sent (no link model: a perfect link)."""
    n = after[2] - before[2]
    if n:
        return (after[3] - before[3]) / n
    return math.nan if after[0] > before[0] else 0.0


# -- rows ------------------------------------------------------------------------------------------------


def _steps(seconds: float, dt: float) -> float:
    """Whole physics steps a packet of this delay waits (the bus delivers at the first step not before it)."""
    return math.ceil(seconds / dt - 1e-6)


def rows_for(trace: Trace, truth: Trace) -> list[Row]:
    """The direct and the twin row of one session, against the ground-truth session of its task."""
    c, dt = trace.condition, trace.dt
    n = min(len(trace.force_c), len(truth.force_c))
    f_truth = truth.force_c[:n]
    peak_truth = float(np.linalg.norm(f_truth, axis=1).max(initial=0.0))
    duration = n * dt
    common = {"task": c.task, "delay_ms": c.delay * 1e3, "jitter_ms": c.jitter * 1e3, "loss_pct": c.loss * 100,
              "mass_scale": c.mass_scale, "seed": c.seed, "truth_peak_n": peak_truth,
              "end_err_c_truth_mm": _end_error(trace.end_c, truth.end_c)}
    rows = []
    for mode in MODES:
        felt = (trace.felt_direct if mode == "direct" else trace.force_twin)[:n]
        err = np.linalg.norm(felt - f_truth, axis=1)
        rms, peak = float(np.sqrt(np.mean(err**2))) if n else 0.0, float(err.max(initial=0.0))
        if mode == "direct":
            # With every command or force sample lost the operator feels nothing: no delay to speak of (it read
            # 2 ms, a perfect link's, at 100 % loss).
            perceived = (dt * (1 + max(1, _steps(trace.uplink_delay, dt)) + _steps(trace.force_delay, dt))
                         if math.isfinite(trace.uplink_delay + trace.force_delay) else math.nan)
            messages = trace.messages["uplink"] + trace.messages["force"]
            sent = trace.bytes["uplink"] + trace.bytes["force"]
            div = (math.nan,) * 3
            end_felt, end_twin_c = common["end_err_c_truth_mm"], math.nan
            energy, blowup = trace.energy_c, trace.blowup_c
        else:
            perceived = dt
            messages = trace.messages["uplink"] + trace.messages["downlink"]
            sent = trace.bytes["uplink"] + trace.bytes["downlink"]
            d = trace.divergence[np.isfinite(trace.divergence)] * 1e3
            div = tuple(float(x) for x in np.percentile(d, [50, 99, 100])) if len(d) else (math.nan,) * 3
            end_felt, end_twin_c = _end_error(trace.end_twin, truth.end_c), _end_error(trace.end_twin, trace.end_c)
            energy, blowup = trace.energy_twin, trace.blowup_twin
        pct = 100.0 / peak_truth if peak_truth > 0 else math.nan
        touching = np.linalg.norm(f_truth, axis=1) > CONTACT_FRACTION * peak_truth
        held = float(np.linalg.norm(f_truth[touching], axis=1).mean()) if touching.any() else math.nan
        felt_held = float(np.linalg.norm(felt[touching], axis=1).mean()) if touching.any() else math.nan
        rows.append(Row(mode=mode, perceived_delay_ms=perceived * 1e3, force_rms_n=rms, force_peak_n=peak,
                        contact_force_err_pct=100.0 * (felt_held - held) / held,
                        force_rms_pct=rms * pct, force_peak_pct=peak * pct, end_err_twin_c_mm=end_twin_c,
                        end_err_felt_truth_mm=end_felt, div_p50_mm=div[0], div_p99_mm=div[1], div_max_mm=div[2],
                        messages=messages, bytes=sent, bytes_per_s=sent / duration if duration else math.nan,
                        energy_j=energy, blowup=blowup, **common))
    return rows


def _end_error(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> float:
    """Largest position difference (mm) over the objects both have; NaN if none."""
    gaps = [float(np.linalg.norm(a[i] - b[i])) for i in sorted(a) if i in b]
    return max(gaps) * 1e3 if gaps else math.nan


# -- sweeps ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Sweep:
    """A grid of conditions: every combination of the lists. Seconds, fractions."""

    tasks: tuple[str, ...] = TASKS
    delays: tuple[float, ...] = (0.0, 0.01, 0.025, 0.05, 0.1, 0.2)
    jitter: float = 0.0
    loss: float = 0.0
    mass_scales: tuple[float, ...] = (1.0,)
    seeds: int = 1
    speed: float = 1.0
    #: The remote's sensor in every session (:data:`scenes.headless.SENSORS`).
    sensor: str = "surface"

    @property
    def draws(self) -> int:
        """The seeds that give different sessions: ``seeds`` where the link draws at random, else 1. The seed
        draws only the link's jitter and loss (:class:`sync.netem.LinkModel`); without them every seed ran the
        same session, and a sweep of K seeds K identical ones."""
        return self.seeds if self.jitter > 0 or self.loss > 0 else 1

    def conditions(self) -> list[Condition]:
        """Every run, checked (see :func:`check_condition`). Jitter the distribution cannot take at some delay
        (normal jitter needs ``jitter <= delay / 3``, so any jitter at zero delay) is refused, not clipped.

        Raises:
            ExperimentError: an empty list, fewer than one seed, more than :data:`MAX_RUNS` runs, an unknown
                sensor, or a condition :func:`check_condition` refuses.
        """
        from scenes.headless import SENSORS

        if self.sensor not in SENSORS:
            raise ExperimentError(f"sensor must be one of {', '.join(SENSORS)}, got {self.sensor!r}")
        if not self.tasks or not self.delays or not self.mass_scales:
            raise ExperimentError("tasks, delays and mass scales must each have at least one value")
        if not isinstance(self.seeds, int) or self.seeds < 1:
            raise ExperimentError(f"seeds must be a whole number >= 1, got {self.seeds!r}")
        count = len(self.tasks) * len(self.delays) * len(self.mass_scales) * self.draws
        if count > MAX_RUNS:
            raise ExperimentError(f"{len(self.tasks)} task(s) x {len(self.delays)} delay(s) x {len(self.mass_scales)} mass "
                                  f"scale(s) x {self.draws} seed(s) is {count:,} runs, more than the {MAX_RUNS:,} a "
                                  "sweep holds")
        runs = [Condition(task=t, delay=d, jitter=self.jitter, loss=self.loss, mass_scale=m, seed=s, speed=self.speed)
                for t in self.tasks for d in self.delays for m in self.mass_scales for s in range(self.draws)]
        for r in runs:
            check_condition(r)
        return runs


@contextmanager
def dask_executor(address: str, workers: int = 2) -> Iterator[Executor]:
    """Sessions on a Dask distributed cluster, as an :class:`~concurrent.futures.Executor`.

    Args:
        address: a running scheduler's address (``tcp://HOST:8786``; its workers need this package and the
            scene's files at the same paths), or ``"local"`` for a :class:`distributed.LocalCluster` of
            ``workers`` single-threaded processes on this machine, listening on loopback only. Its scheduler
            serves HTTP (health routes; no dashboard pages without bokeh) on a free loopback port: distributed
            starts that server even when told not to (dask/distributed#7207), and on 8787 it took a port a
            user's own dashboard may hold.
        workers: processes of the local cluster (at least 1).

    Raises:
        ExperimentError: ``distributed`` is not installed (``pip install 'tactile-twin[dask]'``), or no
            scheduler answers at ``address`` within 10 s.
    """
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise ExperimentError("Dask is not installed: pip install 'tactile-twin[dask]' (or distributed)") from None
    if address == "local":
        with LocalCluster(n_workers=max(1, workers), threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address="127.0.0.1:0") as cluster, Client(cluster) as client:
            yield client.get_executor()
        return
    try:
        client = Client(address, timeout=10)
    except (OSError, TimeoutError, ValueError) as exc:
        raise ExperimentError(f"no Dask scheduler at {address!r}: {exc}") from None
    with client:
        yield client.get_executor()


def _job(scene: SceneSpec, condition: Condition, cache_dir: Path | None, recorded: RecordedTask | None,
         sensor: str) -> Trace:
    return run_session(scene, condition, cache_dir=cache_dir, recorded=recorded, sensor=sensor)


def run_experiment(scene: SceneSpec, sweep: Sweep, *, workers: int = 1, executor: Executor | None = None,
                   cache_dir: Path | None = None, recorded: RecordedTask | None = None,
                   progress: Callable[[int, int], None] | None = None) -> tuple[list[Row], dict[Condition, Trace]]:
    """Run every condition of ``sweep`` and its tasks' ground truths; one session per worker job.

    Args:
        scene: the scene (objects, table, end effector).
        sweep: the conditions.
        workers: processes (spawned) when no ``executor`` is given; 0 runs everything in this process.
        executor: where to run the sessions instead (e.g. :func:`dask_executor`).
        cache_dir: CoACD cache for both sides (default: the usual one).
        recorded: the operator of the :data:`RECORDED` task (an experiment on a recording).
        progress: called as ``progress(done, total)`` after each session.

    Returns:
        The rows, sorted (task, delay, jitter, loss, mass scale, seed, mode), and every session's trace.

    Raises:
        ExperimentError: a condition :func:`check_condition` refuses (before any session runs).
    """
    runs = sweep.conditions()
    if RECORDED in sweep.tasks and recorded is None:
        raise ExperimentError(f"the {RECORDED!r} task needs a recording")
    todo = sorted(set(runs) | {r.truth() for r in runs}, key=lambda c: tuple(asdict(c).values()))
    traces: dict[Condition, Trace] = {}
    if executor is None and workers == 0:
        for i, c in enumerate(todo):
            traces[c] = run_session(scene, c, cache_dir=cache_dir, recorded=recorded, sensor=sweep.sensor)
            if progress is not None:
                progress(i + 1, len(todo))
    else:
        pool = executor or ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"))
        try:
            futures = {pool.submit(_job, scene, c, cache_dir, recorded, sweep.sensor): c for c in todo}
            for i, future in enumerate(as_completed(futures)):
                traces[futures[future]] = future.result()
                if progress is not None:
                    progress(i + 1, len(todo))
        finally:
            if executor is None:
                pool.shutdown(wait=True, cancel_futures=True)
    rows = [row for c in runs for row in rows_for(traces[c], traces[c.truth()])]
    return sorted(rows, key=Row.key), traces
