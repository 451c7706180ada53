"""Recordings of sessions: MCAP files any MCAP tool (Foxglove, ``mcap`` CLI) can open. Not a pickle.

What a recording holds, one MCAP channel per topic:

``/wire/<side>/<sent|received>/<key>``
    Every wire message one side (``remote`` or ``twin``) put or received on a Zenoh key (or the in-process
    bus), its bytes as they crossed the wire (message encoding ``msgpack``, no MCAP schema: the layout is
    :mod:`sync.messages`, format version ``v`` in each message; the channel's metadata names it
    ``tactile_twin.wire`` with ``side``, ``direction`` and ``key``). ``log_time`` is when this side sent
    or received it, ``publish_time`` the sender's ``stamp_ns`` inside the message (the send time; for a
    received message that cannot be parsed, the receive time). Query replies count as sent by the side
    that answered and received by the side that asked.
``/operator/target``
    The end-effector target the twin applied at each loop iteration (JSON, schema
    ``tactile_twin.OperatorTarget``: ``sim_time`` s of the twin, ``position`` {x, y, z} m, world frame).
``/operator/force``
    The force the operator should feel (JSON, ``tactile_twin.OperatorForce``: ``sim_time``, ``force``
    {x, y, z} N, world axes), decimated to ``truth_rate``.
``/truth/transforms``
    Ground truth where the process has it (the remote's true poses), decimated to ``truth_rate`` (JSON,
    ``foxglove.FrameTransforms``, so Foxglove's 3D panel draws them: frame ``truth/<id>`` in ``world``,
    origin at the centre of mass; plus ``sim_time``, the remote's time, s).

Plus one MCAP metadata record ``tactile_twin.session`` at the start (``schema_version``, ``tool_version``,
``clock`` ``real``/``sim``, ``scene_name``, ``scene_toml`` (the scene file's text, "" when the process
has none), ``scene_dir``, ``seeds`` and ``network`` (JSON), ``side``, ``command``, ``dt``, and ``sensor``, the
remote's sensor by name (``surface``, ``cameras``), which replay rebuilds and checks: absent from ``twin local``'s
recordings, which do not know it, and from those made before it was recorded) and
``tactile_twin.end`` when the recording is closed properly (``messages``, ``duration_s``, ``not_recorded``:
messages past :data:`MAX_CHANNELS` topics or :data:`MAX_RECORDED_TOPIC` characters).

Times are the recording process's clock (:meth:`sync.clock.Clock.stamp_ns`: wall nanoseconds live,
simulated nanoseconds headless), taken under one lock as each record is queued and never allowed to go
back, so ``log_time`` is monotonic per channel and across the file. Records are written by one
background thread (a Zenoh callback only queues); :meth:`Recorder.close` drains and finishes the file.

:func:`read_recording` checks the schema version and reads as far as the file is intact: a torn tail (a
killed process, a truncated copy) is reported in ``Recording.damage`` with how many records were read,
and what came before it is kept.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import queue
import struct
import threading
import zlib
from array import array
from collections import Counter
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from estimation.errors import TwinError
from sync.clock import Clock
from sync.messages import MAX_COORDINATE, QUAT_NORM_TOLERANCE, peek_stamp
from sync.replacing import found_at, hidden_sibling
from sync.transport import Answer, OnSample, Transport

log = logging.getLogger(__name__)

#: The layout of recordings this module writes and reads (channels, schemas, metadata keys).
SCHEMA_VERSION = 1

#: MCAP profile string in the file header.
PROFILE = "tactile-twin"

#: Ground truth and force samples per simulated (or real) second: 100 Hz shows a push's motion and keeps
#: a 20-object scene under ~10 KB/s compressed.
DEFAULT_TRUTH_RATE_HZ = 100.0

#: Uncompressed bytes per MCAP chunk: a torn tail loses at most the chunk being written (the default
#: 1 MiB would lose seconds of a session).
CHUNK_BYTES = 64 * 1024

#: Slack when comparing a sampled side's time with the next sample time: step times are float sums
#: (0.001 added a thousand times is not 1.0), and a microsecond is far below any physics step.
_TIME_SLACK = 1e-6

#: The largest record a recording may hold once decompressed (a chunk, a message, metadata), bytes: a
#: 10 M-point cloud (:data:`sync.messages.MAX_CLOUD_POINTS`) packs to well under it, while a 27 KB file of
#: zstd-compressed zeros once claimed 200 MB per message. Checked before and while decompressing.
MAX_RECORD_BYTES = 128 * 2**20

#: The most a recording may hold in all, decompressed, bytes: an hour's live session is a few hundred MB.
MAX_RECORDING_BYTES = 1 * 2**30

#: The most records a recording may hold: an hour's headless session (a 1 s push recorded 3,807: three a 1 kHz
#: tick, poses, truth and forces), 13.7 M, with room. Each costs ~280 bytes of Python once read whatever its
#: size, so the byte limit alone let a 12.5 KB file of empty messages hold 4 M records in 1.1 GB, and ~34 M.
MAX_RECORDS = 16_000_000

#: Topics (MCAP channels) a recording makes at most: MCAP numbers channels in 16 bits. A session has a few a
#: wire key (two or three keys an object, at most a thousand objects); past this, messages on new topics are
#: counted in ``Recorder.dropped``, not recorded.
MAX_CHANNELS = 16_384

#: Longest topic recorded, characters: a wire key holds a scene name and an object id (64 each) and a few words.
MAX_RECORDED_TOPIC = 512

#: The most records a recording may hold per byte of its file. A recording's records take 20-40 bytes each
#: compressed with their message index (a target a millisecond, 25 B if it never moves, 34 B if it does); a 43 KB
#: file of 16 M empty messages packed into four zstd chunks took 4 GB to read. One a byte leaves 20x room for a
#: writer that packs tighter than ours and keeps such a file to a few hundred bytes of Python per byte read.
MAX_RECORDS_PER_BYTE = 1

#: The largest ground-truth record read, bytes of JSON: a transform takes ~250, so a thousand objects (the most a
#: scene holds) ~250 KB. Parsed, JSON takes ~12 times its size in Python: a 96 KB file of eight 120 MiB truth
#: records, within every limit above, took 7.5 GB to replay (a hostile-input review's find).
MAX_TRUTH_RECORD_BYTES = 4 * 2**20

#: The longest replay, twin seconds: the live commands' default session (an hour). A replay also runs no
#: longer than its recording holds (:meth:`Recording.span_s` plus :data:`RECORDED_TIME_SLACK_S`).
MAX_REPLAY_SECONDS = 3600.0

#: How far a recorded twin time may run past the recording's own span of log times, seconds: the twin's
#: clock starts after the recorder's, and a step or a late final record is far below a second.
RECORDED_TIME_SLACK_S = 1.0

#: The first bytes of every MCAP file: a non-empty existing file without them is not a recording a recorder may
#: replace (:func:`check_record_destination`).
MCAP_MAGIC = b"\x89MCAP0\r\n"

WIRE_SCHEMA = "tactile_twin.wire"
TARGET_TOPIC = "/operator/target"
FORCE_TOPIC = "/operator/force"
TRUTH_TOPIC = "/truth/transforms"
WIRE_PREFIX = "/wire/"

_VEC3 = {"type": "object", "properties": {a: {"type": "number"} for a in "xyz"}, "required": list("xyz")}
_TIME = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}
_SCHEMAS: dict[str, tuple[str, dict]] = {
    TARGET_TOPIC: ("tactile_twin.OperatorTarget", {
        "type": "object", "title": "end-effector target applied by the twin (metres, world frame)",
        "properties": {"sim_time": {"type": "number", "description": "twin time, s"}, "position": _VEC3},
        "required": ["sim_time", "position"]}),
    FORCE_TOPIC: ("tactile_twin.OperatorForce", {
        "type": "object", "title": "net contact force on the end effector (newtons, world axes)",
        "properties": {"sim_time": {"type": "number"}, "force": _VEC3}, "required": ["sim_time", "force"]}),
    TRUTH_TOPIC: ("foxglove.FrameTransforms", {
        "type": "object", "title": "foxglove.FrameTransforms (ground truth, centre of mass frames)",
        "properties": {
            "sim_time": {"type": "number", "description": "the remote's time, s"},
            "transforms": {"type": "array", "items": {
                "type": "object",
                "properties": {
                    "timestamp": _TIME, "parent_frame_id": {"type": "string"}, "child_frame_id": {"type": "string"},
                    "translation": _VEC3,
                    "rotation": {"type": "object", "properties": {a: {"type": "number"} for a in "xyzw"}},
                }}}},
        "required": ["transforms"]}),
}


class RecordingError(TwinError, ValueError):
    """A recording that cannot be written or read: missing, not MCAP, corrupt, or of another schema."""


# -- writing -----------------------------------------------------------------------------------------


class Recorder:
    """Writes one session to an MCAP file. Thread-safe: any thread may log; one thread writes.

    The file is written as a hidden sibling (``.<name>.<random>.partial``, an MCAP file too, so a killed
    process leaves its torn recording there) and renamed onto ``path`` by :meth:`close`: an existing file at
    ``path`` is replaced only when the session has run; :meth:`discard` drops the sibling instead (a command
    that failed before it started).

    Args:
        path: the ``.mcap`` file (created or replaced when the recording is closed).
        clock: the session's clock (its ``stamp_ns`` times every record; ``realtime`` names the clock kind).
        metadata: more ``tactile_twin.session`` entries (``scene_name``, ``scene_toml``, ``seeds``, ...);
            values are strings, or JSON-encoded when they are not.
        truth_rate: ground-truth and force samples per second of the sampled side's time.

    Raises:
        RecordingError: ``path`` is a folder, a device or pipe, or an existing file that is neither empty nor an
            MCAP recording (:func:`check_record_destination`), or the file cannot be created.
    """

    def __init__(self, path: str | Path, *, clock: Clock, metadata: Mapping[str, object] | None = None,
                 truth_rate: float = DEFAULT_TRUTH_RATE_HZ) -> None:
        from mcap.writer import Writer

        self.path = Path(path)
        self.clock = clock
        if not (math.isfinite(truth_rate) and truth_rate > 0):
            raise RecordingError(f"truth rate must be a positive number of samples per second, got {truth_rate}")
        self.truth_every = 1.0 / truth_rate
        check_record_destination(self.path)  # now, not at close(): a folder there cost the whole session
        try:
            fd, self._partial = hidden_sibling(self.path, ".partial")
            self._file = os.fdopen(fd, "wb")  # closed by close()
        except OSError as exc:
            raise RecordingError(f"{self.path}: cannot write a recording ({exc.strerror or exc})") from None
        # The data section's CRC covers what chunks' CRCs do not: the session metadata (scene, network, seeds),
        # where a flipped digit replayed another scene without a word.
        self._writer = Writer(self._file, chunk_size=CHUNK_BYTES, enable_data_crcs=True)
        self._writer.start(profile=PROFILE, library="tactile-twin")  # what written_here() knows it by
        meta = {"schema_version": str(SCHEMA_VERSION), "tool_version": tool_version(),
                "clock": "real" if clock.realtime else "sim"}
        meta.update({k: v if isinstance(v, str) else json.dumps(v) for k, v in (metadata or {}).items()})
        self._writer.add_metadata("tactile_twin.session", meta)
        self._channels: dict[str, int] = {}
        self._topics: set[str] = set()  # topics logged so far (their channels are made by the writing thread)
        self.dropped = 0  # messages not recorded: on a topic past MAX_CHANNELS, or one past MAX_RECORDED_TOPIC
        self._write_failures = 0
        self._lock = threading.Lock()
        self._last_ns = -1
        self._first_ns: int | None = None
        self.messages = 0
        self._next_truth: float | None = None
        self._next_force: float | None = None
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._drain, name="recorder", daemon=True)
        self._thread.start()
        self._closed = False

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # what the session logs

    def wire(self, side: str, direction: str, key: str, data: bytes) -> None:
        """One wire message ``side`` sent or received (``direction``: ``"sent"`` or ``"received"``) on ``key``."""
        self._log(f"{WIRE_PREFIX}{side}/{direction}/{key}", bytes(data), peek_stamp(data),
                  {"side": side, "direction": direction, "key": key})

    def target(self, sim_time: float, position: np.ndarray) -> None:
        """The end-effector target the twin applied at ``sim_time`` (metres, world frame)."""
        self._json(TARGET_TOPIC, {"sim_time": float(sim_time), "position": _xyz(position)})

    def force_due(self, sim_time: float) -> bool:
        """Whether a force sample is due at ``sim_time`` (so the caller computes the force only then)."""
        return self._next_force is None or sim_time + _TIME_SLACK >= self._next_force

    def force(self, sim_time: float, force: np.ndarray) -> None:
        """The operator's force at ``sim_time`` (newtons, world axes); kept at ``truth_rate``."""
        if not self.force_due(sim_time):
            return
        self._next_force = _next_sample(self._next_force, sim_time, self.truth_every)
        self._json(FORCE_TOPIC, {"sim_time": float(sim_time), "force": _xyz(force)})

    def truth_due(self, sim_time: float) -> bool:
        """Whether a ground-truth sample is due at ``sim_time`` (call :meth:`truth` if so)."""
        return self._next_truth is None or sim_time + _TIME_SLACK >= self._next_truth

    def truth(self, sim_time: float, poses: Mapping[str, tuple[np.ndarray, np.ndarray]]) -> None:
        """True poses at ``sim_time``: ``{id: (position (3,) m, quaternion (4,) w x y z)}``, world frame."""
        self._next_truth = _next_sample(self._next_truth, sim_time, self.truth_every)
        sec, nsec = divmod(round(sim_time * 1e9), 1_000_000_000)
        self._json(TRUTH_TOPIC, {"sim_time": float(sim_time), "transforms": [
            {"timestamp": {"sec": sec, "nsec": nsec}, "parent_frame_id": "world", "child_frame_id": f"truth/{i}",
             "translation": _xyz(p), "rotation": _foxglove_quat(q)} for i, (p, q) in poses.items()]})

    def close(self, **end: object) -> None:
        """Drain the queue, finish the file and rename it onto ``path`` (idempotent); ``end`` goes into
        ``tactile_twin.end``.

        Raises:
            RecordingError: finishing the file failed (it is removed: not a whole recording), or the rename
                failed (``path`` became a folder during the session, the file system refused): the whole
                recording stays in its hidden file, which the error names.
        """
        if not self._stop():
            return
        duration = 0.0 if self._first_ns is None else (self._last_ns - self._first_ns) * 1e-9
        self._writer.add_metadata("tactile_twin.end", {"messages": str(self.messages), "duration_s": repr(duration),
                                                       "not_recorded": str(self.dropped),
                                                       **{k: str(v) for k, v in end.items()}})
        try:
            self._writer.finish()
            self._file.close()
        except OSError as exc:  # the file is not whole (a full disk): nothing worth keeping
            with contextlib.suppress(OSError):  # a close that failed to flush may fail again
                self._file.close()
            self._partial.unlink(missing_ok=True)
            raise RecordingError(f"{self.path}: cannot finish the recording ({exc.strerror or exc}); "
                                 "the session was not recorded") from None
        try:
            os.replace(self._partial, self.path)
        except OSError as exc:  # a whole recording: kept where it is, and said where
            raise RecordingError(f"{self.path}: cannot put the recording in place ({exc.strerror or exc}); "
                                 f"it is kept as {self._partial}") from None

    def discard(self) -> None:
        """Stop recording and delete what was written; ``path`` is left as it was (idempotent)."""
        if not self._stop():
            return
        self._file.close()
        self._partial.unlink(missing_ok=True)

    def _stop(self) -> bool:
        """Stop the writer thread once it has written what is queued; False if it was stopped before."""
        if self._closed:
            return False
        self._closed = True
        self._queue.put(None)
        self._thread.join()
        return True

    # internals

    def _json(self, topic: str, record: dict) -> None:
        self._log(topic, json.dumps(record, allow_nan=False).encode(), None, None)

    def _log(self, topic: str, data: bytes, publish_ns: int | None, meta: dict[str, str] | None) -> None:
        if self._closed:
            return
        with self._lock:  # the stamp and the queue position are taken together: log_time never goes back
            if topic not in self._topics:
                # A wire channel a key: a flood of ever new keys (garbage, before any check) made 65,536 channels,
                # past MCAP's 16-bit channel ids: a struct.error at every message after, and the recording lost.
                if len(self._topics) >= MAX_CHANNELS or len(topic) > MAX_RECORDED_TOPIC:
                    self.dropped += 1
                    if self.dropped == 1:
                        log.warning("%s: a message on %s not recorded: more than %d topics, or a topic past %d "
                                    "characters (a flood of garbage keys?); such messages are counted, not recorded",
                                    self.path, topic[:200], MAX_CHANNELS, MAX_RECORDED_TOPIC)
                    return
                self._topics.add(topic)
            now = max(self.clock.stamp_ns(), self._last_ns)
            self._last_ns = now
            if self._first_ns is None:
                self._first_ns = now
            self.messages += 1
            self._queue.put((topic, data, now, now if publish_ns is None else publish_ns, meta))

    def _drain(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            topic, data, log_ns, publish_ns, meta = item
            try:
                channel = self._channels.get(topic)
                if channel is None:
                    channel = self._channels[topic] = self._register(topic, meta)
                self._writer.add_message(channel, log_time=log_ns, data=data, publish_time=max(0, publish_ns))
            except Exception:  # a write error must not kill the thread and leave close() waiting
                self._write_failures += 1
                if self._write_failures <= 3:  # a full disk fails every message: a few tracebacks say it
                    log.exception("writing %s to %s failed", topic, self.path)

    def _register(self, topic: str, meta: dict[str, str] | None) -> int:
        if topic.startswith(WIRE_PREFIX):
            return self._writer.register_channel(topic, "msgpack", 0, {"schema": WIRE_SCHEMA, **(meta or {})})
        name, schema = _SCHEMAS[topic]
        sid = self._writer.register_schema(name, "jsonschema", json.dumps(schema).encode())
        return self._writer.register_channel(topic, "json", sid)


class RecordingTransport:
    """A :class:`sync.transport.Transport` that logs what crosses it to a :class:`Recorder`, then passes it on.

    Wraps any transport (Zenoh, in-process); ``side`` names this end in the channel names. The receive
    callback logs and calls through on the inner transport's thread (logging only queues).
    """

    def __init__(self, inner: Transport, recorder: Recorder, side: str) -> None:
        self.inner = inner
        self.recorder = recorder
        self.side = side

    def put(self, key: str, data: bytes) -> None:
        self.recorder.wire(self.side, "sent", key, data)  # first: an in-process put delivers synchronously
        self.inner.put(key, data)

    def subscribe(self, keyexpr: str, callback: OnSample) -> None:
        def received(key: str, data: bytes) -> None:
            self.recorder.wire(self.side, "received", key, data)
            callback(key, data)

        self.inner.subscribe(keyexpr, received)

    def queryable(self, keyexpr: str, answer: Answer) -> None:
        def answered(selector: str) -> list[tuple[str, bytes]]:
            replies = answer(selector)
            for key, data in replies:
                self.recorder.wire(self.side, "sent", key, data)
            return replies

        self.inner.queryable(keyexpr, answered)

    def get(self, selector: str, timeout: float) -> list[tuple[str, bytes]]:
        replies = self.inner.get(selector, timeout)
        for key, data in replies:
            self.recorder.wire(self.side, "received", key, data)
        return replies

    def close(self) -> None:
        self.inner.close()


# -- reading -----------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)  # slots: a recording holds millions of them (~170 bytes each with slots)
class Record:
    """One message of a recording: its channel's topic, times (ns of the recording's clock), bytes."""

    topic: str
    log_time: int
    publish_time: int
    data: bytes

    def json(self) -> dict:
        return json.loads(self.data)


@dataclass(frozen=True)
class WireRecord:
    """One wire message: which side, ``sent`` or ``received``, on which key, when (ns), its bytes."""

    side: str
    direction: str
    key: str
    log_time: int
    publish_time: int
    data: bytes


@dataclass
class Recording:
    """What :func:`read_recording` found. ``damage`` is None for a whole file, else what stopped the read."""

    path: Path
    metadata: dict[str, str]
    records: list[Record]
    end: dict[str, str] | None = None
    damage: str | None = None
    counts: Counter = field(default_factory=Counter)

    @property
    def schema_version(self) -> int:
        return int(self.metadata["schema_version"])

    def topic(self, topic: str) -> list[Record]:
        return [r for r in self.records if r.topic == topic]

    def wire(self) -> list[WireRecord]:
        out = []
        for r in self.records:
            if r.topic.startswith(WIRE_PREFIX):
                side, direction, key = r.topic[len(WIRE_PREFIX):].split("/", 2)
                out.append(WireRecord(side, direction, key, r.log_time, r.publish_time, r.data))
        return out

    @property
    def span_s(self) -> float:
        """Seconds between the first and the last record's log time (the recording clock's)."""
        if not self.records:
            return 0.0
        return (max(r.log_time for r in self.records) - min(r.log_time for r in self.records)) * 1e-9

    def latest_time(self) -> float:
        """The latest twin time the recording can hold, seconds: its span, the slack, at most the maximum."""
        return min(self.span_s + RECORDED_TIME_SLACK_S, MAX_REPLAY_SECONDS)

    def targets(self) -> tuple[np.ndarray, np.ndarray]:
        """The operator's targets: (times (n,) float64 s of the twin, positions (n, 3) float64 m, world).

        Raises:
            RecordingError: a target that is not a JSON object with a ``sim_time`` from 0 to
                :meth:`latest_time` (ascending) and a ``position`` {x, y, z} within
                :data:`sync.messages.MAX_COORDINATE` metres.
        """
        latest = self.latest_time()
        times, points = [], []
        for r in self.topic(TARGET_TOPIC):
            row = self._object(r)
            t = self._number(row, "sim_time", r.topic, 0.0, latest)
            times.append(self._not_back(r, t, times[-1] if times else None))
            points.append(self._vector(row, "position", "xyz", r.topic, MAX_COORDINATE))
        return np.array(times, dtype=np.float64), np.array(points, dtype=np.float64).reshape(-1, 3)

    def truth(self) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Ground truth per object: (times (n,) s, positions (n, 3) m, quaternions (n, 4) w x y z), world.

        Raises:
            RecordingError: a record that is not a JSON object with a ``sim_time`` from 0 to
                :meth:`latest_time` (ascending: replay looks samples up by time) and a list of ``transforms``,
                each with a string ``child_frame_id``, a ``translation`` {x, y, z} within
                :data:`sync.messages.MAX_COORDINATE` m and a ``rotation`` {x, y, z, w}.
        """
        latest = self.latest_time()
        # Each object's samples as doubles (time, x y z, w x y z) in a flat array: 64 bytes a sample, where a tuple of
        # lists took ~300 (an hour of 20 objects at 100 Hz is 7.2 M samples).
        rows: dict[str, array] = {}
        previous: float | None = None
        for r in self.topic(TRUTH_TOPIC):
            if len(r.data) > MAX_TRUTH_RECORD_BYTES:
                raise RecordingError(f"{self.path}: a {r.topic} record of {len(r.data):,} bytes, more than the "
                                     f"{MAX_TRUTH_RECORD_BYTES >> 20} MiB a thousand objects' poses take")
            msg = self._object(r)
            t = previous = self._not_back(r, self._number(msg, "sim_time", r.topic, 0.0, latest), previous)
            transforms = msg.get("transforms")
            if not isinstance(transforms, list):
                raise RecordingError(f"{self.path}: a {r.topic} record's transforms is not a list")
            for tf in transforms:
                if not isinstance(tf, dict) or not isinstance(tf.get("child_frame_id"), str):
                    raise RecordingError(f"{self.path}: a {r.topic} record's child_frame_id is not a string")
                object_id = tf["child_frame_id"].removeprefix("truth/")
                p = self._vector(tf, "translation", "xyz", r.topic, MAX_COORDINATE)
                x, y, z, w = self._vector(tf, "rotation", "xyzw", r.topic, 1.0 + QUAT_NORM_TOLERANCE)
                rows.setdefault(object_id, array("d")).extend((t, *p, w, x, y, z))
        table = {i: np.frombuffer(v, dtype=np.float64).reshape(-1, 8) for i, v in rows.items()}
        return {i: (v[:, 0].copy(), v[:, 1:4].copy(), v[:, 4:8].copy()) for i, v in table.items()}

    def end_time(self) -> float | None:
        """The twin time the end record says the session stopped at (None: no end record, or none given, or a
        damaged recording whose intact records end before it).

        Raises:
            RecordingError: ``twin_time_s`` is not a number from 0 to :meth:`latest_time`.
        """
        raw = (self.end or {}).get("twin_time_s")
        if raw is None or raw == "None":  # a twin that never started records None
            return None
        try:
            t = float(raw)
        except (ValueError, TypeError, OverflowError):
            raise RecordingError(f"{self.path}: the end record's twin_time_s {raw!r} is not a number") from None
        if self.damage is not None and math.isfinite(t) and t > self.latest_time():
            # Damaged chunks at the end took the records up to the stop with them: the intact part replays (to
            # its last target or truth), and the damage note says what was lost, not this time.
            return None
        return self._in_range(t, "the end record's twin_time_s", 0.0, self.latest_time())

    # checks of decoded fields: one line naming the record kind and the field

    def _object(self, r: Record) -> dict:
        try:
            doc = json.loads(r.data)
        except (ValueError, UnicodeDecodeError, RecursionError):  # nested past Python's stack: not a record of ours
            raise RecordingError(f"{self.path}: a {r.topic} record is not JSON") from None
        if not isinstance(doc, dict):
            raise RecordingError(f"{self.path}: a {r.topic} record is not a JSON object")
        return doc

    def _number(self, doc: dict, key: str, topic: str, low: float, high: float, *, name: str | None = None) -> float:
        value, name = doc.get(key), name or key
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise RecordingError(f"{self.path}: a {topic} record's {name} is "
                                 f"{'missing' if value is None else 'not a number'}")
        try:
            number = float(value)
        except OverflowError:  # JSON holds integers of any length; 1e400 as digits was a traceback
            raise RecordingError(f"{self.path}: a {topic} record's {name} is an integer of about "
                                 f"{int(value.bit_length() * math.log10(2)) + 1} digits, outside [{low:g}, {high:g}]") from None
        return self._in_range(number, f"a {topic} record's {name}", low, high)

    def _in_range(self, value: float, what: str, low: float, high: float) -> float:
        if not (math.isfinite(value) and low <= value <= high):
            note = (f" (the recording holds {self.span_s:.3g} s of records; a replay runs at most "
                    f"{MAX_REPLAY_SECONDS:g} s)" if what.endswith("time") or what.endswith("time_s") else "")
            raise RecordingError(f"{self.path}: {what} {value:g} is outside [{low:g}, {high:g}]{note}")
        return value

    def _not_back(self, r: Record, t: float, previous: float | None) -> float:
        """``t``, record ``r``'s ``sim_time``, unless it is earlier than ``previous`` (the last on its topic;
        None: ``r`` is the first). Equal times pass: two records at one step are not out of order."""
        if previous is not None and t < previous:
            raise RecordingError(f"{self.path}: a {r.topic} record's sim_time {t:g} s goes back (previous "
                                 f"{previous:g} s)")
        return t

    def _vector(self, doc: dict, key: str, axes: str, topic: str, bound: float) -> list[float]:
        v = doc.get(key)
        if not isinstance(v, dict):
            raise RecordingError(f"{self.path}: a {topic} record's {key} is not an object {{{', '.join(axes)}}}")
        return [self._number(v, a, topic, -bound, bound, name=f"{key}.{a}") for a in axes]


def read_recording(path: str | Path) -> Recording:
    """Read a recording as far as it is intact.

    A chunk whose compressed data or CRC is damaged, but whose framing is whole, is skipped and the read
    goes on: one flipped byte costs that chunk's messages (:data:`CHUNK_BYTES` of records, counted from
    the message index that follows it), not the rest of the session. Damage to the framing itself ends
    the read there (a torn or corrupt tail).

    Args:
        path: an ``.mcap`` file written by :class:`Recorder`.

    Returns:
        The recording; ``damage`` says what was skipped or ended the read early (the records kept are in
        ``records`` and ``counts`` says how many of each topic).

    Raises:
        RecordingError: no such file, not an MCAP file, no ``tactile_twin.session`` metadata before the
            damage, a schema version this code does not read, a record past :data:`MAX_RECORD_BYTES` before
            the session metadata (after it, such a length is damage: the read ends there), a chunk or a
            file past :data:`MAX_RECORD_BYTES` / :data:`MAX_RECORDING_BYTES` decompressed, or a bad end record
            (:meth:`Recording.end_time`).
    """
    from mcap.exceptions import McapError, RecordLengthLimitExceeded
    from mcap.records import Channel, Chunk, DataEnd, Message, MessageIndex, Metadata
    from mcap.stream_reader import CRCValidationError, StreamReader

    path = Path(path)
    check_recording_file(path)
    metadata: dict[str, str] | None = None
    end: dict[str, str] | None = None
    topics: dict[int, str] = {}
    held: list[Record | None] = []  # in file order
    unknown: list[tuple[int, int]] = []  # (index in held, channel id) of messages whose channel comes later
    skipped: list[_Skipped] = []
    damage: str | None = None
    try:
        f = open(path, "rb")
        limit = min(MAX_RECORDS, MAX_RECORDS_PER_BYTE * os.fstat(f.fileno()).st_size)
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read the recording ({exc.strerror or exc})") from None
    with f:
        reader = StreamReader(f, validate_crcs=True, emit_chunks=True, record_size_limit=MAX_RECORD_BYTES)
        total = 0  # bytes held, decompressed

        def unchunked():  # type: ignore[no-untyped-def]
            nonlocal total
            in_skipped = False  # the message indexes after a skipped chunk count what it held
            for rec in reader.records:
                if isinstance(rec, Chunk):
                    try:
                        data = _inflate(path, rec)
                    except McapError as exc:
                        skipped.append(_Skipped(str(exc), rec.message_start_time, rec.message_end_time))
                        in_skipped = True
                        continue
                    in_skipped = False
                    total += len(data)
                    _check_total(path, total)
                    yield from _chunk_records(data)
                elif isinstance(rec, MessageIndex):
                    if in_skipped:
                        skipped[-1].messages += len(rec.records)
                else:
                    in_skipped = False
                    if isinstance(rec, Message):
                        total += len(rec.data)
                        _check_total(path, total)
                    yield rec

        try:
            for rec in unchunked():
                if isinstance(rec, Metadata):
                    if rec.name == "tactile_twin.session":
                        metadata = dict(rec.metadata)
                        _check_version(path, metadata)
                    elif rec.name == "tactile_twin.end":
                        end = dict(rec.metadata)
                elif isinstance(rec, Channel):
                    topics[rec.id] = rec.topic
                elif isinstance(rec, Message):
                    # A channel is declared in the chunk of its first message; after a skipped chunk it may be
                    # known only from the summary at the end of the file, so it is looked up then.
                    if rec.channel_id not in topics and not skipped:
                        raise McapError(f"message on unknown channel {rec.channel_id}")
                    if len(held) >= limit:
                        raise RecordingError(_too_many(path, limit))
                    topic = topics.get(rec.channel_id)
                    if topic is None:
                        unknown.append((len(held), rec.channel_id))
                        topic = ""
                    held.append(Record(topic, rec.log_time, rec.publish_time, rec.data))
        except RecordingError:
            raise
        except RecordLengthLimitExceeded as exc:
            # Past the session metadata, a length past the limit is damaged framing like any other (one byte of
            # a chunk's length field): what came before it is kept, as for a torn tail.
            if metadata is None:
                raise RecordingError(f"{path}: a record is larger than the {MAX_RECORD_BYTES >> 20} MiB limit ({exc})") from None
            damage = (f"the recording is damaged after {len(held)} messages (a record claims more than the "
                      f"{MAX_RECORD_BYTES >> 20} MiB limit: {exc}); using those")
        except CRCValidationError as exc:
            if metadata is None or not isinstance(exc.record, DataEnd):
                raise RecordingError(f"{path}: not a readable tactile-twin recording ({exc})") from None
            # Read to its end: every record parsed, but some byte changed, maybe in the scene or the settings.
            damage = (f"the recording fails its checksum (a byte changed since it was written: its scene, "
                      f"network or messages may not be what was recorded); using its {len(held)} messages")
        except (McapError, ValueError, struct.error, zlib.error, EOFError, MemoryError, OverflowError,
                UnicodeDecodeError) as exc:
            # OverflowError: a length field past 2**63 (one flipped top bit) is no index the reader can slice with.
            # ValueError covers the reader's chunk CRC mismatch; _inflate turns zstd's and lz4's errors into McapError.
            # A name or text field of random bytes: "UnicodeDecodeError: 'utf-8' codec can't ..." named Python's
            # codec, not the file's fault.
            what = ("a record's text is not UTF-8" if isinstance(exc, UnicodeDecodeError)
                    else type(exc).__name__ + (f": {exc}" if str(exc) else ""))
            if metadata is None:
                raise RecordingError(f"{path}: not a readable tactile-twin recording ({what})") from None
            damage = f"the recording is damaged after {len(held)} messages ({what}); using those"
    if metadata is None:
        raise RecordingError(f"{path}: no tactile_twin.session metadata: not a tactile-twin recording")
    for i, channel in unknown:
        r = held[i]
        held[i] = None if channel not in topics or r is None else Record(topics[channel], r.log_time,
                                                                         r.publish_time, r.data)
    records = [r for r in held if r is not None] if unknown else held
    notes = [_skipped_note(skipped, len(held) - len(records))] if skipped else []
    if damage is not None:
        notes.append(damage)
    damage = f"{path}: " + "; ".join(notes) if notes else None
    recording = Recording(path, metadata, records, end, damage, Counter(r.topic for r in records))
    recording.end_time()  # checked here, whatever the caller reads (targets and truth: when they are read)
    return recording


def _too_many(path: Path, limit: int) -> str:
    if limit == MAX_RECORDS:
        return f"{path}: holds more than {MAX_RECORDS:,} records, the limit"
    return (f"{path}: holds more than {limit:,} records in {limit // MAX_RECORDS_PER_BYTE:,} bytes, more than "
            f"{MAX_RECORDS_PER_BYTE} a byte (a recording's take 20-40 bytes each): not a session's recording")


@dataclass
class _Skipped:
    """A chunk :func:`read_recording` could not read: why, its messages' time span (ns) and how many."""

    reason: str
    start_ns: int
    end_ns: int
    messages: int = 0


