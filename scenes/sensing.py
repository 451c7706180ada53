"""The sensor seam of the remote scene: what turns the simulated truth into what is published.

A :class:`Sensor` sees the remote's :class:`GroundTruth` (the MuJoCo simulation of C and each object's
true surface) and reports, per object, an :class:`Observation` (a cloud in the world frame and the
sensor's estimate of the object's frame) and a :class:`Track` (the frame's pose and velocity now). The
remote publishes exactly that and nothing else, so the wire carries only what a real site could know.

:class:`SurfaceSensor` is the idealised sensor: points sampled off the whole true surface (no occlusion,
no noise) and the simulator's own poses. Camera-based sensors plug in here.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from scenes.sampling import sample_surface
from twin.poses import rotation


@dataclass(frozen=True)
class Observation:
    """One object's cloud as a sensor reports it.

    Attributes:
        points: (n, 3) float64, metres, world frame.
        sensor_origins: (n, 3) float64 metres, world frame: where each point was seen from; None when the
            sensor has no viewpoint (the surface sensor sees everything).
        frame_position: (3,) metres and ``frame_quat`` (4,) w x y z: the sensor's estimate of the object's
            frame at capture, the frame that later :class:`Track` poses move.
    """

    points: np.ndarray
    sensor_origins: np.ndarray | None
    frame_position: np.ndarray
    frame_quat: np.ndarray


@dataclass(frozen=True)
class Track:
    """An object frame's pose and velocity as sensed: world frame; quaternion w x y z; m/s, rad/s."""

    position: np.ndarray
    quat: np.ndarray
    linvel: np.ndarray
    angvel: np.ndarray


class GroundTruth(Protocol):
    """What a simulated sensor may look at: the remote's running simulation and the true surfaces."""

    twin: object  # twin.sim.Twin of the remote scene C

    def true_surface(self, object_id: str):  # type: ignore[no-untyped-def]
        """The object's true mesh (trimesh.Trimesh) in its body frame (origin at the centre of mass)."""


class Sensor(Protocol):
    """Turns the ground truth into observations and tracks."""

    def observe(self, truth: GroundTruth, object_id: str, points: int, *, shot: int) -> Observation:
        """A cloud of ``object_id`` with about ``points`` points; ``shot`` numbers captures (seeds noise)."""

    def track(self, truth: GroundTruth, object_id: str) -> Track:
        """Where the object's frame is now."""


class SurfaceSensor:
    """Idealised sensing: uniform samples of the whole true surface, and the simulator's poses.

    The object frame is the simulated body's frame. Samples are seeded by the object id and ``shot``,
    so a run is repeatable.
    """

    def observe(self, truth: GroundTruth, object_id: str, points: int, *, shot: int) -> Observation:
        mesh = truth.true_surface(object_id)
        cloud = sample_surface(mesh, points, seed=zlib.crc32(object_id.encode()) + shot)
        pos, quat = truth.twin.pose(object_id)  # type: ignore[attr-defined]
        return Observation(cloud.points @ rotation(quat).T + pos, None, pos, quat)

    def track(self, truth: GroundTruth, object_id: str) -> Track:
        pos, quat = truth.twin.pose(object_id)  # type: ignore[attr-defined]
        lin, ang = truth.twin.velocity(object_id)  # type: ignore[attr-defined]
        return Track(pos, quat, lin, ang)
