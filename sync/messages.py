"""The wire format: versioned msgspec structs, msgpack-encoded; clouds quantised and zstd-compressed.

Every message carries ``v`` (the format version) and a ``stamp_ns`` (the sender's clock,
:meth:`sync.clock.Clock.stamp_ns`; latency across machines needs synchronised clocks). Messages that are
ordered also carry the sender's ``epoch`` (fixed for one run of the sender, larger after a restart) and a
``seq`` counting up within the epoch, so a restarted remote is told from a stale one.

:func:`decode` rejects what no honest sender could mean, before anything is allocated for it: an unknown
type or version, garbage, non-finite numbers, a stamp or sequence number an int64 cannot hold, a quaternion
that is not unit length, an id outside the key-expression alphabet, a material the twin does not know (or a
name longer than an id), sizes, densities and speeds outside physical ranges, a cloud whose header and
payload sizes disagree or that claims more than :data:`MAX_CLOUD_POINTS`. Each rejection is a
:class:`MessageError` with a short ``reason``; receivers drop such a message, count it per reason and log it.

Clouds are quantised on a grid of ``quantum`` metres relative to their minimum corner (16 bits per axis
while the extent fits, else 32), sorted so neighbouring points have similar bytes, split into byte planes
and compressed with zstd. Point order carries no meaning for estimation. Normals, where the sender has them,
follow in the same order, one signed byte per axis (unit vector x 127, under half a degree), zstd too.
"""

from __future__ import annotations

import math

import msgspec
import numpy as np

from estimation.errors import MaterialError, TwinError
from estimation.materials import MAX_DENSITY, MIN_DENSITY, material
from sync.keys import MAX_ID_LENGTH, valid_id

VERSION = 2

#: The largest cloud a message may claim, points: 10 M is several depth frames of one object; a claim past
#: it is refused before anything is decompressed or allocated (a 61 KB message once claimed 2 GB).
MAX_CLOUD_POINTS = 10_000_000

#: How far a quaternion's norm may be from 1: senders normalise; float32 round trips stay within 1e-6.
QUAT_NORM_TOLERANCE = 1e-3

#: Largest coordinate, metres, any message may carry: a scene is metres across, 1 km is no scene.
MAX_COORDINATE = 1e3

#: Fastest an object may move in a pose, m/s and rad/s: far beyond anything on a table (a thrown ball is
#: 40 m/s); past it the twin would write a forged velocity into MuJoCo's state.
MAX_SPEED, MAX_ANGULAR_SPEED = 100.0, 1000.0

#: A scene's sizes, metres: table sides, table height and end-effector radius lie in [MIN_SIZE, MAX_SCENE_SIZE]
#: (a radius up to MAX_EE_RADIUS; 0 means none). Below a millimetre MuJoCo refuses the body (mass and inertia
#: under mjMINVAL); a table is metres across, 100 m is a hall; the end effector is a fingertip or a tool.
MIN_SIZE, MAX_SCENE_SIZE, MAX_EE_RADIUS = 1e-3, 100.0, 1.0

#: A rotation's standard deviation past half a turn says only that the orientation is unknown: senders clamp
#: ``Pose.angle_sigma`` to it (ICP on a nearly symmetric shape can report more), receivers refuse more.
MAX_ANGLE_SIGMA = math.pi

#: Largest force magnitude, newtons, an ``OperatorForce`` may carry: a haptic device renders tens of newtons,
#: and a device driver must never be handed 1e308 N. The twin saturates what it sends at this (its recording
#: keeps the force as simulated).
MAX_FORCE = 1e4

#: Largest simulated time, seconds, a message may carry (30 years); none is negative.
MAX_SIM_TIME = 1e9

#: Most objects a heartbeat may count.
MAX_OBJECTS = 1_000_000

#: Largest stamp, epoch or sequence number a message may carry, and the smallest is 0: what an int64 holds.
#: msgpack carries integers up to 2**64 - 1, but the twin keeps stamps in numpy int64 arrays
#: (:mod:`twin.history`): a pose answering to 2**64 - 1 raised OverflowError out of the twin's loop.
MAX_INT64 = 2**63 - 1

#: The integer fields that are times (ns) or sequence numbers, in any message that has them.
_ORDINALS = ("stamp_ns", "epoch", "seq", "answers_ns")

#: Default cloud quantisation step, metres: a tenth of a millimetre, well under a sensor's noise.
CLOUD_QUANTUM = 1e-4

