"""The simulated remote scene C: the ground-truth simulation, its sensor, and what it publishes.

The ground truth is built from the true meshes (exact mass properties, CoACD of the true surface), so the
twin never sees it: it gets only what the :class:`scenes.sensing.Sensor` reports (clouds, and the sensed
object frames when they leave a deadband). The remote talks through any :class:`sync.transport.Transport`
and reads time only from its :class:`sync.clock.Clock`, so it runs live over Zenoh or headless in one
process with the twin.
"""

from __future__ import annotations

import logging
import numbers
import queue
import threading
from collections import Counter
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from estimation.contracts import check_number, shown
from scenes.placement import check_placement
from scenes.scenefile import MAX_POINTS, MIN_POINTS, ObjectSpec, SceneError, SceneSpec
from scenes.sensing import Sensor, SurfaceSensor, Track
from scenes.sources import prepare_objects, reference_estimate, source_mesh
from sync.clock import REAL_CLOCK, Clock
from sync.keys import Keys
from sync.link import Link
from sync.messages import (
    MAX_ANGLE_SIGMA,
    MAX_INT64,
    VERSION,
    Gone,
    Heartbeat,
    OperatorCommand,
    Pose,
    SceneInfo,
    cloud_message,
)
from sync.ordering import Marks
from sync.ratelimit import RateLimitedLog, TokenBucket
from sync.recording import Recorder
from sync.transport import Transport
from twin.debuglog import OFF, DebugLog
from twin.loop import LoopStats, run_loop, steps_per_iteration
from twin.model import OPERATOR_REACH, add_object, remove_object
from twin.objects import TwinObject
from twin.poses import rotation
from twin.runtime import reach_box
from twin.settings import SettingsError
from twin.sim import Twin

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Deadband:
    """A pose is published when it moved more than ``position`` metres or ``angle_deg`` degrees since the
    last one published. 1 mm and 0.5 degree: below what an operator can see at arm's length."""

    position: float = 0.001
    angle_deg: float = 0.5

    def __post_init__(self) -> None:
        """Refuse a deadband no pose can be compared with (a NaN one compared false: every step published).

        Raises:
            SettingsError: ``position`` not a finite number >= 0 (metres), ``angle_deg`` not one from 0 to 180.
        """
        check_number(self.position, "Deadband.position", error=SettingsError)
        check_number(self.angle_deg, "Deadband.angle_deg", high=180.0, error=SettingsError)


@dataclass(frozen=True)
class _Truth:
    """One ground-truth object: its scene entry, its body in the model, its true surface in the body frame."""

    spec: ObjectSpec
    obj: TwinObject
    body_mesh: object  # trimesh.Trimesh, origin at the centre of mass


#: Joint speed below which the ground truth counts as at rest, m/s or rad/s: a millimetre per second.
SETTLED_SPEED = 1e-3

#: State queries answered at once, and per second after that: each answer is every cloud the remote has. A
#: twin asks once when it starts, so a handful of twins starting together are all answered; a peer asking in
#: a loop gets one answer a second and the remote's uplink stays for its poses.
STATE_QUERY_BURST, STATE_QUERY_RATE = 8, 1.0


