"""The twin's runtime: C', the simulation the operator touches, kept in step with the remote over the wire.

It talks to the wire through a :class:`sync.link.Link` over any :class:`sync.transport.Transport`, and
reads time only from its :class:`sync.clock.Clock`. Live (``workers >= 1``), nothing blocks the loop: the
transport's threads only queue decoded messages; estimation and CoACD run in worker processes; the new
model compiles in a background thread (:meth:`twin.sim.Twin.edit_async`) and is swapped in between two
steps. Headless (``workers = 0``), the same work runs in the loop's thread, so a run on a simulated clock
is deterministic. Pose corrections blend in over ``correction_tau`` unless they are large, in which case
the object is moved at once. Between corrections, an object the remote reports at rest and the operator
leaves alone is held at the remote's pose (:mod:`twin.hold`).

Ordering: each ordered message carries the remote's ``(epoch, seq)``. Newer beats older per object; a
restarted remote (larger epoch) is followed at once. A heartbeat states the remote's counter now, so
a mark past two heartbeats in a row (a forged or corrupted sequence number) is pulled back to the second:
it cannot silence the real remote for longer than two heartbeat periods. One past a single heartbeat is
left alone: an honest message sent after that heartbeat can overtake it on a reordering link. Only a
heartbeat newer than the last one taken counts (a late or replayed one would reopen the window for older
messages); that mark expires as a device's does, so a forged heartbeat cannot disable this for longer
than :data:`sync.ordering.MARK_EXPIRY`. A device driver's targets have no
heartbeat: each device's mark expires :data:`sync.ordering.MARK_EXPIRY` seconds after the last target taken
from it, so a forged one cannot freeze the device for longer (:mod:`sync.ordering`).

Bad input: the link drops what decoding refuses (:mod:`sync.link`); a message that passes and still makes its
handling fail is dropped too, counted in the same counter as ``"handler-error"`` and logged with its traceback
(rate-limited), and the loop goes on.
"""

from __future__ import annotations

import logging
import math
import multiprocessing as mp
import os
import queue
import threading
from collections import Counter
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal, overload

import numpy as np

from estimation import PhysicalEstimate, estimate, make_cloud
from estimation.errors import TwinError
from estimation.materials import resolve_density
from sync.clock import REAL_CLOCK, Clock
from sync.keys import Keys, any_scene_info
from sync.link import Link
from sync.messages import (
    MAX_FORCE,
    VERSION,
    Cloud,
    Gone,
    Heartbeat,
    OperatorCommand,
    OperatorForce,
    OperatorTarget,
    Pose,
    SceneInfo,
    decode,
    encode,
    unpack_completed,
    unpack_normals,
    unpack_points,
)
from sync.ordering import Marks
from sync.ratelimit import RateLimitedLog
from sync.recording import Recorder
from sync.transport import Transport
from twin.debuglog import OFF, DebugLog, display_subset
from twin.decompose import DEFAULT_SETTINGS, CoacdSettings
from twin.history import CORRECTION, STATE, History
from twin.hold import DEFAULT_HOLD, Hold, HoldSettings
from twin.loop import LoopStats, run_loop, steps_per_iteration
from twin.model import (
    OPERATOR_REACH,
    RESERVED_IDS,
    SCENE_REACH,
    EndEffectorSpec,
    TableSpec,
    add_object,
    has_object,
    new_spec,
    reach_corners,
    remove_object,
)
from twin.objects import DEFAULT_FRICTION, TwinObject, lowest_point, object_at_estimate
from twin.poses import from_rotvec, quat_conj, quat_mul, quat_product, rotation, to_rotvec
from twin.samples import Samples
from twin.settings import MAX_RATE_HZ, MAX_WORKERS, check_number, check_type
from twin.sim import Twin
from twin.trajectory import Trajectory
from twin.workers import background_worker

log = logging.getLogger(__name__)


class SyncError(TwinError, RuntimeError):
    """The twin could not join a scene: none answered, or several did (a :class:`TwinError`, so every command
    says it in one line, exit 2)."""


@dataclass(frozen=True)
class LocalSettings:
    """How the twin follows the remote.

    Attributes:
        stale_after: seconds without any message before the link is marked stale.
        correction_tau: time constant of the blend towards a corrected pose, seconds.
        align_window: seconds of the twin's past kept to compare C's poses with C' at the moment they
            answer to (:mod:`twin.history`): at least the longest round trip; 0 compares them with C' now.
        snap_distance, snap_angle_deg: a correction larger than this moves the object at once.
        operator_deadband: the operator's command is published when it moved more than this, metres.
        workers: processes estimating clouds; 0 estimates and compiles in the loop's own thread
            (headless runs: slower per object, but deterministic).
        hold: when an undisturbed object is pinned to the remote's pose (:mod:`twin.hold`).
        defer_touched: leave objects the operator is touching (and those touching them) to the twin's
            physics until ``hold.after`` seconds after release, instead of pulling them towards C's
            round-trip-old pose (needs the hold's contact tracking: off with the hold).
        mass_scale: every estimate's density is multiplied by this, so mass and inertia scale together
            (the experiments' stand-in for a wrong mass estimate; 1: the estimate as it is).
    """

    stale_after: float = 1.0
    correction_tau: float = 0.02
    align_window: float = 1.0
    snap_distance: float = 0.05
    snap_angle_deg: float = 20.0
    operator_deadband: float = 0.0002
    workers: int = 1
    hold: HoldSettings = DEFAULT_HOLD
    coacd: CoacdSettings = DEFAULT_SETTINGS
    cache_dir: Path | None = None
    mass_scale: float = 1.0
    defer_touched: bool = True

    def __post_init__(self) -> None:
        """Refuse what the twin cannot follow a remote with, before a session starts.

        Raises:
            SettingsError: a time, distance or angle NaN, infinite, negative or past its bound below (0 for
                ``stale_after`` and ``correction_tau``); ``workers`` not a whole number from 0 to
                :data:`twin.settings.MAX_WORKERS`; ``mass_scale`` outside :data:`MASS_SCALE_RANGE`; ``hold``,
                ``coacd``, ``cache_dir`` or ``defer_touched`` of the wrong type.
        """
        # Any finite silence means something (a long one: the link is never marked stale).
        check_number(self, "stale_after", low_ok=False)
        # 0 divided by zero; a time constant past MAX_CORRECTION_TAU leaves corrections unfinished for ever.
        check_number(self, "correction_tau", low_ok=False, high=MAX_CORRECTION_TAU)
        check_number(self, "align_window", high=MAX_ALIGN_WINDOW)  # 0: compare with C' now
        # Any finite distance means something (past the scene's size: never snap, never publish).
        check_number(self, "snap_distance")
        check_number(self, "operator_deadband")
        check_number(self, "snap_angle_deg", high=180.0)  # two orientations are at most 180 degrees apart
        check_number(self, "workers", high=MAX_WORKERS, whole=True)
        low, high = MASS_SCALE_RANGE
        check_number(self, "mass_scale", low=low, high=high)
        check_type(self, "hold", HoldSettings, "a HoldSettings")
        check_type(self, "coacd", CoacdSettings, "a CoacdSettings")
        check_type(self, "cache_dir", (str, os.PathLike, type(None)), "a folder path or None")
        check_type(self, "defer_touched", bool, "True or False")


#: Twin mass / true mass ``LocalSettings.mass_scale`` and an experiment's conditions may ask for: a twin a
#: hundred times off is no twin, and far below it MuJoCo refuses the bodies (1e-300 made every step fail
#: while the sweep went on; 0 or a negative one left the twin empty, an error logged per object).
MASS_SCALE_RANGE = (0.01, 100.0)

#: The longest ``LocalSettings.correction_tau``, seconds: a blend slower than a minute never lands between
#: the remote's keyframes (one a second), so the twin would follow nothing.
MAX_CORRECTION_TAU = 60.0

#: The longest ``LocalSettings.align_window``, seconds: ten times the default, past any round trip a twin can
#: be operated through. The history keeps 200 bytes per object per step: 10 s at 1 kHz is 2 MB an object
#: (1e7 s asked for 74.5 GiB at once).
MAX_ALIGN_WINDOW = 10.0

DEFAULT_LOCAL = LocalSettings()




@dataclass(frozen=True)
class OperatorSettings:
    """The operator's device on the wire: targets in, force out (keys in :mod:`sync.keys`).

    Attributes:
        listen: follow :class:`sync.messages.OperatorTarget` messages on ``operator/target`` (a device
            driver) whenever :meth:`Local.iterate` is given no trajectory; newest ``(epoch, seq)`` per
            device wins, a device's mark lasting :data:`sync.ordering.MARK_EXPIRY` seconds after its last
            target taken (so no forged sequence number freezes a device for longer); the latest of any
            device is applied.
        force_rate: :class:`sync.messages.OperatorForce` messages per second of twin time on
            ``operator/force``; 0 publishes none. At or above the loop rate: one per step.
        reach: how far beyond the table's edges (and above its top) a target may be, metres; without a
            table, around the end effector's start. Targets outside are dropped and counted.
    """

    listen: bool = False
    force_rate: float = 0.0
    reach: float = OPERATOR_REACH

    def __post_init__(self) -> None:
        """Refuse a rate or reach the twin cannot use (NaN published no force and took no target, unsaid).

        Raises:
            SettingsError: ``listen`` not a bool; ``force_rate`` outside 0 .. :data:`twin.settings.MAX_RATE_HZ`; ``reach``
                outside 0 .. :data:`twin.model.SCENE_REACH`.
        """
        check_type(self, "listen", bool, "True or False")
        check_number(self, "force_rate", high=MAX_RATE_HZ)
        # Targets beyond the scene's own reach are beyond every object the twin keeps (poses there are dropped).
        check_number(self, "reach", high=SCENE_REACH)