_ZSTD_LEVEL = 3


class MessageError(TwinError, ValueError):
    """A message that cannot be used. ``reason`` is a short tag for counting (e.g. ``"non-finite"``)."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(detail)
        self.reason = reason

    def __reduce__(self) -> tuple[type, tuple[str, str]]:
        # Raised in an estimation worker (a cloud's points or normals unpacked there), it comes back pickled: with
        # the default (the message alone as args) it could not be rebuilt, the pool took the worker for dead, and
        # every estimate queued behind it failed with it.
        return (type(self), (self.reason, str(self)))


class _Msg(msgspec.Struct, array_like=True, tag_field="t", forbid_unknown_fields=True):
    v: int
    stamp_ns: int


class SceneInfo(_Msg, tag="scene"):
    """The static scene: table (size xyz, top height, friction), end effector (radius, start) and the
    scene's declared workspace.

    ``workspace_min``/``workspace_max``: the box (world frame, metres) object poses must lie in, as the scene
    file declares it; None when it declares none (the twin then takes its default box around the table).
    They come last with defaults, so a SceneInfo from a sender without them still decodes.
    """

    name: str
    table_size: tuple[float, float, float] | None
    table_height: float
    table_material: str
    ee_radius: float
    ee_position: tuple[float, float, float]
    workspace_min: tuple[float, float, float] | None = None
    workspace_max: tuple[float, float, float] | None = None


class Cloud(_Msg, tag="cloud"):
    """An object's point cloud in the world frame, with what is needed to estimate and place it.

    ``frame_position``/``frame_quat`` (w x y z) is the sensor's estimate of the object's frame when the
    cloud was taken (the frame its later :class:`Pose` messages move): the twin maps those poses onto its
    own body through it. A camera-based sensor fills it from tracking; the surface sensor from the truth.
    """

    object_id: str
    epoch: int
    seq: int
    count: int
    bits: int
    quantum: float
    origin: tuple[float, float, float]
    data: bytes
    material: str | None
    density: float | None
    frame_position: tuple[float, float, float]
    frame_quat: tuple[float, float, float, float]
    #: The points' unit outward normals (:func:`unpack_normals`), or empty: a camera-based sensor's, turned
    #: towards the camera that saw each point, which the estimate cannot recover from the points alone.
    normals: bytes = b""
    #: Which points no sensor saw (:func:`unpack_completed`: added by the sender's completion, the base on the
    #: support plane, a carved or mirrored side), or empty: all observed. The twin's volume interval then
    #: rests on the observed ones (``estimation.views.with_completion``), as ``twin estimate``'s views do.
    completed: bytes = b""
    #: The plane the sender closed the object on, ``A x + B y + C z + D = 0`` in the world frame with (A, B, C)
    #: unit and pointing into the object's side, or None. Nothing of the object lies below it: the twin cuts away
    #: what its reconstruction puts there (``estimation.views.on_support``). Clouds recorded before this field
    #: decode as without it; a twin from before it drops every cloud of a newer sender as undecodable (an
    #: array-like struct sends every field, msgspec omits no defaults there): update both sides together.
    support: tuple[float, float, float, float] | None = None


class Pose(_Msg, tag="pose"):
    """An object frame's pose and velocity as the remote senses it (world frame and axes; quaternion
    w x y z; m/s and rad/s).

    ``answers_ns``: the time on the twin's clock whose operator input this state answers to: the stamp of
    the latest :class:`OperatorCommand` the remote had applied, plus the remote's time since it arrived
    (0: no command yet). The twin compares the pose with its own state at that time, not with its state
    now, which is a round trip ahead (:mod:`twin.history`).

    ``position_sigma`` (m) and ``angle_sigma`` (rad): the pose's standard deviation along its worst
    direction as the remote's sensor reports it (ICP on depth cameras); 0 for the simulator's own state.

    ``seen`` False: the remote's sensor has lost the object (out of view, not found); the pose is the last
    one seen, and no other comes until it is found again. The twin then simulates the object on its own:
    it neither corrects towards that pose nor holds the object there (the remote's silence no longer means
    the object is still).
    """

    object_id: str
    epoch: int
    seq: int
    sim_time: float
    position: tuple[float, float, float]
    quat: tuple[float, float, float, float]
    linvel: tuple[float, float, float]
    angvel: tuple[float, float, float]
    answers_ns: int = 0
    position_sigma: float = 0.0
    angle_sigma: float = 0.0
    seen: bool = True


class Gone(_Msg, tag="gone"):
    object_id: str
    epoch: int
    seq: int


class Heartbeat(_Msg, tag="heartbeat"):
    """The remote is alive; ``seq`` is its message counter now (no honest message of this epoch has a
    larger one)."""

    epoch: int
    seq: int
    sim_time: float
    objects: int


class OperatorCommand(_Msg, tag="operator"):
    """The operator's end-effector target, world frame, metres."""

    epoch: int
    seq: int
    position: tuple[float, float, float]


