"""The wire format: versioned msgspec structs, msgpack-encoded; clouds quantised and zstd-compressed.

Every message carries ``v`` (the format version) and a ``stamp_ns`` (sender's wall clock,
``time.time_ns()``; latency across machines needs synchronised clocks). Decoding anything else (an
unknown type or version, a bad array size, garbage) raises :class:`MessageError`: receivers drop such a
message, count it and log it.

Clouds are quantised on a grid of ``quantum`` metres relative to their minimum corner (16 bits per axis
while the extent fits, else 32), sorted so neighbouring points have similar bytes, split into byte planes
and compressed with zstd. Point order carries no meaning for estimation.
"""

from __future__ import annotations

import time

import msgspec
import numpy as np

VERSION = 1

#: Default cloud quantisation step, metres: a tenth of a millimetre, well under a sensor's noise.
CLOUD_QUANTUM = 1e-4

_ZSTD_LEVEL = 3


class MessageError(ValueError):
    """A message that cannot be used: unknown type or version, bad size, or garbage."""


class _Msg(msgspec.Struct, array_like=True, tag_field="t", forbid_unknown_fields=True):
    v: int
    stamp_ns: int


class SceneInfo(_Msg, tag="scene"):
    """The static scene: table (size xyz, top height, friction) and end effector (radius, start)."""

    name: str
    table_size: tuple[float, float, float] | None
    table_height: float
    table_material: str
    ee_radius: float
    ee_position: tuple[float, float, float]


class Cloud(_Msg, tag="cloud"):
    """An object's point cloud in the world frame, with what is needed to estimate and place it.

    ``body_position``/``body_quat`` (w x y z) is the remote body's pose when the cloud was taken: the twin
    maps later remote poses onto its own body through it.
    """

    object_id: str
    seq: int
    count: int
    bits: int
    quantum: float
    origin: tuple[float, float, float]
    data: bytes
    material: str | None
    density: float | None
    body_position: tuple[float, float, float]
    body_quat: tuple[float, float, float, float]


class Pose(_Msg, tag="pose"):
    """A remote body's pose and velocity (world frame and axes; quaternion w x y z; m/s and rad/s)."""

    object_id: str
    seq: int
    sim_time: float
    position: tuple[float, float, float]
    quat: tuple[float, float, float, float]
    linvel: tuple[float, float, float]
    angvel: tuple[float, float, float]


class Gone(_Msg, tag="gone"):
    object_id: str
    seq: int


class Heartbeat(_Msg, tag="heartbeat"):
    seq: int
    sim_time: float
    objects: int


class OperatorCommand(_Msg, tag="operator"):
    """The operator's end-effector target, world frame, metres."""

    seq: int
    position: tuple[float, float, float]


Message = SceneInfo | Cloud | Pose | Gone | Heartbeat | OperatorCommand

_encoder = msgspec.msgpack.Encoder()
_decoder = msgspec.msgpack.Decoder(Message)


def now_ns() -> int:
    return time.time_ns()


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
        raise MessageError(f"undecodable message ({exc})") from exc
    if msg.v != VERSION:
        raise MessageError(f"message version {msg.v}, expected {VERSION}")
    if isinstance(msg, Cloud):
        _check_cloud(msg)
    return msg


def pack_points(points: np.ndarray, quantum: float = CLOUD_QUANTUM) -> tuple[int, int, tuple[float, float, float], bytes]:
    """(count, bits, origin, compressed bytes) of an (n, 3) cloud in metres."""
    import zstandard

    points = np.asarray(points, dtype=np.float64)
    origin = points.min(axis=0)
    q = np.round((points - origin) / quantum)
    bits = 16 if q.max() < 2**16 else 32
    q = q.astype(np.uint16 if bits == 16 else np.uint32)
    q = q[np.lexsort((q[:, 2], q[:, 1], q[:, 0]))]
    # Byte planes: all high bytes together, then the low ones; sorted columns make runs zstd finds.
    planes = np.ascontiguousarray(q.T).view(np.uint8).reshape(3, len(q), bits // 8).transpose(0, 2, 1)
    data = zstandard.ZstdCompressor(level=_ZSTD_LEVEL).compress(np.ascontiguousarray(planes).tobytes())
    return len(points), bits, (float(origin[0]), float(origin[1]), float(origin[2])), data


def unpack_points(msg: Cloud) -> np.ndarray:
    """The (n, 3) float64 cloud of a :class:`Cloud` message, metres."""
    import zstandard

    width = msg.bits // 8
    try:
        raw = zstandard.ZstdDecompressor().decompress(msg.data, max_output_size=3 * width * msg.count)
    except zstandard.ZstdError as exc:
        raise MessageError(f"cloud {msg.object_id!r}: corrupt compressed data ({exc})") from exc
    if len(raw) != 3 * width * msg.count:
        raise MessageError(f"cloud {msg.object_id!r}: {len(raw)} bytes for {msg.count} points")
    planes = np.frombuffer(raw, np.uint8).reshape(3, width, msg.count).transpose(0, 2, 1)
    q = np.ascontiguousarray(planes).view(np.uint16 if width == 2 else np.uint32).reshape(3, msg.count).T
    return q.astype(np.float64) * msg.quantum + np.asarray(msg.origin)


def cloud_message(object_id: str, seq: int, points: np.ndarray, *, material: str | None, density: float | None,
                  body_position: np.ndarray, body_quat: np.ndarray, quantum: float = CLOUD_QUANTUM) -> Cloud:
    count, bits, origin, data = pack_points(points, quantum)
    return Cloud(v=VERSION, stamp_ns=now_ns(), object_id=object_id, seq=seq, count=count, bits=bits,
                 quantum=quantum, origin=origin, data=data, material=material, density=density,
                 body_position=_vec(body_position, 3), body_quat=_vec(body_quat, 4))


def _check_cloud(msg: Cloud) -> None:
    if msg.bits not in (16, 32) or msg.count <= 0 or not (0 < msg.quantum < 1):
        raise MessageError(f"cloud {msg.object_id!r}: bad header (bits {msg.bits}, count {msg.count}, "
                           f"quantum {msg.quantum})")
    if not np.all(np.isfinite(msg.origin)):
        raise MessageError(f"cloud {msg.object_id!r}: non-finite origin")


def _vec(values, n: int) -> tuple:  # type: ignore[no-untyped-def]
    out = tuple(float(x) for x in np.asarray(values, dtype=np.float64).ravel())
    if len(out) != n:
        raise ValueError(f"expected {n} numbers, got {len(out)}")
    return out