def _skipped_note(skipped: list[_Skipped], orphans: int) -> str:
    """One clause for the damage line: how many chunks were skipped, what they held, the first reason."""
    lost = sum(s.messages for s in skipped)
    span = f"{min(s.start_ns for s in skipped) * 1e-9:.3f}-{max(s.end_ns for s in skipped) * 1e-9:.3f} s"
    more = f", and {orphans} later messages on channels they declared" if orphans else ""
    return (f"{len(skipped)} damaged chunk{'s' if len(skipped) > 1 else ''} skipped ({lost} messages logged at "
            f"{span}{more}; {skipped[0].reason})")


def check_recording_file(path: Path) -> None:
    """Raise a :class:`RecordingError` naming what ``path`` is when it is not a regular file to read."""
    import stat

    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise RecordingError(f"{path}: no such recording") from None
    except OSError as exc:  # a loop of links, a name too long, a folder we may not enter
        raise RecordingError(f"{path}: cannot read the recording ({exc.strerror or exc})") from None
    if stat.S_ISDIR(mode):
        raise RecordingError(f"{path}: is a folder, not a recording")
    if not stat.S_ISREG(mode):  # a FIFO would block the read, /dev/zero never end it
        raise RecordingError(f"{path}: is not a regular file (a device, pipe or socket), not a recording")