def check_remote_options(points: object, epoch: object, *, heartbeat_s: object = 0.2, keyframe_s: object = 1.0,
                         settle_s: object = 3.0) -> None:
    """Refuse :class:`Remote`'s ``points``, ``epoch`` and periods before any work.

    Raises:
        SettingsError: ``points`` not None or a whole number from :data:`scenes.scenefile.MIN_POINTS` to
            :data:`~scenes.scenefile.MAX_POINTS` (a scene file's and ``--points``' bounds: 10**9 allocated
            7.45 GiB); ``epoch`` not None or a whole number from 0 to :data:`sync.messages.MAX_INT64` (what
            the wire carries: a negative one had every message dropped by the twin, 2**70 failed to encode);
            ``heartbeat_s``, ``keyframe_s`` or ``settle_s`` not a finite number of seconds >= 0 (0: every step,
            no keyframes, no settling; a NaN heartbeat compared false and never beat, so the twin called the
            link stale).
    """
    if points is not None and not _whole_in(points, MIN_POINTS, MAX_POINTS):
        raise SettingsError(f"Remote: points must be None or a whole number from {MIN_POINTS} to {MAX_POINTS}, "
                            f"got {shown(points)}")
    if epoch is not None and not _whole_in(epoch, 0, MAX_INT64):
        raise SettingsError(f"Remote: epoch must be None or a whole number from 0 to 2**63 - 1 (the wire's range), "
                            f"got {shown(epoch)}")
    for name, value in (("heartbeat_s", heartbeat_s), ("keyframe_s", keyframe_s), ("settle_s", settle_s)):
        check_number(value, f"Remote: {name}", error=SettingsError)


