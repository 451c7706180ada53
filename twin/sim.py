"""The running twin: a MuJoCo model and its state, live edits, and the paced local loop."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from twin.model import EE_FORCE, EE_TARGET, add_object, body_pose, remove_object
from twin.objects import TwinObject

log = logging.getLogger(__name__)


class Twin:
    """The local simulation C'. The caller owns the loop: ``step()`` advances one physics step.

    Use as a context manager. Live edits (:meth:`add`, :meth:`remove`, :meth:`replace`) recompile the
    spec keeping every other body's state (MjSpec.recompile carries qpos/qvel over).
    """

    def __init__(self, spec, model=None) -> None:  # type: ignore[no-untyped-def]
        import mujoco

        self.spec = spec
        self.model = model if model is not None else spec.compile()
        self.data = mujoco.MjData(self.model)
        mujoco.mj_forward(self.model, self.data)
        self._mocap = self._mocap_id()

    def __enter__(self) -> Twin:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Release the model (nothing external is held; present for symmetry with sessions)."""

    @property
    def time(self) -> float:
        return float(self.data.time)

    def step(self, n: int = 1) -> None:
        import mujoco

        mujoco.mj_step(self.model, self.data, n)

    def set_end_effector(self, position: np.ndarray) -> None:
        """Move the operator's mocap target (world frame, metres)."""
        if self._mocap is None:
            raise LookupError("this scene has no end effector")
        self.data.mocap_pos[self._mocap] = position

    def end_effector_force(self) -> np.ndarray:
        """Contact force on the end effector (N, sensor frame = world axes at identity pose), (3,)."""
        import mujoco

        sid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SENSOR, EE_FORCE)
        if sid < 0:
            raise LookupError("this scene has no end effector")
        adr = self.model.sensor_adr[sid]
        return self.data.sensordata[adr:adr + 3].copy()

    def pose(self, object_id: str) -> tuple[np.ndarray, np.ndarray]:
        """(position, quaternion w x y z) of an object's centre of mass."""
        return body_pose(self.model, self.data, object_id)

    def object_ids(self) -> list[str]:
        # Objects are the bodies with a free joint named "<id>/free" (element info is not saved in XML).
        return [b.name for b in self.spec.bodies if any(j.name == f"{b.name}/free" for j in b.joints)]

    def add(self, obj: TwinObject) -> None:
        """Add an object without disturbing the others."""
        add_object(self.spec, obj)
        self._recompile()

    def remove(self, object_id: str) -> None:
        remove_object(self.spec, object_id)
        self._recompile()

    def replace(self, obj: TwinObject) -> None:
        """Swap an object's geometry and inertia, keeping its current pose and velocity."""
        pos, quat = self.pose(obj.id)
        remove_object(self.spec, obj.id)
        add_object(self.spec, obj)
        self._recompile()
        self.set_pose(obj.id, pos, quat)

    def set_pose(self, object_id: str, position: np.ndarray, quat: np.ndarray) -> None:
        """Teleport an object's free joint (world frame; quaternion w x y z)."""
        import mujoco

        jid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, f"{object_id}/free")
        if jid < 0:
            raise KeyError(f"no object {object_id!r} in the model")
        adr = self.model.jnt_qposadr[jid]
        self.data.qpos[adr:adr + 3] = position
        self.data.qpos[adr + 3:adr + 7] = quat
        mujoco.mj_forward(self.model, self.data)

    def _recompile(self) -> None:
        import mujoco

        mocap = self.data.mocap_pos.copy() if self._mocap is not None else None
        self.model, self.data = self.spec.recompile(self.model, self.data)
        self._mocap = self._mocap_id()
        if mocap is not None and self._mocap is not None:
            self.data.mocap_pos[:] = mocap
        mujoco.mj_forward(self.model, self.data)

    def _mocap_id(self) -> int | None:
        import mujoco

        bid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, EE_TARGET)
        return None if bid < 0 else int(self.model.body_mocapid[bid])


@dataclass(frozen=True)
class LoopStats:
    """Timing of a paced loop, seconds."""

    steps: int
    p50: float
    p99: float
    max: float
    missed: int
    wall: float


def run_paced(twin: Twin, duration: float, rate: float, *,
              trajectory=None, realtime: bool = True) -> LoopStats:  # type: ignore[no-untyped-def]
    """Step ``twin`` at ``rate`` Hz for ``duration`` simulated seconds.

    Each iteration moves the end effector along ``trajectory(t) -> (3,)`` (if given), steps the physics
    enough to cover 1/rate of simulated time, and, when ``realtime``, sleeps to the next deadline. A step
    that ends after its deadline counts as missed.
    """
    period = 1.0 / rate
    substeps = max(1, round(period / twin.model.opt.timestep))
    n = round(duration * rate)
    times = np.empty(n)
    missed = 0
    start = time.perf_counter()
    for k in range(n):
        t0 = time.perf_counter()
        if trajectory is not None:
            twin.set_end_effector(trajectory(twin.time))
        twin.step(substeps)
        t1 = time.perf_counter()
        times[k] = t1 - t0
        deadline = start + (k + 1) * period
        if t1 > deadline:
            missed += 1
        elif realtime:
            time.sleep(max(0.0, deadline - time.perf_counter()))
    wall = time.perf_counter() - start
    return LoopStats(n, float(np.percentile(times, 50)), float(np.percentile(times, 99)), float(times.max()),
                     missed, wall)


def push_trajectory(start: np.ndarray, end: np.ndarray, duration: float):  # type: ignore[no-untyped-def]
    """A straight push from ``start`` to ``end`` over ``duration`` seconds, then hold."""
    start, end = np.asarray(start, float), np.asarray(end, float)

    def at(t: float) -> np.ndarray:
        s = min(1.0, max(0.0, t / duration))
        return start + s * (end - start)

    return at