def written_here(head: bytes) -> bool:
    """Whether a file's first bytes are an MCAP recording this program wrote: its magic, then a header record
    (opcode 1, a uint64 length) whose profile and library strings (uint32 length, then UTF-8) are
    :data:`PROFILE` and ``tactile-twin``. Another tool's MCAP (a ROS 2 bag) is a user's file."""
    at = len(MCAP_MAGIC) + 9
    if not head.startswith(MCAP_MAGIC) or head[len(MCAP_MAGIC):len(MCAP_MAGIC) + 1] != b"\x01":
        return False
    strings = []
    for _ in range(2):
        size = int.from_bytes(head[at:at + 4], "little")
        strings.append(head[at + 4:at + 4 + size])
        at += 4 + size
    return strings == [PROFILE.encode(), b"tactile-twin"]


def check_record_destination(path: Path, label: str | None = None) -> None:
    """Refuse a path a recording must not be renamed onto (:func:`sync.replacing.found_at`): a folder, a device,
    pipe or socket, or an existing file that is neither empty nor a recording this program wrote
    (:func:`written_here`; a user's own file, another tool's MCAP included, which the recording would replace).

    ``label`` starts the error (default: ``path``), e.g. ``"--record x.mcap"``.

    Raises:
        RecordingError: naming the path and why.
    """
    found = found_at(path, lambda head, _size: written_here(head))
    if not found.replaceable:
        why = {"unchecked": f"cannot check it ({found.error})", "folder": "is a folder, not a recording file",
               "special": "not a regular file",  # the rename would delete the FIFO or device node
               "unreadable": f"cannot read it ({found.error})",
               "other": "exists and is not a recording this program wrote; refusing to replace it"}[found.kind]
        raise RecordingError(f"{path if label is None else label}: {why}")