def _whole_in(value: object, low: int, high: int) -> bool:
    """``value`` is a whole number (not a bool, which Python counts as one) from ``low`` to ``high``."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool) and low <= value <= high


class Remote:
    """The remote scene C on a transport. ``run()`` steps it; everything else is message handling.

    What happens to the scene (:meth:`add`, :meth:`remove`, :meth:`move`) may be called from any thread:
    it is queued and done by the loop between two steps, never during one.

    ``epoch`` numbers this run of the remote on the wire (default: the clock's stamp at start, so a
    restarted remote has a larger one). ``points``: each object's cloud size (default: the scene file's).
    Both are checked first (:func:`check_remote_options`: :class:`twin.settings.SettingsError`).

    Operator commands are taken by the rule the twin applies to device targets: newest ``(epoch, seq)`` wins,
    a mark lasting :data:`sync.ordering.MARK_EXPIRY` seconds after the last command taken (so with two twins
    commanding, the later started one wins while it streams), and only inside the twin's operator workspace
    (:func:`twin.runtime.reach_box` with :data:`twin.runtime.OPERATOR_REACH`). The rest are counted in
    ``operator_dropped`` by reason (``"out-of-order"``, ``"out-of-workspace"``). On a simulated clock, objects added later compile in the loop's
    thread (deterministic); on a real one, in the background.
    """

    def __init__(self, scene: SceneSpec, transport: Transport, *, clock: Clock = REAL_CLOCK,
                 sensor: Sensor | None = None, deadband: Deadband = Deadband(), points: int | None = None,
                 heartbeat_s: float = 0.2, cache_dir: Path | None = None, progress: bool = False,
                 publish: bool = True, keyframe_s: float = 1.0, settle_s: float = 3.0, epoch: int | None = None,
                 rlog: DebugLog = OFF, recorder: Recorder | None = None) -> None:
        check_remote_options(points, epoch, heartbeat_s=heartbeat_s, keyframe_s=keyframe_s, settle_s=settle_s)
        self.scene = scene
        self.recorder = recorder  # gets the true poses at its truth rate (wrap the transport to log the wire)
        self.rlog = rlog
        self.clock = clock
        self.sensor: Sensor = sensor if sensor is not None else SurfaceSensor()
        self.epoch = clock.stamp_ns() if epoch is None else epoch
        self.keys = Keys(scene.name)
        self.deadband = deadband
        self.points = points
        self.heartbeat_s = heartbeat_s
        self.keyframe_s = keyframe_s
        self._last_keyframe = clock.now()
        self.link = Link(transport, clock)
        self._lock = threading.Lock()
        self._actions: queue.SimpleQueue[Callable[[], None]] = queue.SimpleQueue()  # run by step()
        self._replies: dict[str, bytes] = {}  # key -> last encoded message, for late joiners
        self._operator: np.ndarray | None = None
        self._command: tuple[int, int] | None = None  # (its stamp on the twin's clock, when it arrived here)
        self._commands = Marks()  # the newest (epoch, seq) of the operator's commands taken (sync.ordering)
        self.operator_dropped: Counter = Counter()  # reason -> operator commands dropped after decoding
        self._dropped_log = RateLimitedLog(log, clock)
        self._seq = 0
        self._published: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._rows: _Published | None = None  # _published as arrays, for the deadband check over all objects
        self._pose_keys: dict[str, str] = {}  # object id -> its pose key (built once, not at every publication)
        self._objects: dict[str, _Truth] = {}
        self._cache_dir = cache_dir
        self.pose_updates = 0
        self.cloud_updates = 0  # clouds published again because the sensor saw the object better
        self.unseen_reports = 0  # times the sensor lost an object (Track.seen False), each said once on the wire
        self._unseen: set[str] = set()  # objects lost and said so: nothing more is published of them until found
        self.unseen_clouds = 0  # objects whose cloud was held back, the sensor having observed nothing of them
        self._withheld: set[str] = set()  # objects never published (nothing observed): no cloud, no pose yet
        top = scene.table.height if scene.table else None
        truth = prepare_objects(scene.objects, table_top=top, cache_dir=cache_dir, progress=progress,
                                estimates=[reference_estimate(s) for s in scene.objects],
                                table_size=scene.table.size if scene.table else None)
        spec = scene.empty_spec()
        for spec_obj, obj in zip(scene.objects, truth, strict=True):
            add_object(spec, obj)
            self._remember(spec_obj, obj)
        try:
            self.twin = Twin(spec, background=clock.realtime)
        except ValueError as exc:  # MuJoCo's compiler: a 1 mm sphere at 0.1 kg/m^3 has no inertia it accepts
            self.link.close()
            raise SceneError(f"scene {scene.name!r}: MuJoCo could not compile it: {' '.join(str(exc).split())}") from None
        try:
            check_placement(scene.name, self.twin.model, set(self._objects), self.twin.data)
            self._check_extents(scene)
        except SceneError:
            self.twin.close()
            self.link.close()
            raise
        self.settled_after = self._settle(settle_s)
        if scene.table is not None:
            rlog.table(scene.table.size, scene.table.height)
        self._info = self.link.put(self.keys.info, self._scene_info()) if publish else None
        self._workspace = reach_box(self._scene_info(), OPERATOR_REACH)
        self.link.queryable(self.keys.info, lambda _k: [(self.keys.info, self._info or b"")])
        self.link.queryable(self.keys.state, lambda _k: list(self._replies_snapshot()),
                            budget=TokenBucket(STATE_QUERY_BURST, STATE_QUERY_RATE, self.clock))
        self.link.subscribe(self.keys.operator, self._on_operator)
        if publish:
            for spec_obj in scene.objects:
                self.publish_cloud(spec_obj.id)
        self._last_heartbeat = -np.inf

    # -- what the operator and the scene do ------------------------------------------------------

    def add(self, spec: ObjectSpec, position: np.ndarray | None = None) -> Future:
        """An object appears. Returns a Future that resolves to its id once its cloud is published (or held back
        until the sensor sees it: :meth:`publish_cloud`).

        The true mesh's mass properties, CoACD and the compile run in the background while the loop
        steps (a 200k-point object took over a second, long enough for twins to mark the link stale);
        :meth:`step` swaps the new model in and publishes the cloud. An object that would overlap another, the
        table or the end effector where they are then (:mod:`scenes.placement`) is taken out again unpublished,
        and the Future raises :class:`SceneError` naming what it overlaps.
        """
        top = self.scene.table.height if self.scene.table else None
        # A position given is where the object goes: the table's edges judge only where its spec rests it.
        size = self.scene.table.size if self.scene.table and position is None else None
        prepared: list[TwinObject] = []
        done: Future = Future()

        def edit(model_spec) -> None:  # type: ignore[no-untyped-def]
            (obj,) = prepare_objects([spec], table_top=top, cache_dir=self._cache_dir, progress=False,
                                     estimates=[reference_estimate(spec)], table_size=size)
            if position is not None:
                obj = replace(obj, position=np.asarray(position, float))
            add_object(model_spec, obj)
            prepared.append(obj)

        def then() -> None:
            # Where the scene is now, not where its file put it: another object may have come to rest there.
            try:
                check_placement(self.scene.name, self.twin.model, set(self._objects) | {spec.id}, self.twin.data,
                                added=spec.id)
            except SceneError as exc:
                self._refuse(spec.id)
                done.set_exception(exc)
                return
            self._remember(spec, prepared[0])
            self.publish_cloud(spec.id)
            done.set_result(spec.id)

        self._actions.put(lambda: self.twin.edit_async(edit, then=then))
        return done

    def remove(self, object_id: str) -> None:
        """An object vanishes: twins are told at the next step; the ground truth drops it soon after."""
        self._actions.put(lambda: self._remove(object_id))

    def move(self, object_id: str, position: np.ndarray, quat: np.ndarray) -> Future:
        """Something outside the twin's view moves an object (world frame, quaternion w x y z), at rest.

        Returns a Future that resolves to the id once the object is there (at the next step). A pose where it
        would be inside another object, the table or the end effector (:mod:`scenes.placement`) is no move
        MuJoCo could follow (it pushes the pair apart at once): the object stays where it was and the Future
        raises :class:`SceneError` naming what it would overlap; so it does for a pose that is not finite or
        lies beyond :data:`sync.messages.MAX_COORDINATE` (:meth:`twin.sim.Twin.set_pose`).
        """
        done: Future = Future()

        def teleport() -> None:
            if not self.twin.has(object_id):
                done.set_exception(SceneError(f"{self.scene.name}: cannot move {object_id!r}: no such object"))
                return
            before = self.twin.pose(object_id)
            try:  # the caller's Future, not the loop that runs this, hears of a pose no scene holds
                self.twin.set_pose(object_id, np.asarray(position, float), np.asarray(quat, float))
            except ValueError as exc:
                done.set_exception(SceneError(f"{self.scene.name}: cannot move {object_id!r}: {exc}"))
                return
            try:
                check_placement(self.scene.name, self.twin.model, set(self._objects), self.twin.data,
                                added=object_id, moved=True)
            except SceneError as exc:
                self.twin.set_pose(object_id, *before)
                done.set_exception(exc)
                return
            self.twin.set_velocity(object_id, np.zeros(3), np.zeros(3))
            done.set_result(object_id)

        self._actions.put(teleport)
        return done

    def _check_extents(self, scene: SceneSpec) -> None:
        """Raise a :class:`SceneError` naming the first object whose true surface, where it starts, reaches out
        of the scene's declared workspace: the twin drops the cloud of an object that does not fit its scene
        box, and ``twin demo`` waited ten minutes for it (the loader checks positions only; a surface needs
        its mesh)."""
        if scene.workspace is None:
            return
        low, high = (np.asarray(c, dtype=float) for c in scene.workspace)
        for object_id, truth in self._objects.items():
            position, quat = self.twin.pose(object_id)
            vertices = np.asarray(truth.body_mesh.vertices) @ rotation(quat).T + position  # type: ignore[attr-defined]
            lo, hi = vertices.min(axis=0), vertices.max(axis=0)
            if (lo < low).any() or (hi > high).any():
                raise SceneError(f"scene {scene.name!r}: object {object_id!r} reaches from {np.round(lo, 3).tolist()} to "
                                 f"{np.round(hi, 3).tolist()} m, out of the workspace (min {list(scene.workspace[0])}, "
                                 f"max {list(scene.workspace[1])}); the twin would drop its cloud")

    def cloud_points(self) -> dict[str, int]:
        """Points per object cloud this remote sends."""
        return {i: self.points or t.spec.points for i, t in self._objects.items()}

    def true_surface(self, object_id: str):  # type: ignore[no-untyped-def]
        """The object's true mesh in its body frame (for sensors: :class:`scenes.sensing.GroundTruth`)."""
        return self._objects[object_id].body_mesh

    def publish_cloud(self, object_id: str, points: int | None = None) -> int:
        """Sense and publish one object's cloud (with its sensed frame); returns the bytes sent.

        An object the sensor observed nothing of (no camera saw it, or saw it merged with another) is not
        published: no cloud, and no pose until one is (a cloud of no points is no object, and the wire cannot
        carry one). It is counted in ``unseen_clouds`` and logged, once, and published when the sensor offers a
        view of it (``refreshed``). An object published before keeps what the twin has of it. Returns 0 then.
        """
        truth = self._objects[object_id]
        spec = truth.spec
        seq = self._next()
        seen = self.sensor.observe(self, object_id, points or self.points or spec.points, shot=seq)
        cloud, pos, quat = seen.points, seen.frame_position, seen.frame_quat
        if not len(cloud):
            with self._lock:
                published = self.keys.object(object_id, "cloud") in self._replies
            if not published and object_id not in self._withheld:
                self._withheld.add(object_id)
                self.unseen_clouds += 1
                log.warning("%s: the sensor observed nothing of it (unseen, or merged with another object); its "
                            "cloud is published when it is seen", object_id)
                self.rlog.event(self.twin.time, f"{object_id}: not seen; cloud held back")
            return 0
        if object_id in self._withheld:
            self._withheld.discard(object_id)
            log.info("%s: seen at last; cloud published", object_id)
        msg = cloud_message(object_id, cloud, stamp_ns=self.clock.stamp_ns(), epoch=self.epoch, seq=seq,
                            material=spec.material, density=spec.density, frame_position=pos, frame_quat=quat,
                            normals=seen.normals, completed=seen.completed,
                            support=None if seen.support is None else seen.support.as_abcd())
        data = self.link.put(self.keys.object(object_id, "cloud"), msg)
        if self.rlog.enabled:
            # The truth's estimate frame is the true mesh's: body frame + COM.
            in_mesh_frame = (cloud - pos) @ rotation(quat) + truth.obj.estimate.mass.center_of_mass
            self.rlog.object("remote", truth.obj, sim_time=self.twin.time, cloud=in_mesh_frame, pose=(pos, quat))
            self.rlog.event(self.twin.time, f"{object_id}: cloud published ({len(cloud):,} points, {len(data):,} bytes)")
        with self._lock:
            self._replies[self.keys.object(object_id, "cloud")] = data
        self._publish_pose(object_id)
        return len(data)

    # -- the loop ------------------------------------------------------------------------------------

    def step(self) -> None:
        """One physics step: apply the operator's latest command, step, publish what left the deadband."""
        while True:
            try:
                self._actions.get_nowait()()
            except queue.Empty:
                break
        self.twin.poll()  # objects added in the background
        if self._operator is not None:
            self.twin.set_end_effector(self._operator)
        self.twin.step()
        if self.recorder is not None and self.recorder.truth_due(self.twin.time):
            self.recorder.truth(self.twin.time, {i: self.twin.pose(i) for i in self._objects if self.twin.has(i)})
        if self.rlog.due(self.twin.time):
            self.rlog.frame(self.twin, side="remote")
        self._publish_moved()
        refreshed = getattr(self.sensor, "refreshed", None)
        if refreshed is not None:
            # A turned object showed the cameras another side, or one held back was seen at last.
            for object_id in refreshed():
                if object_id in self._objects:
                    first = object_id in self._withheld
                    if self.publish_cloud(object_id) and not first:
                        self.cloud_updates += 1
        now = self.clock.now()
        if self.keyframe_s > 0 and now - self._last_keyframe >= self.keyframe_s:
            # Every pose now and then, moved or not: a twin that drifted on its own (its estimated shape
            # is not the true one) is pulled back even when the remote object is still.
            self._last_keyframe = now
            for object_id in self._objects:
                self._publish_pose(object_id)
        if now - self._last_heartbeat >= self.heartbeat_s:
            self._last_heartbeat = now
            self.link.put(self.keys.heartbeat, Heartbeat(v=VERSION, stamp_ns=self.clock.stamp_ns(), epoch=self.epoch,
                                                         seq=self._next(), sim_time=self.twin.time,
                                                         objects=len(self._objects)))

    def run(self, duration: float, *, rate: float = 1000.0, stop: threading.Event | None = None) -> LoopStats:
        """Step for ``duration`` simulated seconds (or until ``stop`` is set), ``rate`` iterations a second of the
        clock, each a whole number of physics steps (:func:`twin.loop.steps_per_iteration`; a LoopError else)."""
        rate, substeps = steps_per_iteration(rate, float(self.twin.model.opt.timestep))

        def body() -> None:
            for _ in range(substeps):
                self.step()

        return run_loop(body, rate=rate, duration=duration, clock=self.clock,
                        until=None if stop is None else stop.is_set)

    def close(self) -> None:
        self.link.close()
        close = getattr(self.sensor, "close", None)
        if close is not None:
            close()
        self.twin.close()

    # -- internals -----------------------------------------------------------------------------------

    def _remove(self, object_id: str) -> None:
        self.twin.edit_async(lambda spec: remove_object(spec, object_id))
        self.rlog.removed("remote", object_id, self.twin.time)
        self.rlog.event(self.twin.time, f"{object_id}: removed")
        self._objects.pop(object_id, None)
        self._published.pop(object_id, None)
        self._withheld.discard(object_id)
        self._rows = None  # rebuilt without it at the next step
        with self._lock:  # the queryable reads these from Zenoh's threads
            for kind in ("cloud", "pose"):
                self._replies.pop(self.keys.object(object_id, kind), None)
        self.link.put(self.keys.object(object_id, "gone"), Gone(v=VERSION, stamp_ns=self.clock.stamp_ns(),
                                                               object_id=object_id, epoch=self.epoch, seq=self._next()))

    def _refuse(self, object_id: str) -> None:
        """Take an object just swapped in back out: out of every collision at once (it would push its neighbours
        apart before the edit that removes it compiles), then out of the model. Nothing of it was published."""
        model = self.twin.model
        body = model.body(object_id).id
        geoms = np.flatnonzero(model.geom_bodyid == body)
        model.geom_contype[geoms] = 0
        model.geom_conaffinity[geoms] = 0
        self.twin.edit_async(lambda spec: remove_object(spec, object_id))

    def _remember(self, spec: ObjectSpec, obj: TwinObject) -> None:
        mesh = source_mesh(spec)
        mesh.apply_translation(-obj.estimate.mass.center_of_mass)  # the body frame: origin at the COM
        self._objects[spec.id] = _Truth(spec, obj, mesh)

    def _settle(self, limit: float) -> float:
        """Step until nothing moves (or ``limit`` simulated seconds): returns the time it took.

        A scene file places objects, it does not promise they rest there (the paper's stack topples);
        a sensor sees a scene at rest, and a twin built from a toppling object's first cloud would be
        snapped along its fall at every keyframe.
        """
        check = 50
        while self.twin.time < limit:
            self.twin.step(check)
            if float(np.abs(self.twin.data.qvel).max(initial=0.0)) < SETTLED_SPEED:
                break
        return self.twin.time

    def _publish_moved(self) -> None:
        """Publish every object whose sensed frame left the deadband since its last publication.

        One check over all objects' arrays at once: the deadband is asked about every object at every step
        and passed by a few, so only those are asked for a full track (velocity included). A sensor without
        :meth:`scenes.sensing.PoseSensor.poses` gives a full track of each object, as it always did.
        """
        ids = list(self._objects)
        if not ids:
            return
        tracks = None
        poses = getattr(self.sensor, "poses", None)
        if poses is not None:
            pos, quat = poses(self, ids)
        else:
            tracks = [self.sensor.track(self, i) for i in ids]
            pos = np.array([t.position for t in tracks], dtype=float).reshape(-1, 3)
            quat = np.array([t.quat for t in tracks], dtype=float).reshape(-1, 4)
        last = self._last_published(ids)
        # Batched matmul, not einsum: row by row it sums as np.linalg.norm and np.dot do on one vector,
        # so each object's decision is bit for bit the one the per-object check made.
        gap = pos - last.position
        moved = np.sqrt(np.matmul(gap[:, None, :], gap[:, :, None])[:, 0, 0])
        cos_half = np.fmin(1.0, np.abs(np.matmul(quat[:, None, :], last.quat[:, :, None])[:, 0, 0]))
        turned = 2 * np.degrees(np.arccos(cos_half))  # as twin.poses.angle_deg (fmin: as its min on NaN)
        still = (moved <= self.deadband.position) & (turned <= self.deadband.angle_deg) & last.known
        if self._unseen:  # asked every step: found again, it is published at once, moved or not
            still &= ~np.isin(ids, list(self._unseen))
        if tracks is not None and not all(t.seen for t in tracks):  # and lost: said at once, not at a keyframe
            still &= ~np.array([not t.seen for t in tracks])
        for k in np.flatnonzero(~still):
            self._publish_pose(ids[k], track=None if tracks is None else tracks[k])

    def _last_published(self, ids: list[str]) -> _Published:
        """The last published poses of ``ids`` as arrays, rebuilt only when the objects change."""
        rows = self._rows
        if rows is None or rows.ids != ids:
            rows = self._rows = _Published.of(ids, self._published)
        return rows

    def _publish_pose(self, object_id: str, *, track: Track | None = None) -> None:
        """Publish the object's pose now (the deadband is the caller's: :meth:`_publish_moved`).

        When the sensor has lost the object, that is said once (``Pose.seen`` False, the last pose seen) and
        nothing more is published of it until it is found: the twin simulates it alone meanwhile, rather
        than being pulled back to, or held at, where it was last seen. Nothing is published of an object whose
        cloud is held back (:meth:`publish_cloud`).
        """
        if object_id in self._withheld:
            return  # no cloud yet: a pose of it would be of nothing the twin knows (and not a sensed one)
        seen = self.sensor.track(self, object_id) if track is None else track
        if not seen.seen:
            if object_id in self._unseen:
                return
            self._unseen.add(object_id)
            self.unseen_reports += 1
        else:
            self._unseen.discard(object_id)
        pos, quat = seen.position, seen.quat
        self._published[object_id] = (pos, quat)
        if self._rows is not None:
            self._rows.update(object_id, pos, quat)
        # A pose measured earlier (a camera scan) answers to the operator's input of then: while commands
        # stream, the answered time runs with the clock, so it is the answer now less the measurement's age.
        age = 0.0 if seen.time is None else max(0.0, self.twin.time - seen.time)
        answers = self._answers_ns()
        msg = Pose(v=VERSION, stamp_ns=self.clock.stamp_ns(), object_id=object_id, epoch=self.epoch, seq=self._next(),
                   sim_time=self.twin.time - age, position=_floats(pos), quat=_floats(quat), linvel=_floats(seen.linvel),
                   angvel=_floats(seen.angvel), answers_ns=max(0, answers - round(age * 1e9)) if answers else 0,
                   position_sigma=float(seen.position_sigma), angle_sigma=min(float(seen.angle_sigma), MAX_ANGLE_SIGMA),
                   seen=seen.seen)
        key = self._pose_keys.get(object_id)
        if key is None:
            key = self._pose_keys[object_id] = self.keys.object(object_id, "pose")
        data = self.link.put(key, msg)
        with self._lock:
            self._replies[key] = data
        self.pose_updates += 1

    def _replies_snapshot(self) -> list[tuple[str, bytes]]:
        with self._lock:
            items = list(self._replies.items())
        # Clouds first: a pose is only useful to a twin that knows the object.
        return sorted(items, key=lambda kv: not kv[0].endswith("/cloud"))

    def _on_operator(self, _key: str, msg) -> None:  # type: ignore[no-untyped-def]
        """Take the operator's command if it is newer and in the workspace (see the class docstring)."""
        if not isinstance(msg, OperatorCommand):
            return
        now, position = self.clock.now(), np.asarray(msg.position, dtype=float)
        low, high = self._workspace
        with self._lock:  # the transport's threads
            if not self._commands.newer("operator", msg.epoch, msg.seq, now):
                self.operator_dropped["out-of-order"] += 1
                return
            if not (np.all(position >= low) and np.all(position <= high)):
                self.operator_dropped["out-of-workspace"] += 1
                self._dropped_log.warning("out-of-workspace", "dropped an operator command outside the workspace: %s",
                                          position.tolist())
                return
            self._commands.take("operator", msg.epoch, msg.seq, now)
            self._operator = position
            self._command = (msg.stamp_ns, self.clock.stamp_ns())

    def _answers_ns(self) -> int:
        """:attr:`sync.messages.Pose.answers_ns` now: the twin's time whose operator input C has applied."""
        if self._command is None:
            return 0
        stamp, arrived = self._command
        # A command stamped near the int64 limit (forged, or a broken clock) must not push every later pose
        # past it, where the twin refuses them all: clamped, the twin finds no such moment and compares now.
        return min(MAX_INT64, max(0, stamp + self.clock.stamp_ns() - arrived))

    def _scene_info(self) -> SceneInfo:
        t, ee = self.scene.table, self.scene.end_effector
        return SceneInfo(v=VERSION, stamp_ns=self.clock.stamp_ns(), name=self.scene.name,
                         table_size=None if t is None else _floats(t.size), table_height=0.0 if t is None else t.height,
                         table_material="" if t is None else t.material,
                         ee_radius=0.0 if ee is None else ee.radius,
                         ee_position=(0.0, 0.0, 0.0) if ee is None else _floats(ee.position),
                         workspace_min=None if self.scene.workspace is None else _floats(self.scene.workspace[0]),
                         workspace_max=None if self.scene.workspace is None else _floats(self.scene.workspace[1]))

    def _next(self) -> int:
        self._seq += 1
        return self._seq