class OperatorTarget(_Msg, tag="target"):
    """Where a device driver wants the end effector: published on ``twin/<scene>/operator/target``.

    Fields (msgpack array, in this order, after the tag ``"target"``): ``v`` (:data:`VERSION`),
    ``stamp_ns`` (the driver's clock), ``device`` (the driver's id, ``[A-Za-z0-9_-]{1,64}``), ``epoch``
    (fixed for one run of the driver, e.g. its start time in ns), ``seq`` (counting up within the epoch),
    ``position`` (x, y, z: metres, world frame of the scene). Example, in Python::

        encode(OperatorTarget(v=VERSION, stamp_ns=time.time_ns(), device="haptic0", epoch=t0, seq=n,
                              position=(0.1, 0.0, 0.55)))

    The twin takes the newest ``(epoch, seq)`` of each device and drops older ones, until the device has had
    no target taken for :data:`sync.ordering.MARK_EXPIRY` seconds (then the next one is taken whatever its
    number); a target that is not finite, beyond :data:`MAX_COORDINATE`, or outside the scene's workspace is
    dropped and counted.
    """

    device: str
    epoch: int
    seq: int
    position: tuple[float, float, float]


class OperatorForce(_Msg, tag="force"):
    """The force the operator should feel, from the twin: published on ``twin/<scene>/operator/force``.

    ``force`` is the net contact force the scene exerts on the end effector (newtons, world axes; zero in
    free space), ``position`` where the twin's end effector is (metres, world frame), ``sim_time`` the
    twin's time (seconds); ``epoch``/``seq`` order them as for every ordered message.
    """

    epoch: int
    seq: int
    sim_time: float
    force: tuple[float, float, float]
    position: tuple[float, float, float]


Message = SceneInfo | Cloud | Pose | Gone | Heartbeat | OperatorCommand | OperatorTarget | OperatorForce

_encoder = msgspec.msgpack.Encoder()
_decoder = msgspec.msgpack.Decoder(Message)


class _Head(msgspec.Struct, array_like=True):
    """The leading fields every message shares (tag, version, stamp); the rest is skipped unread."""

    t: str
    v: int
    stamp_ns: int


_head_decoder = msgspec.msgpack.Decoder(_Head)


def peek_stamp(data: bytes) -> int | None:
    """The sender's ``stamp_ns`` of an encoded message, without checking the rest; None if unreadable.

    For recordings: the send time of a received message, whatever else is wrong with it.
    """
    try:
        return _head_decoder.decode(data).stamp_ns
    except (msgspec.DecodeError, msgspec.ValidationError):
        return None


def encode(msg: Message) -> bytes:
    return _encoder.encode(msg)


def decode(data: bytes) -> Message:
    """Parse and check one message.

    Raises:
        MessageError: not a message of this version, or a cloud whose sizes do not add up.
    """
    try:
        msg = _decoder.decode(data)
    except (msgspec.DecodeError, msgspec.ValidationError) as exc:
        raise MessageError("undecodable", f"undecodable message ({exc})") from exc
    if msg.v != VERSION:
        raise MessageError("version", f"message version {msg.v}, expected {VERSION}")
    _check(msg)
    return msg