def _check_total(path: Path, total: int) -> None:
    if total > MAX_RECORDING_BYTES:
        raise RecordingError(f"{path}: holds more than {MAX_RECORDING_BYTES >> 20} MiB decompressed, the limit")


def _inflate(path: Path, chunk) -> bytes:  # type: ignore[no-untyped-def]
    """A chunk's records, decompressed, never past :data:`MAX_RECORD_BYTES` whatever its header claims.

    Raises:
        RecordingError: the chunk claims or decompresses to more than the limit.
        McapError: an unknown compression, damaged compressed data or a CRC mismatch (damage).
    """
    from mcap.exceptions import McapError

    too_big = RecordingError(f"{path}: a chunk decompresses to more than the {MAX_RECORD_BYTES >> 20} MiB "
                             "limit per record")
    if chunk.uncompressed_size > MAX_RECORD_BYTES:
        raise too_big
    if chunk.compression == "":
        data = chunk.data
    elif chunk.compression == "zstd":
        import io

        import zstandard

        try:
            with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(chunk.data)) as stream:
                parts, size = [], 0
                while piece := stream.read(1 << 20):
                    size += len(piece)
                    if size > MAX_RECORD_BYTES:
                        raise too_big
                    parts.append(piece)
        except zstandard.ZstdError as exc:  # not a ValueError in the C backend: it was a traceback
            raise McapError(f"a chunk's zstd data is damaged ({exc})") from None
        data = b"".join(parts)
    elif chunk.compression == "lz4":
        try:
            import lz4.frame
        except ImportError:
            raise McapError("lz4 compression, and the lz4 package is not installed") from None
        try:
            data = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=MAX_RECORD_BYTES + 1)
        except RuntimeError as exc:  # what lz4 raises on damaged frames
            raise McapError(f"a chunk's lz4 data is damaged ({exc})") from None
        if len(data) > MAX_RECORD_BYTES:
            raise too_big
    else:
        raise McapError(f"unknown chunk compression {chunk.compression!r}")
    if len(data) != chunk.uncompressed_size:
        raise McapError(f"a chunk decompressed to {len(data)} bytes, its header says {chunk.uncompressed_size}")
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise McapError("a chunk's CRC does not match its records")
    return data