def _floats(values) -> tuple[float, ...]:  # type: ignore[no-untyped-def]
    """Plain floats for the encoder (it takes no numpy scalars); ``tolist`` converts in one call."""
    return tuple(np.asarray(values, dtype=np.float64).tolist())


@dataclass
class _Published:
    """The last published pose of each object as rows: what the deadband check compares with every step.

    ``known`` is False for an object never published (it is published at once)."""

    ids: list[str]
    index: dict[str, int]
    position: np.ndarray  # (n, 3) metres, world frame
    quat: np.ndarray  # (n, 4) w x y z
    known: np.ndarray  # (n,) bool

    @classmethod
    def of(cls, ids: list[str], published: dict[str, tuple[np.ndarray, np.ndarray]]) -> _Published:
        rows = cls(list(ids), {i: k for k, i in enumerate(ids)}, np.zeros((len(ids), 3)), np.zeros((len(ids), 4)),
                   np.zeros(len(ids), dtype=bool))
        for object_id, (pos, quat) in published.items():
            rows.update(object_id, pos, quat)
        return rows

    def update(self, object_id: str, position: np.ndarray, quat: np.ndarray) -> None:
        k = self.index.get(object_id)
        if k is not None:
            self.position[k], self.quat[k], self.known[k] = position, quat, True