def pack_points(points: np.ndarray, quantum: float = CLOUD_QUANTUM
                ) -> tuple[int, int, tuple[float, float, float], bytes, np.ndarray]:
    """(count, bits, origin, compressed bytes, order) of an (n, 3) cloud in metres; ``order`` (n,) is the
    permutation the points were sent in (normals follow it)."""
    import zstandard

    points = np.asarray(points, dtype=np.float64)
    origin = points.min(axis=0)
    q = np.round((points - origin) / quantum)
    bits = 16 if q.max() < 2**16 else 32
    q = q.astype(np.uint16 if bits == 16 else np.uint32)
    order = np.lexsort((q[:, 2], q[:, 1], q[:, 0]))
    q = q[order]
    # Byte planes: all high bytes together, then the low ones; sorted columns make runs zstd finds.
    planes = np.ascontiguousarray(q.T).view(np.uint8).reshape(3, len(q), bits // 8).transpose(0, 2, 1)
    data = zstandard.ZstdCompressor(level=_ZSTD_LEVEL).compress(np.ascontiguousarray(planes).tobytes())
    return len(points), bits, (float(origin[0]), float(origin[1]), float(origin[2])), data, order


def pack_normals(normals: np.ndarray) -> bytes:
    """(n, 3) unit vectors as one signed byte per axis (x 127), axis planes, zstd."""
    import zstandard

    q = np.clip(np.round(np.asarray(normals, dtype=np.float64) * 127.0), -127, 127).astype(np.int8)
    return zstandard.ZstdCompressor(level=_ZSTD_LEVEL).compress(np.ascontiguousarray(q.T).tobytes())


def unpack_normals(msg: Cloud) -> np.ndarray | None:
    """The (n, 3) unit normals of a :class:`Cloud` message in :func:`unpack_points`' order, or None.

    Raises:
        MessageError: a payload that does not inflate to one byte per axis and point, or a zero vector.
    """
    if not msg.normals:
        return None
    raw = _inflate(msg, msg.normals, 3 * msg.count, "normals")
    normals = np.frombuffer(raw, np.int8).reshape(3, msg.count).T.astype(np.float64)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    if not (length > 0).all():
        raise MessageError("bad-payload", f"cloud {msg.object_id!r}: a zero normal")
    return normals / length


def pack_completed(completed: np.ndarray) -> bytes:
    """An (n,) bool mask as one bit per point (numpy's ``packbits``, big-endian in each byte), zstd."""
    import zstandard

    return zstandard.ZstdCompressor(level=_ZSTD_LEVEL).compress(np.packbits(np.asarray(completed, bool)).tobytes())


def unpack_completed(msg: Cloud) -> np.ndarray | None:
    """The (n,) bool mask of a :class:`Cloud`'s completed points in :func:`unpack_points`' order, or None.

    Raises:
        MessageError: a payload that does not inflate to one bit per point, or set bits past the last point.
    """
    if not msg.completed:
        return None
    raw = np.frombuffer(_inflate(msg, msg.completed, _completed_size(msg.count), "completed flags"), np.uint8)
    bits = np.unpackbits(raw)
    if bits[msg.count:].any():
        raise MessageError("bad-payload", f"cloud {msg.object_id!r}: completed flags past its {msg.count} points")
    return bits[:msg.count].astype(bool)


def _completed_size(count: int) -> int:
    return (count + 7) // 8


def unpack_points(msg: Cloud) -> np.ndarray:
    """The (n, 3) float64 cloud of a :class:`Cloud` message, metres."""
    width = msg.bits // 8
    raw = _inflate(msg, msg.data, 3 * width * msg.count, "points")
    planes = np.frombuffer(raw, np.uint8).reshape(3, width, msg.count).transpose(0, 2, 1)
    q = np.ascontiguousarray(planes).view(np.uint16 if width == 2 else np.uint32).reshape(3, msg.count).T
    points = q.astype(np.float64) * msg.quantum + np.asarray(msg.origin)
    # The header bounds the origin, not what 32-bit offsets reach from it (up to 4e9 m at a quantum near 1).
    if points.size and float(np.abs(points).max()) > MAX_COORDINATE:
        raise MessageError("out-of-range", f"cloud {msg.object_id!r}: points beyond {MAX_COORDINATE:g} m of the origin")
    return points


def _inflate(msg: Cloud, payload: bytes, size: int, what: str) -> bytes:
    """``payload`` (a zstd frame of ``msg``'s ``what``) inflated to exactly ``size`` bytes, never more."""
    import zstandard

    try:
        raw = zstandard.ZstdDecompressor().decompress(payload, max_output_size=size)
    except zstandard.ZstdError as exc:
        raise MessageError("bad-payload", f"cloud {msg.object_id!r}: corrupt compressed {what} ({exc})") from exc
    if len(raw) != size:
        raise MessageError("bad-payload", f"cloud {msg.object_id!r}: {len(raw)} bytes of {what} for {msg.count} "
                                          f"points")
    return raw


def _framed_size(msg: Cloud, payload: bytes, size: int, what: str) -> None:
    """Check that ``payload``'s zstd frame header states ``size`` bytes, without inflating it."""
    import zstandard

    try:
        stated = zstandard.frame_content_size(payload)
    except zstandard.ZstdError as exc:
        raise MessageError("bad-payload", f"cloud {msg.object_id!r}: {what} not a zstd frame ({exc})") from exc
    if stated != size:
        raise MessageError("bad-payload", f"cloud {msg.object_id!r}: {what} hold {stated} bytes, the header "
                                          f"claims {msg.count} points ({size} bytes)")


def cloud_message(object_id: str, points: np.ndarray, *, stamp_ns: int, epoch: int, seq: int,
                  material: str | None, density: float | None, frame_position: np.ndarray,
                  frame_quat: np.ndarray, quantum: float = CLOUD_QUANTUM, normals: np.ndarray | None = None,
                  completed: np.ndarray | None = None, support: tuple[float, float, float, float] | None = None
                  ) -> Cloud:
    """A :class:`Cloud` of ``points`` ((n, 3) metres, world frame), quantised and compressed, with their
    ``normals`` ((n, 3) unit, outward) when given and every one of them is finite and not zero (else the
    cloud goes without: a receiver would refuse it), which of them are ``completed`` ((n,) bool; sent
    when any is), and the ``support`` plane it was closed on (A, B, C, D; :attr:`Cloud.support`).

    Raises:
        ValueError: ``normals`` or ``completed`` not one per point.
    """
    count, bits, origin, data, order = pack_points(points, quantum)
    flags = b""
    if completed is not None:
        completed = np.asarray(completed, bool)
        if completed.shape != (count,):
            raise ValueError(f"cloud {object_id!r}: completed flags of shape {completed.shape} for {count} points")
        if completed.any():
            flags = pack_completed(completed[order])
    packed = b""
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != (count, 3):
            raise ValueError(f"cloud {object_id!r}: normals of shape {normals.shape} for {count} points")
        length = np.linalg.norm(normals, axis=1)
        if np.isfinite(length).all() and (length > 0).all():
            packed = pack_normals(normals[order] / length[order, None])
    return Cloud(v=VERSION, stamp_ns=stamp_ns, object_id=object_id, epoch=epoch, seq=seq, count=count, bits=bits,
                 quantum=quantum, origin=origin, data=data, material=material, density=density,
                 frame_position=_vec(frame_position, 3), frame_quat=_vec(frame_quat, 4), normals=packed,
                 completed=flags, support=None if support is None else _vec(support, 4))


def as_received(points: np.ndarray, normals: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """``points`` ((n, 3) metres) and their ``normals`` as a receiver decodes them from a :class:`Cloud`:
    on the ``CLOUD_QUANTUM`` grid, reordered, normals to a byte per axis (benches: what the twin gets)."""
    msg = decode(encode(cloud_message("o", points, stamp_ns=0, epoch=0, seq=0, material=None, density=1.0,
                                      frame_position=np.zeros(3), frame_quat=np.array([1.0, 0.0, 0.0, 0.0]),
                                      normals=normals)))
    assert isinstance(msg, Cloud)
    return unpack_points(msg), unpack_normals(msg)


def _check(msg: Message) -> None:
    """Raise :class:`MessageError` for values no honest sender produces."""
    name = msg.object_id if hasattr(msg, "object_id") else getattr(msg, "name", None)
    if name is not None and not valid_id(name):
        raise MessageError("bad-id", f"id {name[:80]!r} is not a key chunk ([A-Za-z0-9_-], 1-64)")
    _ordinals(msg)
    if isinstance(msg, Pose):
        _finite(msg, msg.position, msg.linvel, msg.angvel, (msg.sim_time, msg.position_sigma, msg.angle_sigma))
        _coordinates(msg, msg.position)
        _unit(msg, msg.quat)
        if msg.position_sigma < 0 or msg.angle_sigma < 0 or msg.position_sigma > MAX_COORDINATE:
            raise MessageError("out-of-range", f"pose {msg.object_id!r}: sigma outside [0, {MAX_COORDINATE:g}]")
        if msg.angle_sigma > MAX_ANGLE_SIGMA:
            raise MessageError("out-of-range", f"pose {msg.object_id!r}: angle sigma over {MAX_ANGLE_SIGMA:.4g} rad")
        _sim_time(msg)
        if math.hypot(*msg.linvel) > MAX_SPEED or math.hypot(*msg.angvel) > MAX_ANGULAR_SPEED:
            raise MessageError("out-of-range", f"pose {msg.object_id!r}: faster than {MAX_SPEED:g} m/s or "
                                               f"{MAX_ANGULAR_SPEED:g} rad/s")
    elif isinstance(msg, Cloud):
        _check_cloud(msg)
    elif isinstance(msg, OperatorCommand | OperatorTarget):
        if isinstance(msg, OperatorTarget) and not valid_id(msg.device):
            raise MessageError("bad-id", f"device {msg.device[:80]!r} is not a key chunk ([A-Za-z0-9_-], 1-64)")
        _finite(msg, msg.position)
        _coordinates(msg, msg.position)
    elif isinstance(msg, OperatorForce):
        _finite(msg, msg.force, msg.position, (msg.sim_time,))
        _coordinates(msg, msg.position)
        _sim_time(msg)
        if math.hypot(*msg.force) > MAX_FORCE:
            raise MessageError("out-of-range", f"force: over {MAX_FORCE:g} N")
    elif isinstance(msg, Heartbeat):
        _finite(msg, (msg.sim_time,))
        _sim_time(msg)
        if msg.objects < 0:
            raise MessageError("bad-size", "heartbeat: negative object count")
        if msg.objects > MAX_OBJECTS:
            raise MessageError("bad-size", f"heartbeat: more than {MAX_OBJECTS:,} objects")
    elif isinstance(msg, SceneInfo):
        _finite(msg, msg.table_size or (), (msg.table_height, msg.ee_radius), msg.ee_position)
        _coordinates(msg, msg.ee_position, msg.table_size or (), (msg.table_height,))
        if (msg.table_size is not None and min(msg.table_size) <= 0) or msg.ee_radius < 0:
            raise MessageError("bad-size", "scene: non-positive table size or negative end-effector radius")
        _check_scene_sizes(msg)
        low, high = msg.workspace_min, msg.workspace_max
        if (low is None) != (high is None):
            raise MessageError("bad-size", "scene: a workspace needs both corners")
        if low is not None and high is not None:
            _finite(msg, low, high)
            _coordinates(msg, low, high)
            if not all(a < b for a, b in zip(low, high, strict=True)):
                raise MessageError("bad-size", "scene: workspace min is not below max on every axis")


def _sim_time(msg: Pose | OperatorForce | Heartbeat) -> None:
    """Raise unless the (finite) ``sim_time`` lies in [0, :data:`MAX_SIM_TIME`]."""
    if not 0.0 <= msg.sim_time <= MAX_SIM_TIME:
        raise MessageError("out-of-range", f"{type(msg).__name__.lower()}: sim_time {msg.sim_time:.4g} s outside "
                                           f"[0, {MAX_SIM_TIME:g}]")


def _check_scene_sizes(msg: SceneInfo) -> None:
    """Table and end effector within :data:`MIN_SIZE` .. :data:`MAX_SCENE_SIZE` (:data:`MAX_EE_RADIUS`), and
    the table's material one the twin knows (it sets the table's friction)."""
    if msg.table_size is not None:
        if not all(MIN_SIZE <= x <= MAX_SCENE_SIZE for x in (*msg.table_size, msg.table_height)):
            raise MessageError("out-of-range", f"scene: table size or height outside {MIN_SIZE:g} .. "
                                               f"{MAX_SCENE_SIZE:g} m")
        _material(msg, msg.table_material)
    elif len(msg.table_material) > MAX_ID_LENGTH:  # unused without a table, but carried along and printable
        raise MessageError("bad-material", f"scene: table material of {len(msg.table_material):,} characters, more "
                                           f"than {MAX_ID_LENGTH}")
    if msg.ee_radius != 0 and not MIN_SIZE <= msg.ee_radius <= MAX_EE_RADIUS:
        raise MessageError("out-of-range", f"scene: end-effector radius {msg.ee_radius:g} m outside {MIN_SIZE:g} .. "
                                           f"{MAX_EE_RADIUS:g}")


def _material(msg: SceneInfo | Cloud, name: str) -> None:
    """A material name the twin knows, at most :data:`sync.keys.MAX_ID_LENGTH` characters (a long one is refused
    before it is looked up, matched against the table for hints, or logged)."""
    what = "scene: table material" if isinstance(msg, SceneInfo) else f"cloud {msg.object_id!r}: material"
    if len(name) > MAX_ID_LENGTH:
        raise MessageError("bad-material", f"{what} of {len(name):,} characters, more than {MAX_ID_LENGTH}")
    try:
        material(name)
    except MaterialError as exc:
        raise MessageError("bad-material", f"{what}: {exc}") from exc


def _check_cloud(msg: Cloud) -> None:
    if msg.bits not in (16, 32) or msg.count <= 0 or not (0 < msg.quantum < 1) or not math.isfinite(msg.quantum):
        raise MessageError("bad-header", f"cloud {msg.object_id!r}: bad header (bits {msg.bits}, count "
                                         f"{msg.count}, quantum {msg.quantum})")
    if msg.count > MAX_CLOUD_POINTS:
        raise MessageError("too-large", f"cloud {msg.object_id!r}: {msg.count:,} points claimed, more than "
                                        f"{MAX_CLOUD_POINTS:,}")
    _finite(msg, msg.origin, msg.frame_position)
    _coordinates(msg, msg.origin, msg.frame_position)
    _unit(msg, msg.frame_quat)
    if msg.material is not None:
        _material(msg, msg.material)
    if (msg.density is not None and not (math.isfinite(msg.density) and msg.density > 0)):
        raise MessageError("non-finite", f"cloud {msg.object_id!r}: density {msg.density}")
    if msg.density is not None and not MIN_DENSITY <= msg.density <= MAX_DENSITY:
        raise MessageError("out-of-range", f"cloud {msg.object_id!r}: density {msg.density:g} kg/m^3 outside "
                                           f"{MIN_DENSITY:g} .. {MAX_DENSITY:g}")
    # The frame headers state the decompressed sizes: checked against the point count without inflating.
    _framed_size(msg, msg.data, 3 * (msg.bits // 8) * msg.count, "points")
    if msg.normals:
        _framed_size(msg, msg.normals, 3 * msg.count, "normals")
    if msg.completed:
        _framed_size(msg, msg.completed, _completed_size(msg.count), "completed flags")
    if msg.support is not None:
        _finite(msg, msg.support)
        _coordinates(msg, msg.support[3:])
        norm = math.hypot(*msg.support[:3])
        if not abs(norm - 1.0) <= QUAT_NORM_TOLERANCE:
            raise MessageError("out-of-range", f"cloud {msg.object_id!r}: support plane normal of length {norm:.6g}, "
                                               f"not unit")


def _ordinals(msg: Message) -> None:
    """Stamps and sequence numbers: a negative epoch, seq or answers_ns is a bad sequence number; any of
    them (or a stamp) outside 0 .. :data:`MAX_INT64` is out of range."""
    for field in _ORDINALS:
        value = getattr(msg, field, 0)
        if value < 0 and field != "stamp_ns":
            raise MessageError("bad-seq", f"{type(msg).__name__}: negative {field}")
        if not 0 <= value <= MAX_INT64:
            raise MessageError("out-of-range", f"{type(msg).__name__}: {field} {value} outside 0 .. 2**63 - 1")


def _finite(msg: Message, *groups) -> None:  # type: ignore[no-untyped-def]
    if not all(math.isfinite(x) for g in groups for x in g):
        raise MessageError("non-finite", f"{type(msg).__name__}: NaN or infinite value")


def _coordinates(msg: Message, *groups) -> None:  # type: ignore[no-untyped-def]
    if any(abs(x) > MAX_COORDINATE for g in groups for x in g):
        raise MessageError("out-of-range", f"{type(msg).__name__}: a coordinate beyond {MAX_COORDINATE:g} m")


def _unit(msg: Message, quat: tuple[float, ...]) -> None:
    norm = math.sqrt(sum(x * x for x in quat)) if all(math.isfinite(x) for x in quat) else math.nan
    if not abs(norm - 1.0) <= QUAT_NORM_TOLERANCE:
        raise MessageError("bad-quaternion", f"{type(msg).__name__}: quaternion of norm {norm:.6g}, not unit")


def _vec(values, n: int) -> tuple:  # type: ignore[no-untyped-def]
    out = tuple(float(x) for x in np.asarray(values, dtype=np.float64).ravel())
    if len(out) != n:
        raise ValueError(f"expected {n} numbers, got {len(out)}")
    return out