NO_OPERATOR_IO = OperatorSettings()

#: Multiplies a w x y z quaternion into its inverse (unit quaternions).
_CONJUGATE = np.array([1.0, -1.0, -1.0, -1.0])


#: A correction is done (what is left of it dropped) under this distance, metres, and angle, degrees.
DONE_DISTANCE, DONE_ANGLE_DEG = 2e-4, 0.1


def _norms(rows: np.ndarray) -> np.ndarray:
    """Euclidean norm of each row of ``rows`` (n, k) (np.linalg.norm's axis handling costs more than this)."""
    return np.sqrt(np.einsum("ij,ij->i", rows, rows))


def _squared_norms(error: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Squared lengths of the position (m) and rotation (rad) parts of correction rows (n, 12), in one pass."""
    both = np.einsum("nij,nij->in", error[:, :6].reshape(-1, 2, 3), error[:, :6].reshape(-1, 2, 3))
    return both[0], both[1]


#: Slack when comparing twin time with the next force publication: step times are float sums.
_TIME_SLACK = 1e-6


@dataclass
class LocalReport:
    """What the local side saw. Latencies in seconds."""

    objects_synced: int = 0
    pose_updates: int = 0
    pose_latency: list[float] = field(default_factory=Samples)  # a uniform subsample past a million (twin.samples)
    add_latency: list[float] = field(default_factory=list)  # cloud received -> touchable in the twin
    # id -> (seconds from the cloud's publish stamp, seconds from its arrival) to touchable, latest cloud
    touchable_after: dict[str, tuple[float, float]] = field(default_factory=dict)
    worst_step_while_adding: float = 0.0
    stale_events: int = 0
    recoveries: int = 0
    resyncs: int = 0  # state queries asked again: a restarted remote, or heartbeats counting objects the twin lacks
    estimation_errors: int = 0
    worker_retries: int = 0  # clouds estimated again because their worker process died
    clouds_superseded: int = 0  # estimations cancelled before they started: a newer cloud of the object came
    poses_superseded: int = 0  # poses skipped unhandled: a newer pose of the object was queued with them
    failed_edits: int = 0  # objects whose model did not compile: the twin went on without them
    out_of_order: int = 0  # messages older than what the twin already had from the remote
    stamps_off: int = 0  # poses whose stamp is outside LATENCY_RANGE of the twin's clock: applied, not in pose_latency
    out_of_scene: int = 0  # poses and clouds placed outside the scene's box (its workspace, or SCENE_REACH around the table)
    unseen: int = 0  # times the remote's sensor lost an object (Pose.seen False): the twin simulated it alone
    holds: int = 0  # times an object strayed from the remote's pose on its own and was pinned to it
    snaps: int = 0  # corrections too large to blend in: the object was moved at once
    # objects added or replaced whose estimate came with warnings (each logged once, naming it; the warnings and
    # the volume interval stay with the object: Local.twin_object)
    warned_objects: int = 0
    operator_targets: int = 0  # device targets taken (OperatorSettings.listen)
    # reason -> device targets dropped after decoding: "out-of-workspace", "out-of-order" (another message on
    # the target key is the link's "wrong-key")
    operator_dropped: Counter = field(default_factory=Counter)
    forces_sent: int = 0  # OperatorForce messages published
    # kind -> entries forgotten to bound memory: "pose" (ids with a pose and no cloud, past MAX_ORPHAN_POSES),
    # "device" (device marks, past sync.ordering.MAX_SENDERS)
    evicted: Counter = field(default_factory=Counter)
    # id -> |twin - remote| position, metres, every DIVERGENCE_EVERY seconds of twin time while both are known
    # (each a twin.samples.Samples: a uniform subsample past a million)
    divergence: dict[str, list[float]] = field(default_factory=dict)


#: Ids the twin keeps a pose of while it has no cloud of them (no body, none being estimated): a pose may come
#: just before its object's cloud and is used when the object arrives, but poses for ids that never get a cloud
#: (forged, or a remote's mistake) must not grow memory without limit. Past this many, the oldest is forgotten.
MAX_ORPHAN_POSES = 1024

#: Objects the twin takes at once (in it, or being estimated or compiled): as many as a scene file may hold
#: (:data:`scenes.scenefile.MAX_OBJECTS`). Each costs an estimate in a worker and a body in the model, so clouds of
#: ever new ids (forged, or a remote's bug) must not queue estimates and grow the model without limit: past it,
#: a cloud of a new id is dropped and counted (``"too-many-objects"``); one of an object the twin has is taken.
MAX_OBJECTS = 1000

#: Points of clouds waiting for estimation at once (all objects). Each waits with its message and an encoded
#: copy for its worker: 40 forged clouds of 5 M points took 1 GB and held a honest cloud behind them for the
#: minutes their estimates took. Past it a cloud is dropped and counted (``"too-much-pending"``); the state query
#: asked again while heartbeats count objects the twin lacks brings it later. A scene of a thousand 30k-point
#: objects waits within it.
MAX_PENDING_POINTS = 40_000_000

#: Messages the transport's threads may queue for the loop at once. The loop drains them every step; a flood
#: faster than it handles them (49,000 heartbeats a second once stood the loop still for 25 s) must not grow
#: memory without limit: past this many, a message arriving is dropped and counted (``"inbox-full"``). An
#: honest remote sends a few hundred a second.
MAX_INBOX = 65_536

#: Messages one loop iteration takes from the inbox; the rest wait for the next. Each costs the loop a few
#: microseconds at least (a flood of valid Gones for new ids, 65,536 queued: 1.5 s in one step, 0.4 s once
#: such Gones cost nothing), so a full inbox taken at once stood the loop still. An honest remote sends a few
#: a step; a late joiner's state reply a few hundred, taken over a few steps.
MAX_DRAIN = 256

#: Ids the twin remembers the removal of (the ``(epoch, seq)`` of their :class:`Gone`), so that an older cloud or
#: pose of them does not bring the object back: the late-join reply, taken before the removal, can arrive after
#: the live Gone, and the remote sends no second Gone. Past this many, the oldest removal is forgotten.
MAX_GONE = 1024

#: A pose's age (the twin's clock less the sender's ``stamp_ns``, seconds) counts as a latency only within this
#: range: clocks of two machines that agree to within a second, and a link slower than a minute is no link.
#: Outside it the stamp is broken or forged (a stamp of 0 read as a 56-year latency and set the report's p99);
#: the pose is still applied (order is by ``(epoch, seq)``), and the stamp counted (``LocalReport.stamps_off``).
LATENCY_RANGE = (-1.0, 60.0)

#: Seconds after a state query before the twin asks again while the remote's heartbeats count more objects than
#: it knows (a query refused by the remote's budget, clouds published while the link was down), doubling each
#: time up to ``RESYNC_MAX_S``: a remote that withholds objects (cameras that have not seen them) is asked
#: rarely. A heartbeat of a new epoch (a restarted remote) asks at once.
RESYNC_FIRST_S, RESYNC_MAX_S = 1.0, 60.0

#: Older remotes' epochs (heartbeats still coming from an epoch older than the one followed) that each make the
#: twin ask the newest remote's state once; forged heartbeats of ever new old epochs stop asking past this.
MAX_OLDER_EPOCHS = 16


@dataclass(frozen=True)
class _StateAnswered:
    """Queued after a state query's replies: the epoch asked of, whether anything answered, and the ids of the
    clouds that came (what a restarted remote still holds)."""

    epoch: int
    answered: bool
    ids: frozenset[str]


#: How often (twin time, seconds) the report samples each object's divergence from the remote.
DIVERGENCE_EVERY = 0.01


def build_from_cloud(data: bytes, coacd: CoacdSettings, cache_dir: Path | None,
                     display: bool = False, mass_scale: float = 1.0,
                     floor: float | None = None) -> tuple[TwinObject, np.ndarray | None]:
    """Worker-process job: a cloud message's bytes -> a twin object at the estimated place, lifted clear of
    the support at height ``floor`` (metres; None: not lifted; see :func:`clear_of_support`).

    With ``display``, also a subset of the cloud (world frame at capture) for the rerun view, so the
    loop's process never unpacks a cloud.
    """
    from estimation.views import on_support, plane_from_abcd, with_completion

    msg = decode(data)
    assert isinstance(msg, Cloud)
    density, mat = resolve_density(msg.material, msg.density)  # an unknown material raises: no guess
    density *= mass_scale  # uniform density: mass and inertia scale together
    points = unpack_points(msg)
    # A camera's normals, turned towards the camera that saw each point, say which side is out where the
    # points alone do not (a thin part, a partial view closed by completion).
    normals, completed = unpack_normals(msg), unpack_completed(msg)
    est = estimate(make_cloud(points, normals), density, material=None if mat is None else mat.name)
    if msg.support is not None:  # nothing of it lies below the plane it was closed on
        est = on_support(est, plane_from_abcd(msg.support), points=points)
    if completed is not None:  # what the sender added where no sensor saw: the interval rests on the rest
        est = with_completion(est, points, completed, normals=normals)
    friction = DEFAULT_FRICTION if mat is None else mat.friction
    obj = object_at_estimate(msg.object_id, est, friction, coacd=coacd, cache_dir=cache_dir)
    if floor is not None:
        obj = clear_of_support(obj, floor)
    return obj, display_subset(points) if display else None


def _kept(obj: TwinObject) -> TwinObject:
    """``obj`` with its estimate but for the full reconstruction (vertices and faces left empty; ``obj.visual``
    is what the twin draws and decomposed) and the points it was built from (None): what the twin keeps of an
    object while it is in it (:meth:`Local.twin_object`). A 30k-point box's whole estimate takes 3.1 MB, all
    but a few kB of it those arrays; its mass properties, warnings and volume interval stay."""
    est = obj.estimate
    return replace(obj, estimate=replace(est, vertices=np.empty((0, 3)), faces=np.empty((0, 3), np.int64),
                                         points=None, normals=None))


def estimate_note(est: PhysicalEstimate) -> str:
    """One line of what the twin says of an estimate that came with warnings: its mass and volume, the interval
    the cloud cannot tell the volume from, and the warnings (joined by `` | ``: a warning may hold a ``;``)."""
    bounds = est.volume_bounds_m3
    known = "" if bounds is None else f" (known only to {bounds[0]:.3g}..{bounds[1]:.3g} m^3)"
    return f"{est.mass.mass:.3g} kg, volume {est.volume:.3g} m^3{known}: " + " | ".join(est.warnings)


def clear_of_support(obj: TwinObject, floor: float) -> TwinObject:
    """``obj`` lifted out of the support (table top or floor) at height ``floor``, metres, if what collides
    reaches into it.

    An estimated surface can bulge a few cells past the true one; placed where the remote body rests, its
    hulls would start inside the table and be shot out. The lift becomes part of the object's offset, so
    later corrections keep it. Under a collision primitive only the primitive counts: lifting by the hulls'
    fringe held a box 3.4 mm above the table, pinned there by every later correction.
    """
    lowest = lowest_point(obj)
    if obj.position[2] > floor > lowest - 0.01:
        lift = floor - lowest + 0.0005
        if lift > 0:
            return replace(obj, position=obj.position + np.array([0.0, 0.0, lift]))
    return obj


class Local:
    """The twin C' on a transport. Call :meth:`run` (or :meth:`iterate` from your own loop)."""

    def __init__(self, transport: Transport, *, clock: Clock = REAL_CLOCK, scene: str | None = None,
                 settings: LocalSettings = DEFAULT_LOCAL, wait: float = 10.0, rlog: DebugLog = OFF,
                 operator: OperatorSettings = NO_OPERATOR_IO, recorder: Recorder | None = None) -> None:
        self.settings = settings
        self.operator = operator
        self.recorder = recorder  # logs the targets applied and the force felt (the transport logs the wire)
        self.rlog = rlog
        self.clock = clock
        self.link = Link(transport, clock)
        self.dropped_log = RateLimitedLog(log, clock)  # per reason: a flood of bad input, a few log lines
        self.report = LocalReport()
        info = self._find_scene(scene, wait)
        self.keys = Keys(info.name)
        self.twin = Twin(_empty_spec(info), background=settings.workers > 0)
        self._floor = info.table_height if info.table_size is not None else 0.0
        self.workspace = reach_box(info, operator.reach)
        self.scene_box = _scene_box(info)
        self._box: tuple[object, list[float], list[float]] = (None, [], [])  # scene_box as floats, see _in_scene
        if info.table_size is not None:
            rlog.table(info.table_size, info.table_height)
        self._dropped_seen = 0
        self._heartbeats = Marks()  # the remote's newest heartbeat taken ("remote"), expiring (module docstring)
        # (which marks, object id) -> a mark found past the last heartbeat taken; pulled back if past the next too
        self._beyond: dict[tuple[int, str], tuple[int, int]] = {}
        self.inbox: queue.SimpleQueue = queue.SimpleQueue()
        self.stale = False
        self._jobs: dict[str, tuple[Future, Cloud, float]] = {}
        # (id, epoch, seq) of clouds whose worker died once: by id too, as a forged cloud may reuse another's seq
        self._retried: set[tuple[str, int, int]] = set()
        self._clouds: dict[str, tuple[int, int]] = {}  # id -> (epoch, seq) of the cloud in (or going into) the twin
        # id -> (epoch, seq) of its cloud the twin could not take (estimate, scene, compile): a state query asked
        # again sends it again, and it is not estimated again (a later cloud of the object is)
        self._refused: dict[str, tuple[int, int]] = {}
        self._offsets: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._taken: dict[str, TwinObject] = {}  # id -> the object as it went into the twin (twin_object)
        self._latest: dict[str, Pose] = {}
        self._unseen: set[str] = set()  # objects the remote's sensor has lost (Pose.seen False)
        self._pose_mark: dict[str, tuple[int, int]] = {}  # id -> (epoch, seq) of the newest pose taken
        self._orphans: dict[str, None] = {}  # ids with a pose and no cloud, oldest first (MAX_ORPHAN_POSES)
        self._gone: dict[str, tuple[int, int]] = {}  # id -> (epoch, seq) of its Gone, oldest first (MAX_GONE)
        self._targets: dict[str, Pose] = {}  # id -> its newest pose from C, until measured (_measure)
        self._errors: dict[str, tuple[np.ndarray, bool]] = {}  # id -> (correction left (12,), snap it)
        self._history = History(round(settings.align_window / self.twin.model.opt.timestep))
        # Within two steps of a recorded one: a stamp between steps, never one from outside the window.
        self._align_tolerance = round(2e9 * self.twin.model.opt.timestep)
        self._blend = 1.0 - float(np.exp(-self.twin.model.opt.timestep / settings.correction_tau))  # a step's share
        self._history_for: tuple[object, int] = (None, 0)  # (model, objects) the history's rows were made for
        self._history_index: tuple[np.ndarray, np.ndarray] | None = None  # their body and qvel indices
        # id -> (pose message, offset, its pose on the twin's body, the row _measure reads): the newest pose is
        # read again by the hold, the divergence samples and the debug log, so it is mapped once per message.
        self._mapped: dict[str, tuple[Pose, tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray],
                                      np.ndarray]] = {}
        self._to_correct: list[str] = []  # objects whose new pose is measured at the next flush (_measure)
        # per model: ids -> (body ids, (n, 7) qpos and (n, 6) qvel indices); the same objects are corrected
        # step after step until they reach their targets
        self._rows: tuple[object, dict[tuple[str, ...], tuple[np.ndarray, np.ndarray, np.ndarray]]] = (None, {})
        self.hold = Hold(settings.hold, tau=settings.correction_tau)
        self._next_sample = 0.0
        self._sent_operator: np.ndarray | None = None
        self._seq = 0
        self._epoch = clock.stamp_ns()  # of the operator commands this twin sends
        self.device_target: np.ndarray | None = None  # the latest device target taken (OperatorSettings.listen)
        self._device_marks = Marks()  # newest (epoch, seq) per device, expiring (sync.ordering)
        self._force_every = None if operator.force_rate <= 0 else 1.0 / operator.force_rate
        self._next_force = 0.0
        self._force_seq = 0
        self._pool = self._new_pool()
        self.link.subscribe(self.keys.objects, self._enqueue)
        self.link.subscribe(self.keys.heartbeat, self._enqueue)
        if operator.listen:
            self.link.subscribe(self.keys.operator_target, self._enqueue)
        # A late joiner asks for the current scene: every cloud and pose the remote last published.
        self._state_wait = wait
        self._remote_epoch: int | None = None  # of the newest heartbeat taken
        self._resync_at = clock.now() + RESYNC_FIRST_S
        self._resync_every = RESYNC_FIRST_S
        self._resyncing: threading.Thread | None = None
        self._older: set[int] = set()  # epochs of older remotes whose heartbeats still come (MAX_OLDER_EPOCHS)
        self.link.query(self.keys.state, self._enqueue, timeout=wait)
        self._start = clock.now()
        # Start estimating what the query brought before the loop runs: all of it, MAX_DRAIN at a time (taken
        # 256 at most, a 300-object scene's joiner counted 256 clouds to wait for).
        for _ in range(-(-self.inbox.qsize() // MAX_DRAIN)):
            self._drain()

    # -- loop ----------------------------------------------------------------------------------------

    def run(self, duration: float, *, rate: float = 1000.0, trajectory: Trajectory | None = None,
            until=None) -> LoopStats:  # type: ignore[no-untyped-def]
        """Run the twin for ``duration`` seconds of its clock, or until ``until()`` is true.

        ``trajectory(t) -> (3,)`` is the operator's end-effector target at twin time t (None: hold).
        On a real clock the loop waits on incoming messages between steps, so a pose correction is
        applied when it arrives, not at the next step. Each of the ``rate`` iterations a second is a whole
        number of :meth:`iterate` calls, one physics step each (:func:`twin.loop.steps_per_iteration`), so
        ``duration`` is simulated seconds too.
        """
        rate, steps = steps_per_iteration(rate, float(self.twin.model.opt.timestep))

        def body() -> None:
            busy = self.adding
            t0 = self.clock.now()
            for _ in range(steps):
                self.iterate(trajectory)
            if busy:
                self.report.worst_step_while_adding = max(self.report.worst_step_while_adding, self.clock.now() - t0)

        return run_loop(body, rate=rate, duration=duration, clock=self.clock, until=until,
                        wait=self._wait if self.clock.realtime else None)

    def _wait(self, left: float) -> None:
        """Handle messages as they arrive until ``left`` seconds from now (a real clock's wait)."""
        deadline = self.clock.now() + left
        while left > 0:
            try:
                item = self.inbox.get(timeout=left)
            except queue.Empty:
                return
            self._handle_safely(*item)
            self._flush_corrections()
            left = deadline - self.clock.now()

    def iterate(self, trajectory=None) -> None:  # type: ignore[no-untyped-def]
        """One loop iteration: handle messages, take finished objects, correct poses, step once.

        The operator's target is ``trajectory(twin time)`` (None from it: no new target), else with
        :attr:`OperatorSettings.listen` the latest device target; the end effector stays where it is
        without either. After the step, the force is published when due (:attr:`OperatorSettings.force_rate`).
        """
        self._drain(correct=False)
        if self._jobs or self.twin.edits_pending:
            # A new model may be swapped in below, carrying the state over: correct towards the poses that
            # arrived first, on the model they arrived for.
            self._flush_corrections()
        self._collect()
        self.twin.poll()
        self._flush_corrections()
        if self._errors:
            # C's pose of an object in the operator's hand answers to the operator's input of a round trip
            # ago; measured against C' then (twin.history), it is right, but a wrong estimate makes it
            # differ, and pulling the object towards it is felt. Such objects follow the twin's physics
            # until released; C's later poses then correct them.
            touched = self.hold.disturbed(self.twin.time) if self.settings.defer_touched else set()
            self._apply_corrections([i for i in self._errors if i not in touched])
        target = self._operator_target(trajectory)
        if target is not None:
            self.twin.set_end_effector(target)
            self._publish_operator(target)
            if self.recorder is not None:
                self.recorder.target(self.twin.time, target)
        for object_id in self.hold.apply(self.twin):
            self.report.holds += 1
            if self.rlog.enabled:
                self.rlog.event(self.twin.time, f"{object_id}: strayed from the remote's pose on its own; held there")
        self.twin.step()
        self._remember()
        self._feedback()
        if self.twin.time >= self._next_sample:
            self._next_sample = self.twin.time + DIVERGENCE_EVERY
            self._sample_divergence()
        if self.rlog.due(self.twin.time):
            self.rlog.frame(self.twin, remote={i: self.remote_pose(i) for i in self._offsets})
        self._check_link()

    def _drain(self, *, correct: bool = True) -> None:
        """Handle the messages queued now; the poses they bring are corrected towards in one batch at the end
        (``correct=False``: left to the caller, see :meth:`iterate`).

        At most :data:`MAX_DRAIN` are taken; the rest, and messages arriving meanwhile, wait for the next call.
        Of an object's poses in the batch only the
        newest is handled (where it arrived; the others would be replaced unmeasured): handling a pose costs
        the loop more than receiving it costs the transport's thread, so a flood of valid poses (21,000 a
        second, forged) once kept the loop in here for 12 s, simulated time standing still.
        """
        batch: list[tuple[float, str, object]] = []
        for _ in range(min(self.inbox.qsize(), MAX_DRAIN)):
            try:
                batch.append(self.inbox.get_nowait())
            except queue.Empty:
                break
        newest: dict[str, Pose] = {}
        beat: Heartbeat | None = None  # a heartbeat costs a pass over every mark: only the newest of a batch
        for _, _, msg in batch:
            if isinstance(msg, Pose):
                known = newest.get(msg.object_id)
                if known is None or (msg.epoch, msg.seq) > (known.epoch, known.seq):
                    newest[msg.object_id] = msg
            elif isinstance(msg, Heartbeat) and (beat is None or (msg.epoch, msg.seq) > (beat.epoch, beat.seq)):
                beat = msg
        for item in batch:
            msg = item[2]
            if isinstance(msg, Heartbeat) and msg is not beat:
                self.report.out_of_order += 1
                continue
            if isinstance(msg, Pose) and newest[msg.object_id] is not msg:
                mark = self._pose_mark.get(msg.object_id)
                if mark is not None and (msg.epoch, msg.seq) <= mark:
                    self.report.out_of_order += 1
                else:
                    self.report.poses_superseded += 1
                continue
            self._handle_safely(*item)  # type: ignore[arg-type]
        if correct:
            self._flush_corrections()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
        self.link.close()
        self.twin.close()

    def remote_pose(self, object_id: str) -> tuple[np.ndarray, np.ndarray] | None:
        """Where the remote last said the object is, mapped onto the twin's body: (position m, quaternion
        w x y z), world frame. None before the object is in the twin and a pose has arrived."""
        latest, offset = self._latest.get(object_id), self._offsets.get(object_id)
        if latest is None or offset is None:
            return None
        return self._on_body(object_id, latest, offset)

    def twin_object(self, object_id: str) -> TwinObject | None:
        """The object as it went into the twin (added, or replaced by a later cloud's), or None while it is not in
        it: its :attr:`~twin.objects.TwinObject.estimate` holds the mass properties, ``warnings`` and
        ``volume_bounds_m3`` (not the full reconstruction and points: :func:`_kept`)."""
        return self._taken.get(object_id) if object_id in self._clouds else None

    @property
    def expected(self) -> int:
        """Objects the twin knows of (in the twin or being estimated)."""
        return len(self._clouds)

    @property
    def adding(self) -> bool:
        return bool(self._jobs) or self.twin.edits_pending > 0

    @property
    def objects(self) -> list[str]:
        """Objects in the running twin (touchable)."""
        return [i for i in self._clouds if self.twin.has(i)]

    @property
    def pending(self) -> list[str]:
        """Objects whose cloud arrived but which are not touchable yet (estimating or compiling)."""
        return [i for i in self._clouds if not self.twin.has(i)]

    # -- messages ------------------------------------------------------------------------------------

    def _enqueue(self, key: str, msg) -> None:  # type: ignore[no-untyped-def]
        if self.inbox.qsize() >= MAX_INBOX:  # transport thread: queue only, never touch the twin
            self.link.dropped("inbox-full", "dropped a %s on %s: %d messages wait for the loop already",
                              type(msg).__name__, key, MAX_INBOX)
            return
        self.inbox.put((self.clock.now(), key, msg))

    def _newer(self, marks: dict[str, tuple[int, int]], msg) -> bool:  # type: ignore[no-untyped-def]
        """Take ``msg`` if it is newer than the mark for its object (and move the mark), else count it."""
        mark = marks.get(msg.object_id)
        gone = self._gone.get(msg.object_id)
        if (mark is not None and (msg.epoch, msg.seq) <= mark) or (gone is not None and (msg.epoch, msg.seq) <= gone):
            self.report.out_of_order += 1  # e.g. the late-join reply raced a newer live message, or the Gone
            return False
        marks[msg.object_id] = (msg.epoch, msg.seq)
        return True

    def _on_heartbeat(self, msg: Heartbeat, received: float) -> None:
        """Pull back every mark past this heartbeat's counter that was past the last one's too (no honest message
        is: the one past a single heartbeat was sent after it and overtook it). Not newer than the last heartbeat
        taken (late, replayed): counted out of order, nothing else. ``received``: clock seconds."""
        if not self._heartbeats.newer("remote", msg.epoch, msg.seq, received):
            self.report.out_of_order += 1
            if self._remote_epoch is not None and msg.epoch < self._remote_epoch:
                # Alive, and older than the epoch followed: two remotes publish this scene (their objects were
                # merged without a word before session 39), or an old one still runs.
                self.dropped_log.warning("older-remote", "a heartbeat of an older remote (epoch %d) while the twin "
                                         "follows epoch %d: two remotes publish this scene? Following the newer",
                                         msg.epoch, self._remote_epoch)
                if msg.epoch not in self._older and len(self._older) < MAX_OLDER_EPOCHS:
                    # Once an older epoch: the newer remote's state says which objects are its own (the first
                    # state query took both remotes' clouds).
                    self._older.add(msg.epoch)
                    self._start_resync(self._remote_epoch)
            return
        self._heartbeats.take("remote", msg.epoch, msg.seq, received)
        self._resync_if_behind(msg)
        now = (msg.epoch, msg.seq)
        beyond: dict[tuple[int, str], tuple[int, int]] = {}
        for which, marks in enumerate((self._pose_mark, self._clouds, self._gone)):
            for object_id, mark in marks.items():
                if mark <= now:
                    continue
                if self._beyond.get((which, object_id)) == mark:  # rate-limited like every drop
                    self.dropped_log.warning("forged-seq", "object %r: a message claimed sequence %s beyond the "
                                             "remote's %s; ignoring the claim", object_id, mark, now)
                    marks[object_id] = now
                else:
                    beyond[(which, object_id)] = mark
        self._beyond = beyond

    def _resync_if_behind(self, beat: Heartbeat) -> None:
        """Ask for the scene state again when ``beat`` is of a new epoch (a restarted remote publishes its clouds
        once, perhaps before the link was up again, and knows nothing of the objects it no longer has), or counts
        more objects than the twin knows (the first query went unanswered: over the remote's budget). On a real
        clock the query runs in a thread of its own (it waits up to ``wait``); its replies queue as live
        messages do, then a :class:`_StateAnswered`."""
        restarted = self._remote_epoch is not None and beat.epoch > self._remote_epoch
        self._remote_epoch = beat.epoch
        behind = beat.objects > len(self._clouds) + len(self._refused) and self.clock.now() >= self._resync_at
        if not (restarted or behind) or (self._resyncing is not None and self._resyncing.is_alive()):
            return
        if restarted:
            log.warning("the remote restarted (a new epoch): asking for its scene state again")
            self._resync_every = RESYNC_FIRST_S
        else:
            log.info("the remote counts %d objects, the twin knows %d: asking for its scene state again",
                     beat.objects, len(self._clouds))
            self._resync_every = min(2 * self._resync_every, RESYNC_MAX_S)
        self._resync_at = self.clock.now() + self._resync_every
        self._start_resync(beat.epoch)

    def _start_resync(self, epoch: int) -> None:
        """Ask for the scene state of the remote of ``epoch`` (see :meth:`_resync_if_behind`)."""
        if self._resyncing is not None and self._resyncing.is_alive():
            return
        self.report.resyncs += 1
        if self.clock.realtime:
            self._resyncing = threading.Thread(target=self._ask_state, args=(epoch,), daemon=True, name="twin-resync")
            self._resyncing.start()
        else:  # the in-process bus answers at once: asked in the loop, a headless session stays repeatable
            self._ask_state(epoch)

    def _ask_state(self, epoch: int) -> None:
        ids: set[str] = set()
        answered = [False]  # by the remote of ``epoch`` (an older one still running answers the same key)

        def take(key: str, msg) -> None:  # type: ignore[no-untyped-def]
            if getattr(msg, "epoch", -1) >= epoch:
                answered[0] = True
                if isinstance(msg, Cloud):
                    ids.add(msg.object_id)
            self._enqueue(key, msg)

        self.link.query(self.keys.state, take, timeout=self._state_wait)
        self.inbox.put((self.clock.now(), "", _StateAnswered(epoch, answered[0], frozenset(ids))))

    def _on_state_answered(self, done: _StateAnswered) -> None:
        """After the state of the remote followed: objects of older epochs it did not send are gone. An
        unanswered query is said (a remote's query budget spent by another peer starves a joining twin)."""
        if not done.answered:
            self.dropped_log.warning("state-unanswered", "the remote did not answer the twin's scene-state query "
                                     "(its query budget spent by other peers?); asking again in %.0f s",
                                     self._resync_every)
            return
        for object_id, (epoch, _) in list(self._clouds.items()):
            if epoch < done.epoch and object_id not in done.ids:
                log.warning("object %r: the remote followed (epoch %d) does not hold it (restarted without it, or "
                            "it was another remote's); removed", object_id, done.epoch)
                self._handle(self.clock.now(), "", Gone(v=VERSION, stamp_ns=self.clock.stamp_ns(), object_id=object_id,
                                                        epoch=done.epoch, seq=0))

    def _operator_target(self, trajectory) -> np.ndarray | None:  # type: ignore[no-untyped-def]
        if not self.twin.has_end_effector:
            return None
        if trajectory is not None:
            value = trajectory(self.twin.time)
            return None if value is None else np.asarray(value, dtype=float)
        return self.device_target

    def _feedback(self) -> None:
        """Publish (and record) the force the operator should feel, when due."""
        if not self.twin.has_end_effector:
            return
        t = self.twin.time
        publish = self._force_every is not None and t + _TIME_SLACK >= self._next_force
        record = self.recorder is not None and self.recorder.force_due(t)
        if not (publish or record):
            return
        force = self.twin.end_effector_force()
        if record:
            self.recorder.force(t, force)  # type: ignore[union-attr]
        if publish:
            assert self._force_every is not None
            self._next_force += self._force_every
            if self._next_force <= t:  # behind (the first publication, or a rate above the loop's): from now
                self._next_force = t + self._force_every
            self._force_seq += 1
            self.report.forces_sent += 1
            self.link.put(self.keys.operator_force, OperatorForce(
                v=VERSION, stamp_ns=self.clock.stamp_ns(), epoch=self._epoch, seq=self._force_seq, sim_time=t,
                force=_float3(_saturated(force)), position=_float3(self.twin.data.mocap_pos[0])))

    def _on_device_target(self, msg: OperatorTarget, received: float) -> None:
        """Take a device driver's target if it is newer than the last of its device (or that device's mark has
        expired: :mod:`sync.ordering`) and in the workspace. ``received``: when it arrived, clock seconds."""
        dropped = self.report.operator_dropped
        if not self._device_marks.newer(msg.device, msg.epoch, msg.seq, received):
            dropped["out-of-order"] += 1
            return
        position = np.asarray(msg.position, dtype=float)
        low, high = self.workspace
        if not (np.all(position >= low) and np.all(position <= high)):
            dropped["out-of-workspace"] += 1
            self.dropped_log.warning("out-of-workspace", "dropped an operator target outside the workspace: %s",
                                     position.tolist())
            return
        if self._device_marks.take(msg.device, msg.epoch, msg.seq, received):
            self.report.evicted["device"] += 1
        self.device_target = position
        self.report.operator_targets += 1

    def _in_scene(self, msg, position) -> bool:  # type: ignore[no-untyped-def]
        """Whether an object message's position lies in the scene's box (:func:`_scene_box`: its declared
        workspace, or :data:`SCENE_REACH` around the table); one that does not is dropped and counted, never
        written into the twin."""
        box = self._box
        if box[0] is not self.scene_box:  # its corners as floats: every pose passes here
            box = self._box = (self.scene_box, *(np.asarray(c, dtype=float).tolist() for c in self.scene_box))
        if all(lo <= x <= hi for x, lo, hi in zip(position, box[1], box[2], strict=True)):
            return True
        p = np.asarray(position, dtype=float)
        self.report.out_of_scene += 1
        self.dropped_log.warning("out-of-scene", "dropped a %s of %r at %s: outside the scene", type(msg).__name__,
                                 msg.object_id, p.tolist())
        return False

    def _fits_scene(self, obj: TwinObject) -> bool:
        """Whether every vertex of ``obj``'s reconstruction, where it is placed, lies in the scene's box
        (:func:`_scene_box`); one that does not is counted in ``out_of_scene`` and logged (rate-limited)."""
        vertices = obj.visual[0] @ rotation(obj.quat).T + obj.position
        low, high = self.scene_box
        if len(vertices) and np.all(vertices >= low) and np.all(vertices <= high):
            return True
        self.report.out_of_scene += 1
        self.dropped_log.warning("out-of-scene", "dropped the cloud of %r: its object (%s m across) reaches outside "
                                 "the scene", obj.id, np.ptp(vertices, axis=0).round(3).tolist() if len(vertices) else [])
        return False

    def _handle_safely(self, received: float, key: str, msg) -> None:  # type: ignore[no-untyped-def]
        """:meth:`_handle`, with an exception dropping the message (counted as ``"handler-error"``, logged with
        its traceback, rate-limited) instead of ending the loop: decoding checks every value it knows of, and
        one message it let through must not stop the twin. The physics step is not in here."""
        try:
            self._handle(received, key, msg)
        except Exception as exc:
            self._handler_error(msg, key, exc)

    def _handler_error(self, msg, key: str, exc: Exception) -> None:  # type: ignore[no-untyped-def]
        self.link.dropped("handler-error", "dropped a %s on %s: handling it failed (%s: %s)", type(msg).__name__,
                          key, type(exc).__name__, exc, exc_info=True)

    def _handle(self, received: float, key: str, msg) -> None:  # type: ignore[no-untyped-def]
        if isinstance(msg, OperatorTarget):  # the link passes one on its key only (sync.keys.carried_by)
            self._on_device_target(msg, received)
        elif isinstance(msg, _StateAnswered):
            self._on_state_answered(msg)
        elif isinstance(msg, Heartbeat):
            self._on_heartbeat(msg, received)
        elif isinstance(msg, (Pose, Cloud)) and msg.object_id in RESERVED_IDS:
            self.link.dropped("reserved-id", "dropped a %s of %r: the twin's model uses that name itself",
                              type(msg).__name__, msg.object_id)
        elif isinstance(msg, Pose):
            if not self._in_scene(msg, msg.position) or not self._newer(self._pose_mark, msg):
                return
            self._latest[msg.object_id] = msg
            if msg.object_id not in self._clouds:
                self._orphan(msg.object_id)
            if not msg.seen:
                self._on_unseen(msg.object_id)
                return
            self._unseen.discard(msg.object_id)
            if msg.object_id in self._offsets and self.twin.has(msg.object_id):
                self._targets[msg.object_id] = msg  # replaces an older one not yet measured
                self._hold_at(msg.object_id)
                self._to_correct.append(msg.object_id)
                if self.rlog.enabled:
                    self._flush_corrections()  # keep the debug log's events in arrival order
                self.report.pose_updates += 1
                age = (self.clock.stamp_ns() - msg.stamp_ns) * 1e-9
                if LATENCY_RANGE[0] <= age <= LATENCY_RANGE[1]:
                    self.report.pose_latency.append(age)
                else:
                    self.report.stamps_off += 1
                    if self.report.stamps_off == 1:
                        log.warning("%s: pose stamped %.3g s from the twin's clock, outside %s s: not a latency "
                                    "(unsynchronised clocks, or a broken sender); such stamps are counted, not "
                                    "measured", msg.object_id, -age, LATENCY_RANGE)
                if self.rlog.enabled:  # every pose passes here: no string building with rerun off
                    self.rlog.event(self.twin.time, f"{msg.object_id}: pose correction (seq {msg.seq})", "DEBUG")
        elif isinstance(msg, Cloud):
            # The frame and the points' lowest corner: a cloud placed in the scene whose points lie 1 km away
            # would build a body far off the table.
            if not self._in_scene(msg, msg.frame_position) or not self._in_scene(msg, msg.origin):
                return
            if msg.object_id not in self._clouds and len(self._clouds) >= MAX_OBJECTS:
                self.link.dropped("too-many-objects", "dropped a cloud of %r: the twin has %d objects already",
                                  msg.object_id, len(self._clouds))
                return
            if self._refused.get(msg.object_id) == (msg.epoch, msg.seq):
                self.report.out_of_order += 1  # refused once already (sent again by a state query)
                return
            waiting = sum(job[1].count for i, job in self._jobs.items() if i != msg.object_id)
            if waiting + msg.count > MAX_PENDING_POINTS:
                # Before its mark moves: a state query asked again (heartbeats count the object) takes it later.
                self.link.dropped("too-much-pending", "dropped a cloud of %r (%d points): %d points wait for "
                                  "estimation already", msg.object_id, msg.count, waiting)
                return
            if not self._newer(self._clouds, msg):
                return
            self._orphans.pop(msg.object_id, None)  # its pose, if one came first, is kept for it
            self._refused.pop(msg.object_id, None)
            superseded = self._jobs.get(msg.object_id)
            if superseded is not None and superseded[0].cancel():  # its result would be thrown away unused
                self.report.clouds_superseded += 1
            self._jobs[msg.object_id] = (self._submit(msg), msg, received)
            self.rlog.event(self.twin.time, f"{msg.object_id}: cloud received (seq {msg.seq}); estimating")
        elif isinstance(msg, Gone):
            if not self._holds_anything_of(msg.object_id):
                # Nothing to remove; remembered only so that its cloud, arriving late, stays out. A flood of these
                # for new ids took 23 us each through the removal below (65,536 a step: 1.5 s).
                self._forget_later(msg)
                return
            self._flush_corrections()  # poses that came before it were corrected towards before it
            mark = self._clouds.get(msg.object_id)
            if mark is not None and (msg.epoch, msg.seq) < mark:
                self.report.out_of_order += 1  # older than the cloud the twin has: not about this object
                return
            self._forget_later(msg)
            for held in self._per_object():
                held.pop(msg.object_id, None)
            self._unseen.discard(msg.object_id)
            self.hold.forget(msg.object_id)
            # An object whose model is compiling now is not in the twin yet: its add's ``done`` removes it.
            if self.twin.has(msg.object_id):
                self.twin.edit_async(lambda spec, i=msg.object_id: _remove_if_there(spec, i))
            for side in ("twin", "remote"):
                self.rlog.removed(side, msg.object_id, self.twin.time)
            self.rlog.event(self.twin.time, f"{msg.object_id}: removed by the remote")

    def _refuse(self, object_id: str, msg: Cloud) -> None:
        """Remember that ``msg``, ``object_id``'s cloud, was not taken (newest last, at most :data:`MAX_OBJECTS`)."""
        self._refused.pop(object_id, None)
        self._refused[object_id] = (msg.epoch, msg.seq)
        if len(self._refused) > MAX_OBJECTS:
            del self._refused[next(iter(self._refused))]

    def _per_object(self) -> tuple[dict, ...]:
        """Every map the twin keeps by object id (what a :class:`Gone` clears, with ``_unseen`` and the hold)."""
        return (self._refused, self._jobs, self._clouds, self._offsets, self._taken, self._targets, self._errors,
                self._latest, self._mapped, self._pose_mark, self._orphans)

    def _holds_anything_of(self, object_id: str) -> bool:
        """Whether the twin holds anything of ``object_id``: its model or a job building it, a cloud, pose, mark,
        refusal or correction of it (what a :class:`Gone` removes)."""
        return (any(object_id in held for held in self._per_object()) or object_id in self._unseen
                or self.hold.holds(object_id) or self.twin.has(object_id))

    def _forget_later(self, msg: Gone) -> None:
        """Remember that ``msg``'s object is gone as of its ``(epoch, seq)``, newest last; past :data:`MAX_GONE`
        ids, forget the oldest (counted)."""
        self._gone.pop(msg.object_id, None)
        self._gone[msg.object_id] = (msg.epoch, msg.seq)
        if len(self._gone) > MAX_GONE:
            del self._gone[next(iter(self._gone))]
            self.report.evicted["gone"] += 1

    def _orphan(self, object_id: str) -> None:
        """Note a pose of an object the twin has no cloud of, newest last; past :data:`MAX_ORPHAN_POSES` such ids,
        forget all the twin holds of the oldest (its pose, mark and unseen flag) and count it."""
        self._orphans.pop(object_id, None)
        self._orphans[object_id] = None
        if len(self._orphans) > MAX_ORPHAN_POSES:
            oldest = next(iter(self._orphans))
            del self._orphans[oldest]
            for held in (self._latest, self._pose_mark, self._mapped):
                held.pop(oldest, None)
            self._unseen.discard(oldest)
            self.report.evicted["pose"] += 1

    def _collect(self) -> None:
        for object_id, (future, msg, received) in list(self._jobs.items()):
            if not future.done():
                continue
            del self._jobs[object_id]
            try:
                obj, display = future.result()
            except BrokenProcessPool as exc:  # a worker died (killed, out of memory, a native crash)
                self.rlog.event(self.twin.time, f"{object_id}: the estimation worker died", "ERROR")
                if (object_id, msg.epoch, msg.seq) not in self._retried:
                    # The cloud is at hand and the remote sends it only once: one more try (every job of a
                    # broken pool fails with it, not only the one that killed it; _submit replaces the pool).
                    self._retried.add((object_id, msg.epoch, msg.seq))
                    self.report.worker_retries += 1
                    log.error("object %r: the estimation worker died (%s); estimating it again", object_id, exc)
                    self._jobs[object_id] = (self._submit(msg), msg, received)
                    continue
                self.report.estimation_errors += 1
                log.error("object %r: the estimation worker died again (%s); going on without it", object_id, exc)
                self._clouds.pop(object_id, None)  # the next cloud for it is taken again
                self._refuse(object_id, msg)
                continue
            except Exception as exc:  # a cloud the estimator rejects: the twin goes on without it
                self.report.estimation_errors += 1
                self._clouds.pop(object_id, None)  # its slot is free (MAX_OBJECTS), and a later cloud is tried
                self._refuse(object_id, msg)
                self.dropped_log.warning("estimation-failed", "object %r: could not estimate its cloud: %s", object_id, exc)
                self.rlog.event(self.twin.time, f"{object_id}: could not estimate its cloud: {exc}", "ERROR")
                continue
            if not self._fits_scene(obj):
                # The message's origin and frame were in the scene; its points need not be (a 400 m cloud
                # would be a 1e11 kg body). Its slot is free again.
                self._clouds.pop(object_id, None)
                self._refuse(object_id, msg)
                continue

            def edit(spec, obj=obj) -> None:  # type: ignore[no-untyped-def]
                # Whether the object is there is asked of the spec this edit starts from, not of the running
                # model: an earlier view of it may be compiling still (edits apply in order).
                _remove_if_there(spec, obj.id)
                add_object(spec, obj)

            def done(obj=obj, msg=msg, received=received, display=display) -> None:  # type: ignore[no-untyped-def]
                if obj.id not in self._clouds:  # a Gone came while it compiled: out again
                    self.twin.edit_async(lambda spec, i=obj.id: _remove_if_there(spec, i))
                    return
                self._offsets[obj.id] = _offset(obj, msg)
                latest = self._latest.get(obj.id)
                if latest is not None and (latest.epoch, latest.seq) < (msg.epoch, msg.seq):
                    # Older than the cloud, whose frame is where the object was since (a pose of a remote's
                    # earlier run has a larger seq and a smaller epoch): neither corrected nor held towards.
                    del self._latest[obj.id]
                    self._mapped.pop(obj.id, None)
                elif latest is not None and latest.seen:
                    self._targets[obj.id] = latest
                    self._to_correct.append(obj.id)
                self._hold_at(obj.id)
                self._took(obj)
                self.report.objects_synced += 1
                self.report.add_latency.append(self.clock.now() - received)
                self.report.touchable_after[obj.id] = ((self.clock.stamp_ns() - msg.stamp_ns) * 1e-9,
                                                       self.report.add_latency[-1])
                if self.rlog.enabled:
                    t, m = self.twin.time, obj.estimate.mass
                    self.rlog.object("twin", obj, sim_time=t, cloud=display, pose=self.twin.pose(obj.id))
                    self.rlog.ghost(obj, sim_time=t)
                    self.rlog.event(t, f"{obj.id}: added to the twin ({m.mass:.3g} kg, {len(obj.hulls)} hulls) "
                                       f"{self.report.add_latency[-1]:.2f} s after its cloud arrived")

            def failed(exc: Exception, object_id=object_id, msg=msg) -> None:  # type: ignore[no-untyped-def]
                self.report.failed_edits += 1
                self._clouds.pop(object_id, None)  # a later cloud of it is tried again
                self._refuse(object_id, msg)
                self.rlog.event(self.twin.time, f"{object_id}: its model did not compile ({exc}); left out", "ERROR")

            self.twin.edit_async(edit, then=done, failed=failed)

    def _took(self, obj: TwinObject) -> None:
        """Keep ``obj`` (now in the twin) for :meth:`twin_object`, and say once what its estimate warns of: the log,
        the report's ``warned_objects``, the debug log. At insertion only: the loop's steps never look."""
        self._taken[obj.id] = _kept(obj)
        est = obj.estimate
        if not est.warnings:
            return
        self.report.warned_objects += 1
        note = estimate_note(est)
        log.warning("object %r is in the twin from an estimate that warns: %s", obj.id, note)
        self.rlog.event(self.twin.time, f"{obj.id}: in the twin from an estimate that warns: {note}", "WARN")

    def _new_pool(self) -> ProcessPoolExecutor | None:
        if self.settings.workers == 0:
            return None
        return ProcessPoolExecutor(self.settings.workers, mp_context=mp.get_context("spawn"),
                                   initializer=background_worker)

    def _submit(self, msg: Cloud) -> Future:
        """Estimate a cloud: in a worker process, or here and now when there are no workers."""
        args = (encode(msg), self.settings.coacd, self.settings.cache_dir, self.rlog.enabled,
                self.settings.mass_scale, self._floor)
        if self._pool is not None:
            try:
                return self._pool.submit(build_from_cloud, *args)
            except BrokenProcessPool:  # a worker died while idle: the pool refuses work until replaced
                log.error("the estimation worker pool broke; starting a new one")
                self._pool = self._new_pool()
                return self._pool.submit(build_from_cloud, *args)
        future: Future = Future()
        try:
            future.set_result(build_from_cloud(*args))
        except Exception as exc:
            future.set_exception(exc)
        return future

    def _flush_corrections(self) -> None:
        """Measure the corrections the poses handled since the last flush call for (each object once, from its
        newest pose: see :meth:`_handle`); :meth:`_apply_corrections` then applies them step by step.

        A pose whose measurement fails is dropped and counted (``"handler-error"``), as in
        :meth:`_handle_safely`; the others of its batch are measured one by one, so it costs them nothing."""
        if not self._to_correct:
            return
        ids, self._to_correct = self._to_correct, []
        ids = [i for i in dict.fromkeys(ids) if i in self._targets]
        try:
            self._measure(ids)
        except Exception:
            for object_id in ids:
                try:
                    self._measure([object_id])
                except Exception as exc:
                    self._handler_error(self._targets[object_id], self.keys.object(object_id, "pose"), exc)
        for object_id in ids:
            del self._targets[object_id]

    def _measure(self, ids: list[str]) -> None:
        """Turn each object's newest pose from C into the correction C' still needs: C's pose and velocity
        less C''s at the moment the pose answers to (:mod:`twin.history`), less the corrections applied
        since. Without that moment (no operator command yet, or outside the history), C' now stands in.
        A correction larger than the snap limits is applied at once by the next step."""
        if not ids:
            return
        s = self.settings
        body, _, dof = self._indices(ids)
        msgs = [self._targets[i] for i in ids]  # the caller forgets them once measured
        want = np.array([self._on_body(i, m, self._offsets[i], row=True) for i, m in zip(ids, msgs, strict=True)])
        n = len(ids)
        past, since, aligned = np.empty((n, STATE)), np.zeros((n, CORRECTION)), np.zeros(n, dtype=bool)
        if self._history_valid():
            rows = [self._history.rows.get(i, -1) for i in ids]
            stamps = [m.answers_ns if r >= 0 else 0 for m, r in zip(msgs, rows, strict=True)]
            for stamp in set(stamps) - {0}:
                found = self._history.at(stamp, self._align_tolerance)
                if found is not None:
                    k = [j for j, st in enumerate(stamps) if st == stamp]
                    r = [rows[j] for j in k]
                    past[k], since[k], aligned[k] = found[0][r], found[1][r], True
        if not aligned.all():  # no moment for these: C' now
            past[~aligned] = self._state(body[~aligned], dof[~aligned])
        error = np.concatenate([want[:, :3] - past[:, :3],
                                to_rotvec(quat_product(want[:, 3:7], past[:, 3:7] * _CONJUGATE)),
                                want[:, 7:] - past[:, 7:]], axis=1) - since
        shift, turn = _squared_norms(error)
        snap = (shift > s.snap_distance**2) | (turn > np.radians(s.snap_angle_deg) ** 2)
        for k, object_id in enumerate(ids):
            self._errors[object_id] = (error[k], bool(snap[k]))

    def _apply_corrections(self, ids: list[str]) -> None:
        """One step of each object's outstanding correction: the fraction ``1 - exp(-dt / tau)`` of what
        is left (all of it when it snaps), on position, orientation and both velocities. A correction is
        done under :data:`DONE_DISTANCE` and :data:`DONE_ANGLE_DEG`; what is left of it then is dropped."""
        if not ids:
            return
        twin = self.twin
        data = twin.data
        body, qpos, dof = self._indices(ids)
        error = np.array([self._errors[i][0] for i in ids])
        snap = np.array([self._errors[i][1] for i in ids])
        alpha = np.where(snap, 1.0, self._blend)[:, None]
        step = alpha * error
        q = data.qpos[qpos]
        quat = quat_product(from_rotvec(step[:, 3:6]), q[:, 3:])
        new = np.concatenate([q[:, :3] + step[:, :3], quat / _norms(quat)[:, None]], axis=1)
        if not np.isfinite(new).all():
            bad = ids[int(np.flatnonzero(~np.isfinite(new).all(axis=1))[0])]
            raise ValueError(f"object {bad!r}: pose must be finite with a non-zero quaternion")
        data.qpos[qpos] = new  # no mj_forward: the next step computes positions (as set_pose(forward=False))
        if snap.any():  # a snap may carry an object off the table in one step
            twin.moved(body[snap])
        # Angular velocity: MuJoCo keeps it in body axes; the correction is in world axes.
        xmat, vel = data.xmat[body].reshape(-1, 3, 3), data.qvel[dof]
        ang = np.matmul(xmat, vel[:, 3:, None])[:, :, 0] + step[:, 9:]
        data.qvel[dof] = np.concatenate([vel[:, :3] + step[:, 6:9],
                                         np.matmul(xmat.transpose(0, 2, 1), ang[:, :, None])[:, :, 0]], axis=1)
        if self._history_valid():
            rows = [self._history.rows.get(i, -1) for i in ids]
            if min(rows) >= 0:
                self._history.corrected(rows, step)
            else:  # objects added since the last step: not in the history yet
                mine = [k for k, r in enumerate(rows) if r >= 0]
                self._history.corrected([rows[k] for k in mine], step[mine])
        left = error - step
        shift, turn = _squared_norms(left)
        done = snap | ((shift < DONE_DISTANCE**2) & (turn < np.radians(DONE_ANGLE_DEG) ** 2))
        for k, object_id in enumerate(ids):
            if not done[k]:
                self._errors[object_id] = (left[k], False)
                continue
            del self._errors[object_id]
            if snap[k]:
                self.report.snaps += 1
                self.rlog.event(self.twin.time, f"{object_id}: snapped {np.linalg.norm(error[k, :3]) * 1e3:.1f} mm, "
                                                f"{np.degrees(np.linalg.norm(error[k, 3:6])):.1f} deg to the remote pose",
                                "WARN")

    def _state(self, body: np.ndarray, dof: np.ndarray) -> np.ndarray:
        """(n, 13) rows of position, quaternion, linear and angular velocity (world axes) of ``body``, as of
        the last step (like :meth:`twin.sim.Twin.pose`)."""
        data = self.twin.data
        vel = data.qvel[dof]
        ang = np.matmul(data.xmat[body].reshape(-1, 3, 3), vel[:, 3:, None])[:, :, 0]
        return np.concatenate([data.xpos[body], data.xquat[body], vel[:, :3], ang], axis=1)

    def _history_valid(self) -> bool:
        """The history's rows are this model's objects (:meth:`_remember` has run since the last new model)."""
        key = self._history.key
        return key is not None and key[0] is self.twin.model  # type: ignore[index]

    def _remember(self) -> None:
        """Record every object's state after a step (:mod:`twin.history`)."""
        if self._history.capacity == 0:
            return
        if self._history_for[0] is not self.twin.model or self._history_for[1] != len(self._offsets):
            # Objects come and go with a new model: new rows, and the history starts again.
            self._history_for = (self.twin.model, len(self._offsets))
            ids = [i for i in self._offsets if self.twin.has(i)]
            self._history.start((self.twin.model, tuple(ids)) if ids else None, ids)
            self._history_index = self._indices(ids)[::2] if ids else None  # type: ignore[assignment]
        if self._history_index is not None:
            self._history.record(self.clock.stamp_ns(), self._state(*self._history_index))

    def _indices(self, ids: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(body ids (n,), qpos indices (n, 7), qvel indices (n, 6)) of ``ids``' free joints in the twin's model."""
        model, cache = self._rows
        if model is not self.twin.model or len(cache) > 256:  # a new model, or many sets: start afresh
            model, cache = self._rows = (self.twin.model, {})
        key = tuple(ids)
        found = cache.get(key)
        if found is None:
            rows = np.array([self.twin.joint(i) for i in ids], dtype=np.intp).reshape(len(ids), 3)
            found = cache[key] = (rows[:, 0], rows[:, 1:2] + np.arange(7), rows[:, 2:3] + np.arange(6))
        return found

    @overload
    def _on_body(self, object_id: str, pose: Pose, offset: tuple[np.ndarray, np.ndarray],
                 row: Literal[False] = ...) -> tuple[np.ndarray, np.ndarray]: ...

    @overload
    def _on_body(self, object_id: str, pose: Pose, offset: tuple[np.ndarray, np.ndarray],
                 row: Literal[True]) -> np.ndarray: ...

    def _on_body(self, object_id: str, pose: Pose, offset: tuple[np.ndarray, np.ndarray],
                 row: bool = False) -> tuple[np.ndarray, np.ndarray] | np.ndarray:
        """:func:`_on_twin_body` of ``pose``, computed once per (message, offset) of an object.

        With ``row``: the (13,) row of position, quaternion, linear and angular velocity that
        :meth:`_measure` stacks."""
        hit = self._mapped.get(object_id)
        if hit is None or hit[0] is not pose or hit[1] is not offset:
            mapped = _on_twin_body(pose, offset)
            hit = self._mapped[object_id] = (pose, offset, mapped,
                                             np.concatenate([*mapped, pose.linvel, pose.angvel]))
        return hit[3] if row else hit[2]

    def _on_unseen(self, object_id: str) -> None:
        """The remote lost sight of the object: the twin simulates it alone (no hold at a stale pose)."""
        if object_id in self._unseen:
            return
        self._unseen.add(object_id)
        self.report.unseen += 1
        self.hold.forget(object_id)
        self.rlog.event(self.twin.time, f"{object_id}: the remote's sensor lost it; simulated here alone", "WARN")

    def _sample_divergence(self) -> None:
        for object_id in self._offsets:
            if object_id in self._unseen:  # C's pose of it is not known
                continue
            remote = self.remote_pose(object_id)
            if remote is not None and self.twin.has(object_id):
                gap = float(np.linalg.norm(self.twin.pose(object_id)[0] - remote[0]))
                self.report.divergence.setdefault(object_id, Samples()).append(gap)

    def _hold_at(self, object_id: str) -> None:
        """Tell the hold where the remote last had the object (mapped onto the twin's body)."""
        pose, latest = self.remote_pose(object_id), self._latest.get(object_id)
        if pose is not None and latest is not None and latest.seen:
            self.hold.target(object_id, *pose, latest.linvel, latest.angvel, now=self.twin.time)

    def _publish_operator(self, target: np.ndarray) -> None:
        if self._sent_operator is not None and np.linalg.norm(target - self._sent_operator) <= self.settings.operator_deadband:
            return
        self._sent_operator = target.copy()
        self._seq += 1
        self.link.put(self.keys.operator, OperatorCommand(v=VERSION, stamp_ns=self.clock.stamp_ns(), epoch=self._epoch,
                                                          seq=self._seq, position=tuple(target.tolist())))

    def _check_link(self) -> None:
        last = self.link.counters.last_received
        silent = self.clock.now() - (self._start if last is None else last)
        if not self.stale and silent > self.settings.stale_after:
            self.stale = True
            self.report.stale_events += 1
            log.warning("link stale: no message from the remote for %.1f s; the twin runs on", silent)
            self.rlog.event(self.twin.time, f"link stale: no message for {silent:.1f} s", "WARN")
        elif self.stale and silent <= self.settings.stale_after:
            self.stale = False
            self.report.recoveries += 1
            log.warning("link recovered")
            self.rlog.event(self.twin.time, "link recovered")
        dropped = self.link.counters.dropped_malformed
        if dropped != self._dropped_seen:
            self.rlog.event(self.twin.time, f"dropped {dropped - self._dropped_seen} malformed message(s) "
                                            f"({dropped} in all)", "WARN")
            self._dropped_seen = dropped

    def _find_scene(self, scene: str | None, wait: float) -> SceneInfo:
        selector = Keys(scene).info if scene else any_scene_info()
        found: list[SceneInfo] = []
        deadline = self.clock.now() + wait
        while not found and self.clock.now() < deadline:
            # The link takes a SceneInfo only on its own scene's key (sync.keys.carried_by), and replies only
            # come on keys the selector matches: a reply describing another scene is dropped as wrong-key.
            self.link.query(selector, lambda _k, m: found.append(m) if isinstance(m, SceneInfo) else None,
                            timeout=min(1.0, wait))
            if not found:
                self.clock.sleep(0.1)
        if not found:
            raise SyncError(f"no remote scene answered on {selector} within {wait:g} s")
        names = sorted({f.name for f in found})
        if len(names) > 1:
            raise SyncError(f"several remote scenes answer ({', '.join(names)}); choose one with --scene")
        return found[0]


def reach_box(info: SceneInfo, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) corners of the box targets or object poses must lie in, metres, world frame: ``reach`` beyond
    the announced table (:func:`twin.model.reach_corners`)."""
    return reach_corners(info.table_size, info.table_height, info.ee_position, reach)


def _scene_box(info: SceneInfo) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) corners, metres, world frame, of the box object poses and clouds must lie in: the scene's
    declared workspace when the remote announces one, else :data:`SCENE_REACH` around the table."""
    if info.workspace_min is not None and info.workspace_max is not None:
        return np.asarray(info.workspace_min, dtype=float), np.asarray(info.workspace_max, dtype=float)
    return reach_box(info, SCENE_REACH)


def _remove_if_there(spec, object_id: str) -> None:  # type: ignore[no-untyped-def]
    """Remove the object from ``spec`` if it holds it (edits queued one after another each check the spec)."""
    if has_object(spec, object_id):
        remove_object(spec, object_id)


def _float3(v: np.ndarray) -> tuple[float, float, float]:
    x, y, z = (float(a) for a in v)
    return x, y, z


def _saturated(force: np.ndarray) -> np.ndarray:
    """``force`` (3,) newtons scaled down to just under :data:`sync.messages.MAX_FORCE` where it is larger (a
    contact spike; receivers refuse more), direction kept. Measured as receivers measure it (``math.hypot``: no
    overflow past 1e154 N), and scaled a part in 1e9 under the limit: scaled to it exactly, one in seven came
    out a rounding step over and was refused."""
    size = math.hypot(*(float(f) for f in force))
    return force * (MAX_FORCE * (1 - 1e-9) / size) if size > MAX_FORCE else force


def _empty_spec(info: SceneInfo):  # type: ignore[no-untyped-def]
    """The twin's model before any object arrives: the table and end effector the remote described."""
    table = None if info.table_size is None else TableSpec(size=info.table_size, height=info.table_height,
                                                          material=info.table_material)
    ee = None if info.ee_radius <= 0 else EndEffectorSpec(radius=info.ee_radius, position=info.ee_position)
    return new_spec(info.name, table=table, end_effector=ee)


def _on_twin_body(pose: Pose, offset: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """A remote body pose mapped onto the twin's body through its :func:`_offset`: (position, quat w x y z)."""
    q = np.asarray(pose.quat)
    return np.asarray(pose.position) + rotation(q) @ offset[0], quat_mul(q, offset[1])


def _offset(obj: TwinObject, msg: Cloud) -> tuple[np.ndarray, np.ndarray]:
    """The twin body's pose in the sensed object frame, at the moment the cloud was taken."""
    q_r = np.asarray(msg.frame_quat)
    p = rotation(q_r).T @ (obj.position - np.asarray(msg.frame_position))
    return p, quat_mul(quat_conj(q_r), obj.quat)
