"""The sensor seam of the remote scene: what turns the simulated truth into what is published.

A :class:`Sensor` sees the remote's :class:`GroundTruth` (the MuJoCo simulation of C and each object's
true surface) and reports, per object, an :class:`Observation` (a cloud in the world frame and the
sensor's estimate of the object's frame) and a :class:`Track` (the frame's pose and velocity now). The
remote publishes exactly that and nothing else, so the wire carries only what a real site could know.

:class:`SurfaceSensor` is the idealised sensor: points sampled off the whole true surface with its normals (no
occlusion, no noise) and the simulator's own poses. Camera-based sensors plug in here.
"""

from __future__ import annotations

import logging
import threading
import zlib
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from estimation.fusion import IcpTarget, Registration, SurfaceMotions, icp_target, unseen_motions
from estimation.segmentation import MIN_CLUSTER_POINTS, Plane
from scenes import association
from scenes.restfilter import REST_WINDOW, RestFilter
from scenes.sampling import sample_surface
from twin.model import free_joint, unknown_object
from twin.poses import matrix_quat, rotation, to_rotvec
from twin.workers import lower_priority

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Observation:
    """One object's cloud as a sensor reports it.

    Attributes:
        points: (n, 3) float64, metres, world frame.
        sensor_origins: (n, 3) float64 metres, world frame: where each point was seen from; None when the
            sensor has no viewpoint (the surface sensor sees everything).
        frame_position: (3,) metres and ``frame_quat`` (4,) w x y z: the sensor's estimate of the object's
            frame at capture, the frame that later :class:`Track` poses move.
        normals: (n, 3) float64 unit outward normals (cameras: oriented towards the camera that saw each
            point), or None.
        completed: (n,) bool, True for points no sensor saw (added by completion, e.g. the base on the
            support plane), or None (all observed).
        support: the plane the object was closed on (world frame; nothing of it lies below), or None.
    """

    points: np.ndarray
    sensor_origins: np.ndarray | None
    frame_position: np.ndarray
    frame_quat: np.ndarray
    normals: np.ndarray | None = None
    completed: np.ndarray | None = None
    support: Plane | None = None


@dataclass(frozen=True)
class Track:
    """An object frame's pose and velocity as sensed: world frame; quaternion w x y z; m/s, rad/s.

    ``position_sigma`` (m) and ``angle_sigma`` (rad): the standard deviation of the pose along its worst
    direction, as the sensor reports it (0: exact, the simulator's own state). ``seen`` is False when the
    latest measurement did not find the object (out of view, lost): the pose is then the last one seen,
    and the remote does not publish it again (a stale pose would pull the twin back to where the object was).
    ``time``: the remote's simulated time of the measurement, seconds (None: now), so that a pose measured
    earlier is compared with the twin's state at that moment, not now.
    """

    position: np.ndarray
    quat: np.ndarray
    linvel: np.ndarray
    angvel: np.ndarray
    position_sigma: float = 0.0
    angle_sigma: float = 0.0
    seen: bool = True
    time: float | None = None


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


class PoseSensor(Sensor, Protocol):
    """A sensor that can also report many objects' frames at once, without velocities.

    Optional: the remote asks for this at every step to decide which objects left the deadband, and asks
    :meth:`Sensor.track` only for those it publishes. A sensor without it is asked for a full track of
    every object at every step.
    """

    def poses(self, truth: GroundTruth, object_ids: list[str]) -> tuple[np.ndarray, np.ndarray]:
        """(positions (n, 3) float64 metres, quaternions (n, 4) float64 w x y z), world frame, in the order
        of ``object_ids``: the same values :meth:`Sensor.track` would report now."""


class SurfaceSensor:
    """Idealised sensing: uniform samples of the whole true surface with its outward face normals, and the
    simulator's poses.

    The object frame is the simulated body's frame. Samples are seeded by the object id and ``shot``,
    so a run is repeatable.
    """

    def observe(self, truth: GroundTruth, object_id: str, points: int, *, shot: int) -> Observation:
        mesh = truth.true_surface(object_id)
        cloud = sample_surface(mesh, points, seed=zlib.crc32(object_id.encode()) + shot)
        pos, quat = truth.twin.pose(object_id)  # type: ignore[attr-defined]
        turn = rotation(quat)
        # The true mesh's face normals come with the samples, as a scanner's viewpoint-oriented normals would:
        # without them the twin fitted its own, and a 2 mm plate's two faces merged (+209 % in twin demo).
        return Observation(cloud.points @ turn.T + pos, None, pos, quat, normals=cloud.normals @ turn.T)

    def __init__(self) -> None:
        self._bodies: tuple[object, list[str], np.ndarray] | None = None  # (model, ids, body ids) of poses()

    def track(self, truth: GroundTruth, object_id: str) -> Track:
        pos, quat = truth.twin.pose(object_id)  # type: ignore[attr-defined]
        lin, ang = truth.twin.velocity(object_id)  # type: ignore[attr-defined]
        return Track(pos, quat, lin, ang)

    def poses(self, truth: GroundTruth, object_ids: list[str]) -> tuple[np.ndarray, np.ndarray]:
        """Every object's body frame from the simulator's own arrays: one gather, not a look-up per object.

        Raises:
            UnknownObjectError: an object not in the model (a KeyError too), as ``truth.twin.pose`` says it.
        """
        twin = truth.twin
        model = twin.model  # type: ignore[attr-defined]
        cached = self._bodies
        if cached is None or cached[0] is not model or cached[1] != object_ids:
            # Body ids change only with the model or the objects asked for: looked up by name once.
            joints = [free_joint(model, i) for i in object_ids]
            missing = [i for i, j in zip(object_ids, joints, strict=True) if j < 0]
            if missing:
                raise unknown_object(missing[0], twin.object_ids())  # type: ignore[attr-defined]
            cached = self._bodies = (model, list(object_ids), np.array([model.jnt_bodyid[j] for j in joints], int))
        data = twin.data  # type: ignore[attr-defined]
        return data.xpos[cached[2]], data.xquat[cached[2]]