def _chunk_records(data: bytes) -> Iterator[object]:
    """The channel and message records in a chunk's decompressed ``data`` (others skipped), one at a time: a
    chunk of 4 M empty messages read whole into a list took 900 MB before the record limit could refuse it."""
    from io import BytesIO

    from mcap.data_stream import ReadDataStream
    from mcap.opcode import Opcode
    from mcap.records import Channel, Message

    stream = ReadDataStream(BytesIO(data))
    while stream.count < len(data):
        opcode, length = stream.read1(), stream.read8()
        if opcode == Opcode.CHANNEL:
            yield Channel.read(stream)
        elif opcode == Opcode.MESSAGE:
            yield Message.read(stream, length)
        else:
            stream.read(length)


def _check_version(path: Path, metadata: dict[str, str]) -> None:
    raw = metadata.get("schema_version", "")
    try:
        version = int(raw)
    except ValueError:
        raise RecordingError(f"{path}: schema version {raw!r} is not a number") from None
    if version != SCHEMA_VERSION:
        raise RecordingError(f"{path}: recording schema version {version}; this tool reads version {SCHEMA_VERSION}")


def _next_sample(previous: float | None, now: float, every: float) -> float:
    """The next sample time on a fixed grid from the first one (a late sample does not shift the grid)."""
    if previous is None:
        return now + every
    return previous + every * max(1, math.floor((now + _TIME_SLACK - previous) / every) + 1)


def tool_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("tactile-twin")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "unknown"


def _xyz(v: np.ndarray) -> dict[str, float]:
    x, y, z = (float(a) for a in np.asarray(v, dtype=np.float64).ravel()[:3])
    return {"x": x, "y": y, "z": z}


def _foxglove_quat(q: np.ndarray) -> dict[str, float]:
    """MuJoCo's w x y z quaternion as Foxglove's named {x, y, z, w} (names, not positions, carry the order)."""
    w, x, y, z = (float(a) for a in np.asarray(q, dtype=np.float64).ravel())
    return {"x": x, "y": y, "z": z, "w": w}