class CameraSensor:
    """Sensing with depth cameras: partial noisy views, segmentation, completion, ICP tracking.

    Every :meth:`observe` and every due :meth:`track` scans the scene with the rig
    (:class:`scenes.cameras.CameraFeed`: ray-cast depth with the Kinect noise model, support plane removed,
    the rest clustered). An object is the segment its ICP model lies on where it is predicted (a segment
    may hold several: touching objects, or closer than two clustering cells); the first time, the segment
    nearest its position, which the simulator gives (a real site would label it once, by hand or by
    recognition), and is never used again. A segment that an object not yet observed shares with
    others is parted at a finer cell where that separates them (``_split_shared``). :meth:`observe` fuses the segment's views with per-point
    sensor origins, orients normals towards each point's camera, closes the base on the support plane
    (``estimation.completion``) and reports the segment's centroid with the world's axes as the object
    frame. :meth:`track` registers the object's first fused cloud to the current segment (point-to-plane
    ICP) and reports that motion applied to the frame, with the velocity between its last two tracks.
    Scans happen at most every ``track_period`` simulated seconds; in between, the last track is reported,
    with the scan's time.

    While an object rests, its track is the running mean of its last fits (``rest_window`` of them at most,
    see :class:`scenes.restfilter.RestFilter`), so each scan's noise does not move it; 1 turns that off.
    With ``refine`` (the default), each scan's points are added to the ICP model while the object has not
    moved since the view the model is (``_refine``), and each fit of an object alone in its segment is
    polished by registering the segment onto the model (``_polish``); False: the model is that one view,
    each fit as ICP left it (the tracker as it was before, which bench/rest_tracking.py compares with).

    Between scans an object is predicted at constant velocity (from its last two tracks), and ICP starts
    from that prediction and, when the segment is the object's alone, from the segment's centroid; the
    better fit wins. An object not found near its prediction is looked for again, in segments no other
    object claims, within how far it could have moved since it was last seen (:mod:`scenes.association`).

    Nothing the cameras see raises: an object in no segment, two objects in one segment, a lost ICP are
    logged and counted in ``self.feed.stats``; the last good observation or track is returned, a track
    marked ``seen=False``. An object is never observed from the whole of a segment another object is predicted
    in too (merged: touching, stacked), which is neither of them. With ``segmentation_image`` (the default; a
    simulator gives it with every ray, a real site would need instance segmentation) it is observed from its
    own points of that segment, as the image labels them (counted in ``labelled``); without it, until it is
    seen alone (or parted, above) it has no observation: :meth:`observe` gives one without points, and tracks
    say it unseen. Every later scan looks for it again, and the first to see it alone observes it and offers
    it in :meth:`refreshed`.

    With ``background``, :meth:`track` never scans in the caller's thread: when a scan is due it copies
    the simulation's state and scans and tracks every object in a thread of its own, and answers with the
    last tracks done meanwhile (each with its scan's time), so a live remote's loop is not held up for the
    second a scan takes. MuJoCo's ray casting and Open3D release the GIL. :meth:`observe` still scans at
    once (and waits for a scan in progress). Without it (the default), runs are repeatable bit for bit.
    """

    def __init__(self, feed, *, track_period: float = 0.5, seed: int = 0,  # type: ignore[no-untyped-def]
                 background: bool = False, rest_window: int | None = None, segmentation_image: bool = True,
                 refine: bool = True) -> None:
        self.feed = feed
        self.refine = refine
        self.segmentation_image = segmentation_image
        self.track_period = track_period
        self._rest = RestFilter(REST_WINDOW if rest_window is None else rest_window)  # 1: each scan's own fit
        self.seed = seed
        self._scan = None
        self._claims: dict[int, set[str]] = {}
        self._last: dict[str, np.ndarray] = {}  # object id -> last known position (world, m)
        self._model: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # id -> (ICP model points, frame centre)
        self._motion: dict[str, np.ndarray] = {}  # id -> (4, 4) motion since the model's capture
        self._gathering: dict[str, tuple[float, np.ndarray]] = {}  # id -> (gathers until scan no., view's centroid)
        self._targets: dict[str, tuple[np.ndarray, IcpTarget]] = {}  # id -> (its model, that prepared for ICP)
        self._unseen: dict[str, tuple[np.ndarray, SurfaceMotions]] = {}  # id -> (its model, what it cannot show)
        self._observed: dict[str, Observation] = {}
        self._tracked: dict[str, tuple[float, Track]] = {}
        self._seen_at: dict[str, float] = {}  # id -> scan time of its last good observation or track
        self._previous: dict[str, np.ndarray] = {}  # id -> its frame's position then (world, m)
        self._velocity: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # id -> (linear, angular) between two tracks
        self._gates: dict[str, int] | None = None  # id -> segment at its prediction, in the current scan
        self._reviewed: dict[str, np.ndarray] = {}  # id -> motion when it was last fused (see refreshed)
        self._better: dict[str, tuple[Observation, np.ndarray]] = {}  # id -> (a better view, motion then)
        self._given: set[str] = set()  # ids observe() has given a view of (with points)
        self._fresh: set[str] = set()  # ids first observed by a tracking scan, not yet given (see refreshed)
        self._merges: set[int] = set()  # segments of the current scan counted as merged
        self._merged_said: set[frozenset[str]] = set()  # sets of objects said (at WARNING) to share a segment
        self._waiting: set[str] = set()  # ids never observed whose first miss was said at WARNING
        self._lost: dict[str, int] = {}  # id -> scans its track has been lost in a row (said at WARNING once)
        self._labelled_said: set[str] = set()  # ids observed by the segmentation image, said at INFO once
        self._lock = threading.Lock()  # the tracker's state: one scan-and-track at a time
        # The scans at the priority of the twin's estimation workers: at the loop's, on two cores shared with a
        # twin (twin demo), scanning without pause took the CPU its workers needed (8 objects: 347 s).
        self._pool = (ThreadPoolExecutor(1, thread_name_prefix="cameras", initializer=lower_priority)
                      if background else None)
        self._job: Future | None = None
        self._submitted = -np.inf  # simulated time of the last background scan's state

    @classmethod
    def for_scene(cls, scene, *, cameras: int = 3, seed: int = 0, track_period: float = 0.5,  # type: ignore[no-untyped-def]
                  noise=None, background: bool = False, rest_window: int | None = None,
                  segmentation_image: bool = True, refine: bool = True, **camera: object) -> CameraSensor:
        """The default rig for a scene file: ``cameras`` around its table, the table's workspace.

        ``noise``: a :class:`scenes.cameras.DepthNoise` (None: the Kinect model); ``camera`` options go to
        every :class:`scenes.cameras.Camera`; ``background``, ``rest_window``, ``segmentation_image``,
        ``refine``: see the class.
        """
        from scenes.cameras import KINECT_V1, WORKSPACE_HEIGHT, CameraFeed, table_ring, table_workspace

        size = None if scene.table is None else scene.table.size
        height = None if scene.table is None else scene.table.height
        rig = table_ring(size, height, count=cameras, **camera)
        # Up to the cameras: whatever stands on the table lower than they are is kept whole.
        above = max(c.position[2] for c in rig) - (0.0 if height is None else height)
        workspace = table_workspace(size, height, reach=max(WORKSPACE_HEIGHT, above))
        feed = CameraFeed(rig, workspace, noise=KINECT_V1 if noise is None else noise, seed=seed)
        return cls(feed, track_period=track_period, seed=seed, background=background, rest_window=rest_window,
                   segmentation_image=segmentation_image, refine=refine)

    # -- the Sensor seam -------------------------------------------------------------------------

    def observe(self, truth: GroundTruth, object_id: str, points: int, *, shot: int) -> Observation:
        """The object's view (see the class); without points when it was never seen alone."""
        with self._lock:
            seen = self._observe(truth, object_id, points, shot)
            if len(seen.points):
                self._given.add(object_id)
            return seen

    def track(self, truth: GroundTruth, object_id: str) -> Track:
        if self._pool is not None:
            return self._track_behind(truth, object_id)
        with self._lock:
            return self._track_now(truth, object_id)

    def close(self) -> None:
        """Wait for a background scan in progress and stop its thread."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)

    def refreshed(self) -> list[str]:
        """Objects a later scan saw better than the cloud :meth:`observe` last gave, or saw alone for the
        first time when :meth:`observe` had nothing of them (once each): the remote publishes their cloud
        (again), and :meth:`observe` then gives that view.

        An object is looked at again when it rests, alone in its segment, turned ``REVIEW_TURN_DEG`` or
        moved ``REVIEW_SHIFT`` from where it was last looked at (another side faces the cameras); the view
        is better when its completed share is ``REVIEW_GAIN`` below the last one's. The new cloud is in the
        object's frame as tracked now, so the poses before and after it agree. Empty while a background
        scan runs (it holds the state :meth:`observe` needs).
        """
        if not (self._better or self._fresh) or (self._job is not None and not self._job.done()):
            return []
        return sorted(set(self._better) | self._fresh)

    # -- internals -------------------------------------------------------------------------------

    def _observe(self, truth: GroundTruth, object_id: str, points: int, shot: int, *,
                 force: bool = True) -> Observation:
        """The object's view from the scan of now (``force``: scanned now if it was never observed; else the
        current scan); its last view, or one without points, when that scan does not show it alone."""
        better = self._better.pop(object_id, None)
        if better is not None:
            return self._adopt(object_id, *better, points=points, shot=shot)
        if object_id in self._fresh:  # first seen by a tracking scan: that view, in the frame tracked since
            self._fresh.discard(object_id)
            seen = self._observed[object_id] = self._subsample(self._observed[object_id], points, shot)
            return seen
        scan = self._current(truth, force=force and object_id not in self._observed)
        k = self._associate(truth, scan, object_id)
        segment, shared = None if k is None else scan.segments[k], None
        if k is not None and not self._alone(scan, k, object_id):
            mine = self._labelled(truth, scan, k, object_id)
            if mine is None:
                self._refuse_merged(scan, k, object_id)
                k = None
            else:
                segment, shared = scan.segments[k].part(mine), (scan.segments[k], scan.segments[k].points[~mine])
        if k is None:
            last = self._observed.get(object_id)
            if last is not None:
                return last
            # Its track of this scan too: looked at once per scan (and counted once), not again by track().
            self._tracked[object_id] = (scan.time, self._unseen_track(object_id, scan.time))
            empty = np.zeros((0, 3))
            return Observation(empty, empty, self._last.get(object_id, np.zeros(3)), np.array([1.0, 0, 0, 0]))
        seen = self._subsample(self._fuse(scan, segment, shared=shared), points, shot)
        observed = scan.trackable(seen.points[~seen.completed])  # type: ignore[index]
        self._model[object_id] = (self._icp_model(observed, shot), seen.frame_position)
        self._motion[object_id] = self._reviewed[object_id] = np.eye(4)
        # Its model is a new view, in a new frame: the fits averaged so far answered to the old one.
        self._rest.forget(object_id)
        # The centroid of all its points in this scan, not of the subsample: a few hundred of them drawn at
        # random were 2-3 mm from the scans at rest.
        whole = scan.trackable(segment.points)  # type: ignore[union-attr]
        self._gathering[object_id] = (self.feed.stats.scans + GATHER_SCANS,
                                      whole.mean(axis=0) if len(whole) else seen.frame_position)
        self._observed[object_id] = seen
        self._tracked[object_id] = (scan.time, Track(seen.frame_position, seen.frame_quat, np.zeros(3), np.zeros(3),
                                                     time=scan.time))
        # _last stays where association found the object (the label, the first time): the fused frame's
        # centre is that of the segment, which two touching objects share.
        self._previous[object_id], self._seen_at[object_id] = seen.frame_position, scan.time
        self._velocity.pop(object_id, None)
        if object_id in self._waiting:
            self._waiting.discard(object_id)
            log.info("%s: seen alone at t=%.3f: observed", object_id, scan.time)
        return seen

    def _labelled(self, truth: GroundTruth, scan, k: int, object_id: str) -> np.ndarray | None:  # type: ignore[no-untyped-def]
        """Which points of the merged segment ``k`` are ``object_id``'s own, as the simulator's segmentation image
        labels them ((n,) bool), or None: without ``segmentation_image``, or with fewer than
        ``MIN_LABELLED_POINTS`` of them. Counted in ``labelled`` and said once per object."""
        if not self.segmentation_image:
            return None
        model = truth.twin.model  # type: ignore[attr-defined]
        body = model.jnt_bodyid[free_joint(model, object_id)]
        seg = scan.segments[k]
        mine = np.isin(seg.geom, np.flatnonzero(model.geom_bodyid == body))
        if mine.sum() < MIN_LABELLED_POINTS:
            return None
        self.feed.stats.labelled += 1
        owners = sorted(i for i, g in self._gated(scan).items() if g == k and i != object_id)
        level = logging.DEBUG if object_id in self._labelled_said else logging.INFO
        self._labelled_said.add(object_id)
        log.log(level, "%s: its segment in the scan at t=%.3f holds %s too (merged); observed from its own %d "
                "points, as the simulator's segmentation image labels them", object_id, scan.time,
                ", ".join(owners) or "another object", int(mine.sum()))
        return mine

    def _refuse_merged(self, scan, k: int, object_id: str) -> None:  # type: ignore[no-untyped-def]
        """Say (once per object until it is observed; at DEBUG after) and count (once per segment and scan)
        that segment ``k`` is not ``object_id``'s view: other objects are predicted in it too."""
        owners = sorted(i for i, g in self._gated(scan).items() if g == k)
        self._count_merge(scan, k, owners)
        level = logging.DEBUG if object_id in self._waiting else logging.WARNING
        self._waiting.add(object_id)
        log.log(level, "%s: its segment in the scan at t=%.3f holds %s too (merged); not observed until it is "
                "seen alone", object_id, scan.time, ", ".join(i for i in owners if i != object_id))

    def _count_merge(self, scan, k: int, owners) -> None:  # type: ignore[no-untyped-def]
        """Count and say once per scan that segment ``k`` holds the objects ``owners``."""
        if k in self._merges:
            return
        self._merges.add(k)
        self.feed.stats.merged += 1
        pair = frozenset(owners)
        # Said at WARNING the first time these objects are seen merged; a stack that stays is not said every scan.
        level = logging.DEBUG if pair in self._merged_said else logging.WARNING
        self._merged_said.add(pair)
        log.log(level, "segment %d of the scan at t=%.3f holds %s: merged", k, scan.time, ", ".join(sorted(owners)))

    def _adopt(self, object_id: str, seen: Observation, motion: np.ndarray, points: int, shot: int) -> Observation:
        """A later, better view of a tracked object as its observation, in its frame as tracked (``motion``,
        (4, 4), since the first capture): its model is the new view moved back by that motion, so the
        tracks go on unchanged."""
        seen = self._subsample(seen, points, shot)
        observed = self._scan.trackable(seen.points[~seen.completed])  # type: ignore[union-attr,index]
        back = (observed - motion[:3, 3]) @ motion[:3, :3]  # R^T (x - t)
        self._model[object_id] = (self._icp_model(back, shot), self._model[object_id][1])
        self._gathering.pop(object_id, None)  # moved back by a fit: not in the frame it was seen in
        self._rest.restart(object_id)
        self._observed[object_id] = seen
        return seen

    def _review(self, scan, k: int, object_id: str, motion: np.ndarray, linvel: np.ndarray) -> None:  # type: ignore[no-untyped-def]
        """Fuse the object's segment again if it rests, turned or moved since it was last looked at, alone in
        its segment; keep that view for :meth:`refreshed` if it leaves less to completion."""
        from twin.poses import angle_deg

        last = self._reviewed.get(object_id, np.eye(4))
        turned = angle_deg(matrix_quat(motion[:3, :3] @ last[:3, :3].T), np.array([1.0, 0, 0, 0]))
        moved = float(np.linalg.norm(motion[:3, 3] - last[:3, 3]))
        if float(np.linalg.norm(linvel)) > REVIEW_REST_SPEED or (turned < REVIEW_TURN_DEG and moved < REVIEW_SHIFT):
            return
        if not self._alone(scan, k, object_id):
            return  # merged: look again when it is alone
        self._reviewed[object_id] = motion
        current = self._observed.get(object_id)
        candidate = self._fuse(scan, scan.segments[k])
        if current is None or _completed_share(candidate) <= _completed_share(current) - REVIEW_GAIN:
            centre = self._model[object_id][1]
            frame = Observation(candidate.points, candidate.sensor_origins, motion[:3, :3] @ centre + motion[:3, 3],
                                matrix_quat(motion[:3, :3]), candidate.normals, candidate.completed, candidate.support)
            self._better[object_id] = (frame, motion.copy())
            log.info("%s: seen better at t=%.3f (%.0f %% completed, was %.0f %%)", object_id, scan.time,
                     100 * _completed_share(candidate), 100 * _completed_share(current) if current else 100)

    def _track_now(self, truth: GroundTruth, object_id: str) -> Track:
        scan = self._current(truth)
        done = self._tracked.get(object_id)
        if done is not None and done[0] == scan.time:
            return done[1]
        if object_id not in self._model:
            return self._first_sight(truth, scan, object_id)
        k = self._associate(truth, scan, object_id)
        model, centre = self._model.get(object_id, (np.zeros((0, 3)), self._last.get(object_id, np.zeros(3))))
        result = None
        if k is not None and len(model) >= 3:
            result = self._register(scan, k, object_id, model)
            if result.fitness < MIN_FITNESS:
                # Predicted into a segment that is not it (another object's, where it was): look further.
                free = self._search(scan, object_id, taken=set(self._gated(scan).values()) | {k})
                retry = None if free is None else self._register(scan, free, object_id, model)
                if retry is not None and retry.fitness >= MIN_FITNESS:
                    result, k = retry, free
                    self._claims.setdefault(k, set()).add(object_id)
            if result.fitness < MIN_FITNESS:
                self._lose(object_id, "%s: ICP lost the object (fitness %.2f); keeping the last pose",
                           object_id, result.fitness)
                result = None
            elif not self._alone(scan, k, object_id):
                through = _seen_through(scan, model, result.transform)
                if through > MAX_SEEN_THROUGH:
                    self._lose(object_id, "%s: ICP put %.0f %% of it where the cameras see through, in a segment "
                               "it shares; keeping the last pose", object_id, 100 * through)
                    result = None
        if result is not None and self.refine and self._alone(scan, k, object_id):
            result = self._polish(scan, k, object_id, model, result)
        if result is not None and (missed := self._lost.pop(object_id, 0)):
            log.info("%s: tracked again at t=%.3f after %d lost scan(s)", object_id, scan.time, missed)
        if result is None:
            last = self._tracked.get(object_id)
            kept = last[1] if last is not None else Track(centre, np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3))
            track = replace(kept, seen=False)
        else:
            before = self._motion[object_id]
            # What the model's surface cannot show (a ball's turns, a can's about its axis) stays as it was:
            # ICP's answer there is noise, and it went out as corrections of objects at rest.
            step = self._surface_motions(object_id, model).without(np.linalg.inv(before) @ result.transform)
            step, shrink = self._rest.step(object_id, model, step, result.rmse)
            motion = self._motion[object_id] = before @ step
            if self.refine:
                self._refine(scan, k, object_id, result.rmse)
            position = motion[:3, :3] @ centre + motion[:3, 3]
            linvel, angvel = self._update_velocity(object_id, position, motion[:3, :3] @ before[:3, :3].T, scan.time)
            track = Track(position, matrix_quat(motion[:3, :3]), linvel, angvel,
                          shrink * result.position_sigma(position), shrink * result.angle_sigma, time=scan.time)
            self._review(scan, k, object_id, motion, linvel)
        self._tracked[object_id] = (scan.time, track)
        return track

    def _polish(self, scan, k: int, object_id: str, model: np.ndarray, fit: Registration) -> Registration:  # type: ignore[no-untyped-def]
        """ICP's ``fit`` of the object's ``model`` to segment ``k`` (the object's alone) polished the other way
        round: the segment's points registered onto the model, from the inverse of the fit, with the motions
        the model cannot show held; the fit as it was if that matches under ``MIN_FITNESS`` of them.

        The model onto the segment reads the tangent planes of the scan, each fitted to a few noisy points: on
        a torus 4.4 cm across seen by one camera (some 200 points a scan) the fits of later scans onto eight
        scans' points leaned 0.6 degrees on average one way; the segment onto those points, whose planes are
        fitted to eight scans' worth, 0.05 degrees (/tmp harness on bench/rest_tracking.py's scans, session 59)."""
        from estimation.fusion import register

        points = scan.trackable(scan.segments[k].points)
        if len(points) < 3:
            return fit
        target = self._targets.get(object_id)
        if target is None or target[0] is not model:
            target = self._targets[object_id] = (model, icp_target(model))
        hold = self._surface_motions(object_id, model).moved(fit.transform)
        back = register(points, target[1], init=np.linalg.inv(fit.transform), max_distance=_match_distance(scan),
                        hold=hold)
        if back.fitness < MIN_FITNESS:
            return fit
        return replace(fit, transform=np.linalg.inv(back.transform))

    def _refine(self, scan, k: int, object_id: str, rmse: float) -> None:  # type: ignore[no-untyped-def]
        """Add segment ``k``'s points to the object's ICP model while the object rests where the view the model
        was taken from saw it: alone in its segment, for the ``GATHER_SCANS`` scans after that view at most
        (gathered or not), up to ``MODEL_POINTS_CAP`` points.

        Fits at rest answer to that one noisy view: averaging them takes their own noise away, not the
        model's, and a 3 cm dice seen by one camera (some 300 points) settled over a degree turned. An object
        that has not moved is where it was, so a later scan's points are in the model's frame with no fit
        applied, and each scan added takes the model's noise down; placed by the polished fit instead, the
        hex nut at one camera kept 2.3 degrees of its first view's bias. So a scan that moved it must not be
        added: a step the rest filter takes for motion ends the gathering, a scan whose step it holds is left
        out, and so is, for good, a segment whose centroid is further from the view's than the fit's RMS
        residual ``rmse`` (metres): a nudge under the rest gate, whose scans would otherwise have gone into
        the model unmoved and kept the track between the two poses (a box nudged 3 mm at one camera stayed
        2.3 mm off). At rest the centroid moves less than the residual (one camera of tests/test_cameras.py's
        rig: 0.5-1.9 mm against a 2 mm residual; a 3 mm nudge moved it 3-4 mm). A smaller nudge or a creep is
        taken in, blurring the model by up to the residual, and so is a turn under the rest gate, which
        hardly moves the centroid (a review turned that box 2-3 degrees about its vertical axis: the track
        stayed 1.7-2.6 degrees off, where the one-view tracker settled within 0.6; not mended). What the
        model's surface cannot show stays as its first view found it."""
        model, centre = self._model[object_id]
        until, centroid = self._gathering.get(object_id, (-np.inf, centre))
        if self._rest.moved(object_id):
            until = -np.inf
        if self.feed.stats.scans > until or not self._rest.resting(object_id) or len(model) >= MODEL_POINTS_CAP \
                or not self._alone(scan, k, object_id):
            self._gathering[object_id] = (until, centroid)
            return
        more = scan.trackable(scan.segments[k].points)
        shift = float(np.linalg.norm(more.mean(axis=0) - centroid)) if len(more) else np.inf
        if shift > rmse:
            log.debug("%s: its points at t=%.3f are %.2f mm from its first view's; its model gathers no more",
                      object_id, scan.time, 1e3 * shift)
            self._gathering[object_id] = (-np.inf, centroid)
            return
        refined = self._icp_model(np.concatenate([model, more]), len(model))
        self._unseen[object_id] = (refined, self._surface_motions(object_id, model))
        self._model[object_id] = (refined, centre)

    def _lose(self, object_id: str, msg: str, *args: object) -> None:
        """Count a scan that lost ``object_id``'s track, and say so: at WARNING when it is lost, at DEBUG while
        it stays lost (a ball ICP cannot hold was said at every scan: 138 lines in a 20-object demo)."""
        self.feed.stats.lost_tracks += 1
        self._lost[object_id] = self._lost.get(object_id, 0) + 1
        log.log(logging.WARNING if self._lost[object_id] == 1 else logging.DEBUG, msg, *args)

    def _first_sight(self, truth: GroundTruth, scan, object_id: str) -> Track:  # type: ignore[no-untyped-def]
        """The track of an object never observed: observed from ``scan`` if it shows it alone (and offered in
        :meth:`refreshed` unless :meth:`observe` gave it already), else unseen where it was labelled."""
        seen = self._observe(truth, object_id, 0, 0, force=False)
        if len(seen.points) and object_id not in self._given:
            self._fresh.add(object_id)
        return self._tracked[object_id][1]

    def _unseen_track(self, object_id: str, time: float | None) -> Track:
        """The track of an object never observed: not seen, at rest where it was labelled."""
        return Track(self._last.get(object_id, np.zeros(3)), np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3),
                     seen=False, time=time)

    def _track_behind(self, truth: GroundTruth, object_id: str) -> Track:
        """:meth:`track` with ``background``: the last track done; a scan of a copy of now started if due.

        An object not observed yet is not scanned for here (that took a scan in the caller's thread at every
        step): the background scans look for it, and until one sees it its track says it unseen."""
        job = self._job
        if job is not None and job.done():
            self._job = None
            if job.exception() is not None:  # a bug, not something the cameras saw: said, and tried again later
                self.feed.stats.failed_scans += 1
                log.error("a background scan failed: %r", job.exception())
        now = float(truth.twin.time)  # type: ignore[attr-defined]
        if self._job is None and now - self._submitted >= self.track_period:
            self._submitted = now
            ids = list(truth.twin.object_ids())  # type: ignore[attr-defined]  # the unobserved too: looked for
            self._job = self._pool.submit(self._track_all, _Still(truth.twin), ids)  # type: ignore[union-attr]
        done = self._tracked.get(object_id)
        return done[1] if done is not None else self._unseen_track(object_id, None)

    def _track_all(self, truth: GroundTruth, ids: list[str]) -> None:
        with self._lock:
            for object_id in ids:
                self._track_now(truth, object_id)

    def _current(self, truth: GroundTruth, *, force: bool = False):  # type: ignore[no-untyped-def]
        """The scan of now, or the last one if younger than ``track_period`` (unless ``force``)."""
        twin = truth.twin
        now = float(twin.time)  # type: ignore[attr-defined]
        if self._scan is not None and (now - self._scan.time < self.track_period or now == self._scan.time) \
                and not (force and now != self._scan.time):
            return self._scan
        import mujoco

        model = twin.model  # type: ignore[attr-defined]
        expected = [g for i in twin.object_ids()  # type: ignore[attr-defined]
                    if (g := mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"{i}/visual")) >= 0]
        self._scan = self.feed.scan(model, twin.data, time=now, expected=expected)  # type: ignore[attr-defined]
        self._claims, self._gates, self._merges = {}, None, set()
        ids = list(twin.object_ids())  # type: ignore[attr-defined]
        for object_id in ids:
            self._label(truth, object_id, now, again=True)
        self._split_shared(ids)
        return self._scan

    def _label(self, truth: GroundTruth, object_id: str, time: float, *, again: bool = False) -> None:
        """Labelling, once: where ``object_id`` is, from the simulator (see the class docstring); ``again``
        (a new scan), also where an object never observed is now: it is labelled at first sight, and a label
        kept from before would be looked for ever further from where it was (:func:`scenes.association.reach`) while it was unseen."""
        if object_id not in self._last or (again and object_id not in self._observed):
            self._last[object_id] = np.asarray(truth.twin.pose(object_id)[0], float)  # type: ignore[attr-defined]
            self._seen_at[object_id] = time
            self._gates = None  # one more object to gate

    def _split_shared(self, ids: list[str]) -> None:
        """Part the current scan's segments that an object not yet observed shares with others, at finer
        cells (``estimation.segmentation.split_cluster``): clustering joins objects closer than about two
        cells, and a first view fused from two objects is neither of them (the paper's large objects under
        the Kinect model at 3 m, a 31 mm cell, came out +150 % to +2,400 %). Segments of tracked objects only
        are left whole: registration has its own rule for a shared segment (``MAX_SEEN_THROUGH``)."""
        from estimation.segmentation import split_cluster

        scan = self._scan
        if len(scan.segments) == 0 or len(ids) < 2 or all(i in self._observed for i in ids):
            return  # (a tracking scan: nothing to part, and no tree of every point to build)
        sharing = association.sharing(scan.segments, {i: self._predicted(i, scan.time) for i in ids})
        segments = list(scan.segments)
        for k, owners in sorted(sharing.items()):
            away = association.outsiders(scan.segments[k], {i: self._predicted(i, scan.time) for i in owners})
            owners = [i for i in owners if i not in away]
            if len(owners) < 2 or all(i in self._observed for i in owners):
                continue
            seg = scan.segments[k]
            labels = split_cluster(seg.points, np.array([self._predicted(i, scan.time) for i in owners]), scan.cell)
            if labels is None:
                continue
            pieces = [labels == j for j in np.unique(labels)]
            segments[k] = seg.part(pieces[0])
            segments.extend(seg.part(piece) for piece in pieces[1:])
            self.feed.stats.parted += 1
            log.info("segment %d of the scan at t=%.3f held %s: parted in %d at a finer cell", k, scan.time,
                     ", ".join(sorted(owners)), len(pieces))
        if len(segments) > len(scan.segments):
            self._scan, self._gates = replace(scan, segments=tuple(segments)), None

    def _associate(self, truth: GroundTruth, scan, object_id: str) -> int | None:  # type: ignore[no-untyped-def]
        """Index of the segment that is ``object_id`` in ``scan``, or None (logged and counted).

        The segment around the object's predicted position; failing that, the nearest segment no other object
        is predicted in, within the distance the object could have moved since it was last seen.
        """
        self._label(truth, object_id, scan.time)  # done at the scan, unless the object came after it
        if not scan.segments:
            self.feed.stats.unseen += 1
            log.log(self._miss_level(object_id), "%s: the scan at t=%.3f has no segments", object_id, scan.time)
            return None
        gates = self._gated(scan)
        k = gates.get(object_id)
        if k is None:
            k = self._search(scan, object_id, taken=set(gates.values()))
        if k is None:
            self.feed.stats.unseen += 1
            since = scan.time - self._seen_at.get(object_id, scan.time)
            log.log(self._miss_level(object_id), "%s: no free segment within %.0f mm of where it was %.1f s ago; "
                    "not seen", object_id, 1000 * association.reach(since), since)
            return None
        owners = self._claims.setdefault(k, set())
        owners.add(object_id)
        if len(owners) >= 2:
            self._count_merge(scan, k, owners)
        return k

    def _miss_level(self, object_id: str) -> int:
        """WARNING, but DEBUG for an object never observed whose first miss was said: it is looked for at every
        scan (a 5 mm bead no camera resolves would fill the log)."""
        if object_id in self._observed:
            return logging.WARNING
        if object_id in self._waiting:
            return logging.DEBUG
        self._waiting.add(object_id)
        return logging.WARNING

    def _predicted(self, object_id: str, time: float) -> np.ndarray:
        """Where the object's frame centre is expected at ``time``: its last position moved at its velocity."""
        velocity = self._velocity.get(object_id)
        last = self._last[object_id]
        return last if velocity is None else last + velocity[0] * (time - self._seen_at.get(object_id, time))

    def _gated(self, scan) -> dict[str, int]:  # type: ignore[no-untyped-def]
        """Every labelled object's segment at its prediction in ``scan`` (:func:`scenes.association.gate`,
        computed once per scan): by the overlap of its ICP model placed there, for an object observed."""
        if self._gates is None:
            placed = {i: self._placed(i, scan.time) for i in self._last if i in self._model}
            self._gates = association.gate(scan.segments, {i: self._predicted(i, scan.time) for i in self._last},
                                           placed)
        return self._gates

    def _placed(self, object_id: str, time: float) -> np.ndarray:
        """The object's ICP model points where it is predicted at ``time`` (world, m): moved by its motion so
        far and on by its predicted displacement since it was last seen."""
        model = self._model[object_id][0]
        motion = self._motion[object_id]
        return model @ motion[:3, :3].T + motion[:3, 3] + (self._predicted(object_id, time) - self._last[object_id])

    def _search(self, scan, object_id: str, *, taken: set[int]) -> int | None:  # type: ignore[no-untyped-def]
        """The nearest segment no object is predicted in, within reach of where ``object_id`` was last seen."""
        since = scan.time - self._seen_at.get(object_id, scan.time)
        return association.search(scan.segments, self._last[object_id], association.reach(since), taken=taken)

    def _alone(self, scan, k: int, object_id: str) -> bool:  # type: ignore[no-untyped-def]
        """No other object is predicted in segment ``k`` of ``scan``."""
        return all(i == object_id for i, g in self._gated(scan).items() if g == k)

    def _register(self, scan, k: int, object_id: str, model: np.ndarray):  # type: ignore[no-untyped-def]
        """ICP of the object's model to segment ``k``, from where it was (the fit kept if ``GOOD_FITNESS``);
        failing that, the best fit also from its predicted motion and, when the segment is the object's
        alone, from the segment's centroid at a few turns about the vertical (each a coarse pass, then a
        fine one). Best: the lowest RMSE among the fits within ``FITNESS_TIE`` of the highest fitness."""
        from estimation.fusion import icp_target, register

        target = icp_target(scan.trackable(scan.segments[k].points))  # its normals and tree, once for every fit
        motion = self._motion[object_id]
        distance = _match_distance(scan)
        hold = self._surface_motions(object_id, model)
        still = register(model, target, init=motion, max_distance=distance, hold=hold)
        if still.fitness >= GOOD_FITNESS:
            # Not only cheaper: a symmetric object fits as well turned, and noise would pick a turn.
            return still
        starts = []
        if object_id in self._velocity:  # moved on as it moved
            predicted = motion.copy()
            predicted[:3, 3] += self._predicted(object_id, scan.time) - self._last[object_id]
            starts.append(predicted)
        if self._alone(scan, k, object_id):
            moved = model @ motion[:3, :3].T + motion[:3, 3]
            pivot = moved.mean(axis=0)
            shift = scan.segments[k].centroid - pivot
            for turn in CENTROID_TURNS:
                c, s = np.cos(turn), np.sin(turn)
                yaw = np.eye(4)
                yaw[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
                yaw[:3, 3] = pivot + shift - yaw[:3, :3] @ pivot
                starts.append(yaw @ motion)
        fits = [still]
        for start in starts:
            # A coarse pass reaches an object that moved further than the fine distance, then a fine one.
            coarse = register(model, target, init=start, max_distance=COARSE_FACTOR * distance, hold=hold)
            fits.append(register(model, target, init=coarse.transform, max_distance=distance, hold=hold))
        top = max(f.fitness for f in fits)
        return min((f for f in fits if f.fitness >= top - FITNESS_TIE), key=lambda f: f.rmse)

    def _surface_motions(self, object_id: str, model: np.ndarray) -> SurfaceMotions:
        """:func:`estimation.fusion.unseen_motions` of the object's ICP model (worked out once per model)."""
        cached = self._unseen.get(object_id)
        if cached is None or cached[0] is not model:
            cached = self._unseen[object_id] = (model, unseen_motions(model))
        return cached[1]

    def _update_velocity(self, object_id: str, position: np.ndarray, turn: np.ndarray,
                         time: float) -> tuple[np.ndarray, np.ndarray]:
        """The frame's (linear m/s, angular rad/s) velocity, world frame, from the last track to this one at
        ``position`` turned by ``turn`` (3, 3); zero when the last is older than ``VELOCITY_WINDOW``."""
        before, since = self._previous.get(object_id), time - self._seen_at.get(object_id, time)
        if before is not None and 0 < since <= VELOCITY_WINDOW:
            linear = (position - before) / since
            speed = float(np.linalg.norm(linear))
            if speed > association.MAX_SPEED:
                linear = linear * (association.MAX_SPEED / speed)
            self._velocity[object_id] = (linear, to_rotvec(matrix_quat(turn)[None])[0] / since)
        else:
            self._velocity.pop(object_id, None)
        self._last[object_id] = self._previous[object_id] = position
        self._seen_at[object_id] = time
        return self._velocity.get(object_id, (np.zeros(3), np.zeros(3)))

    def _fuse(self, scan, seg, *, carve: bool = True, shared=None) -> Observation:  # type: ignore[no-untyped-def]
        """The segment's views as one cloud: normals towards each point's camera, the base closed (without
        ``carve``, by the mirror image and the base alone: bench/carving_effect.py compares the two).
        ``shared``: (the merged segment ``seg`` was cut from, the rest of its points): that rest is other
        objects', as the other segments are (the whole segment, this object's points included, was)."""
        from estimation.completion import close_on_plane
        from estimation.fusion import oriented_normals
        from estimation.spacing import surface_noise

        pts, origins = seg.points, seg.origins
        others = [s.points for s in scan.segments if s is not seg and (shared is None or s is not shared[0])]
        if shared is not None:
            others.append(shared[1])
        # The segment holds its lowest band too (below the clustering cut, see Scan.cut); completion starts at
        # the cut as before (the skirt, the carving grid's cell), and the mirror test reads the band.
        closed = close_on_plane(pts, origins, oriented_normals(pts, origins), scan.plane, cell=scan.cell / 3,
                                cut=scan.cut, noise=surface_noise(pts), views=(scan.views or None) if carve else None,
                                others=np.concatenate(others) if others else None)
        centre = closed.points.mean(axis=0)
        return Observation(closed.points, closed.origins, centre, np.array([1.0, 0.0, 0.0, 0.0]), closed.normals,
                           closed.completed, closed.support)

    def _icp_model(self, observed: np.ndarray, shot: int) -> np.ndarray:
        """At most ``MODEL_POINTS_CAP`` of ``observed`` (n, 3), drawn from the seed and ``shot``: an ICP model."""
        return observed[np.random.default_rng([self.seed, shot]).permutation(len(observed))[:MODEL_POINTS_CAP]]

    def _subsample(self, seen: Observation, points: int, shot: int) -> Observation:
        """At most ``points`` of ``seen``'s points (0: all), drawn from the seed and ``shot``; the frame kept."""
        if not points or len(seen.points) <= points:
            return seen
        keep = np.sort(np.random.default_rng([self.seed, shot]).permutation(len(seen.points))[:points])
        return replace(seen, points=seen.points[keep], sensor_origins=seen.sensor_origins[keep],  # type: ignore[index]
                       normals=seen.normals[keep], completed=seen.completed[keep])  # type: ignore[index]


def _match_distance(scan) -> float:  # type: ignore[no-untyped-def]
    """Metres: the farthest a point and its match may be apart in ICP on ``scan``: three clustering cells, at
    least a centimetre."""
    return max(3 * scan.cell, 0.01)


def _seen_through(scan, model: np.ndarray, transform: np.ndarray) -> float:  # type: ignore[no-untyped-def]
    """The share of ``model`` ((n, 3) object frame, metres) moved by ``transform`` (4, 4) that some camera of
    ``scan`` saw through, a clustering cell's slack (0 without views)."""
    from estimation.carving import free_space

    if not scan.views or not len(model):
        return 0.0
    moved = model @ transform[:3, :3].T + transform[:3, 3]
    return float(free_space(moved, scan.views, slack=scan.cell).mean())


def _completed_share(seen: Observation) -> float:
    """The share of an observation's points no camera saw: 0 without completion flags, 1 without points."""
    if seen.completed is None or not len(seen.points):
        return 0.0 if seen.completed is None else 1.0
    return float(np.mean(seen.completed))


#: An object is fused again when it rests (m/s) after turning this much (degrees) or moving this far
#: (metres) since it was last fused: another side may face the cameras (see CameraSensor.refreshed).
REVIEW_REST_SPEED = 0.01
REVIEW_TURN_DEG = 30.0
REVIEW_SHIFT = 0.1

#: ... and its new view replaces the published one when its completed share is this much smaller.
REVIEW_GAIN = 0.05

#: Points of an object's first fused cloud kept as its ICP model.
MODEL_POINTS_CAP = 4000

#: Scans after its first view in which an object's ICP model gathers the scans of it at rest, at most (see
#: ``CameraSensor._refine``): as many as the rest filter averages by default. One camera's 300
#: points a scan of a 3 cm dice reach some 2,700; a longer gathering would take more of a creep too slow to
#: show into the model.
GATHER_SCANS = REST_WINDOW



#: An object's own points of a merged segment, as the segmentation image labels them, fewer than this are not a
#: view of it (the clustering's own smallest segment: :data:`estimation.segmentation.MIN_CLUSTER_POINTS`).
MIN_LABELLED_POINTS = MIN_CLUSTER_POINTS

#: ICP matching fewer of the model's points than this share has lost the object.
MIN_FITNESS = 0.3

#: An ICP fit in a segment the object shares with another (touching: merged) is refused, and the object
#: said lost, when more than this share of its model lands in space some camera sees through
#: (``estimation.carving.free_space``, a cell's slack). In a merged segment ICP from where the object was
#: can fit its neighbour's surface instead: a can pushed on by a crate was tracked where the crate now was,
#: said found, 130 mm from the can, for 5 scans (``bench/camera_tracking.py``, into the can). A right fit
#: puts only its silhouette's noise there; that one put a third of the can, its top above the lower crate.
#: Two objects of the same shape in each other's place are not told apart this way.
MAX_SEEN_THROUGH = 0.2


#: Seconds over which two tracks give a velocity to predict with; further apart, none (a stale difference
#: says little about the motion now).
VELOCITY_WINDOW = 1.5



#: Turns about the vertical (radians) tried from the segment's centroid: a pushed object turns.
CENTROID_TURNS = (0.0, np.pi / 2, np.pi, -np.pi / 2)

#: The first ICP pass's correspondence distance, in fine distances.
COARSE_FACTOR = 3.0

#: A fit from where the object was that matches this share of its model is kept without trying others.
GOOD_FITNESS = 0.95

#: Fits within this much of the best fitness are told apart by their RMSE (fitness saturates at 1 when the
#: correspondence distance is several noise sigmas).
FITNESS_TIE = 0.02


class _Still:
    """The remote's simulation frozen at one instant, for a scan in another thread: what a
    :class:`CameraSensor` reads of a :class:`GroundTruth` (its ``twin``'s model, data, time, objects and
    their poses). The model is shared (scans only read it, and hide the end effector from rays, which no
    step reads); the state is a copy."""

    def __init__(self, twin) -> None:  # type: ignore[no-untyped-def]
        import copy

        self.twin = self
        self.model, self.data, self.time = twin.model, copy.copy(twin.data), float(twin.time)
        self._ids = list(twin.object_ids())

    def object_ids(self) -> list[str]:
        return self._ids

    def pose(self, object_id: str) -> tuple[np.ndarray, np.ndarray]:
        body = self.model.jnt_bodyid[free_joint(self.model, object_id)]
        return self.data.xpos[body].copy(), self.data.xquat[body].copy()
