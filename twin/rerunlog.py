"""Visual debugging in rerun: the one module that imports rerun and knows its entity paths.

The twin's loops take a :class:`twin.debuglog.DebugLog` and never import this module: commands pass a
:class:`RerunLog` in when asked for rerun, :data:`twin.debuglog.OFF` otherwise. When on, a call only copies the arrays it needs into a queue; a
child process builds rerun's archetypes and sends them, so the 1 kHz loop pays a queue put, not rerun's
serialisation under its own GIL. Per-frame state (poses, divergence, force) is logged at ``rate_hz`` of
simulated time (:meth:`RerunLog.due`) and sent as columns every BATCH_SECONDS; events and objects are
logged when they happen.

Entity tree (``<side>`` is ``twin`` for C', ``remote`` for C, ``estimate`` for ``twin estimate``)::

    world/table                    Boxes3D (static)
    world/<side>/<id>              Transform3D: the body pose (origin at the centre of mass), per frame
    world/<side>/<id>/cloud        Points3D, body frame: the input cloud (at most DISPLAY_POINTS; count in label)
    world/<side>/<id>/normals      Arrows3D, body frame: the normals the surface was built from (a subset)
    world/<side>/<id>/mesh         Mesh3D, body frame: the reconstructed (decimated) surface
    world/<side>/<id>/obb          Boxes3D, body frame: the points' oriented bounding box, as an outline
    world/<side>/<id>/hulls/<k>    Mesh3D, body frame: CoACD's convex parts, one colour each
    world/<side>/<id>/com          Points3D: centre of mass, labelled "<id> <mass> kg", shown on hover
    world/<side>/<id>/properties   TextDocument: the estimate in full
    world/end_effector             Points3D: the operator's sphere; .../force Arrows3D (N drawn at FORCE_SCALE)
    plots/divergence/<id>          Scalars: |twin - remote| of the centre of mass, mm
    plots/ee_force                 Scalars: end-effector contact force, N; SeriesLines (static) names them x, y, z
    events                         TextLog: clouds received, objects added/removed, corrections, stale link,
                                   dropped messages

Timelines: ``sim_time`` (simulated seconds) and ``wall_time`` (Unix time).

Each command picks the default layout (:data:`LAYOUTS`) whose panels it fills: ``twin estimate`` the 3D view
and the properties; ``twin build`` the 3D view; ``twin run`` adds the force; ``twin remote`` the force and
events; ``twin local`` and ``twin demo`` the divergence as well.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import queue
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimation import PhysicalEstimate
from estimation.errors import TwinError
from sync.replacing import found_at
from twin.debuglog import display_subset
from twin.model import COLLISION_GROUP, VISUAL_GROUP, hull_colour
from twin.poses import rotation, to_xyzw

log = logging.getLogger(__name__)

APP_ID = "tactile-twin"

#: Normals drawn per object (every k-th of the points used): more is a hedgehog.
DISPLAY_NORMALS = 400

#: Arrow length per newton of end-effector force, metres.
FORCE_SCALE = 0.01

#: Default frame rate of per-frame state, Hz of simulated time: smooth to the eye, ~3 % of a 1 kHz loop.
DEFAULT_RATE_HZ = 30.0

#: Per-frame rows are sent in batches this often (wall seconds): what a live viewer lags by, at most.
BATCH_SECONDS = 0.5

#: How long close() waits for the writer process to finish the recording, seconds.
WRITER_CLOSE_S = 120.0

#: The default viewer address for ``connect`` (rerun's own default gRPC proxy).
DEFAULT_CONNECT = "rerun+http://127.0.0.1:9876/proxy"

#: Tolerance on simulated time when deciding a frame is due, seconds (a nanosecond: far below a step).
_TIME_SLACK = 1e-9

_CLOUD_RGB = (60, 170, 90)
_EE_RGB, _FORCE_RGB = (50, 200, 50), (220, 40, 40)
_MESH_RGBA = {"twin": (110, 140, 200, 255), "remote": (240, 150, 40, 90), "estimate": (110, 140, 200, 255)}


@dataclass(frozen=True)
class RerunTarget:
    """Where a recording goes: ``spawn`` a viewer, ``save`` to an .rrd file, or ``connect`` to a viewer.

    Attributes:
        mode: 'spawn', 'save' or 'connect'.
        address: the file (save) or the viewer URL (connect); None for spawn.
        rate_hz: per-frame logging rate, Hz of simulated time.
    """

    mode: str
    address: str | None = None
    rate_hz: float = DEFAULT_RATE_HZ


#: How a rerun recording file starts (its stream header: "RRF" and a format version digit). A non-empty existing
#: file ``--rerun save`` may replace (:func:`sync.replacing.found_at`) has it and names :data:`APP_ID` in its
#: first bytes (the store info rerun writes first): another application's recording is a user's file.
RRD_MAGIC = b"RRF"


def _written_here(head: bytes) -> bool:
    return head.startswith(RRD_MAGIC) and APP_ID.encode() in head


def parse_target(words: list[str], rate_hz: float = DEFAULT_RATE_HZ) -> RerunTarget:
    """``['spawn']``, ``['save', 'FILE.rrd']`` or ``['connect']`` / ``['connect', 'HOST:PORT' or URL]``.

    Raises:
        TwinError: anything else, a save path that is not a writable .rrd, a connect address
            :func:`connect_url` refuses, or a non-positive rate.
    """
    if not rate_hz > 0:
        raise TwinError(f"--rerun-rate must be > 0 Hz, got {rate_hz}")
    mode, rest = (words[0], words[1:]) if words else ("", [])
    if mode == "spawn" and not rest:
        return RerunTarget("spawn", None, rate_hz)
    if mode == "save" and len(rest) == 1:
        path = Path(rest[0])
        if path.suffix != ".rrd":  # ".rrd" alone is a hidden file's name with no suffix: it said ".rrd should end in .rrd"
            raise TwinError(f"--rerun save: {path} should be a file name ending in .rrd (e.g. view.rrd)")
        if not path.parent.resolve().is_dir():
            raise TwinError(f"--rerun save: directory {path.parent} does not exist")
        found = found_at(path, lambda head, _size: _written_here(head))
        if found.kind == "unchecked":
            raise TwinError(f"--rerun save: {path}: cannot check it ({found.error})")
        if not found.replaceable:
            raise TwinError(f"--rerun save: {path} exists and is not a rerun recording this program wrote; "
                            f"refusing to replace it")
        return RerunTarget("save", str(path), rate_hz)
    if mode == "connect" and len(rest) <= 1:
        return RerunTarget("connect", connect_url(rest[0]) if rest else DEFAULT_CONNECT, rate_hz)
    raise TwinError(f"--rerun expects 'spawn', 'save FILE.rrd' or 'connect [HOST:PORT]', got {' '.join(words)!r}")


#: The URL schemes rerun's gRPC client takes (``rerun://`` is ``rerun+https://``), and the one path a viewer's
#: proxy has. rerun itself refuses anything else, but in the writer process, where the refusal was a warning
#: at the end of a run that had exited 0.
CONNECT_SCHEMES, CONNECT_PATH = ("rerun+http", "rerun+https", "rerun"), "/proxy"


def connect_url(address: str) -> str:
    """The viewer URL for ``--rerun connect ADDRESS``: ``HOST:PORT`` (``[::1]:PORT`` for IPv6) becomes
    ``rerun+http://HOST:PORT/proxy``; a URL must be ``SCHEME://HOST[:PORT]/proxy``. Only the form is checked
    here; :meth:`RerunLog.open` checks that the host resolves.

    Raises:
        TwinError: naming the address and what is wrong with it.
    """
    from urllib.parse import urlsplit

    said = f"--rerun connect {address!r}"
    form = f"expected HOST:PORT such as 127.0.0.1:9876, or a URL such as {DEFAULT_CONNECT}"
    url = address if "://" in address else f"rerun+http://{address}{CONNECT_PATH}"
    try:
        parts = urlsplit(url)
    except ValueError:  # an unclosed IPv6 bracket
        raise TwinError(f"{said}: not a host and port ({form})") from None
    try:
        port = parts.port  # urllib reads the port only when asked for it
    except ValueError:  # not a number, or past 65535
        port = -1
    schemes = [f"{s}://" for s in CONNECT_SCHEMES]
    if parts.scheme not in CONNECT_SCHEMES:
        raise TwinError(f"{said}: the scheme must be {', '.join(schemes[:-1])} or {schemes[-1]} ({form})")
    if not parts.hostname or any(c.isspace() for c in parts.netloc):
        raise TwinError(f"{said}: no valid host ({form})")
    if port == -1 or port == 0 or ("://" not in address and port is None):  # else rerun tries port 80
        raise TwinError(f"{said}: no valid port, 1 to 65535 ({form})")
    if parts.path != CONNECT_PATH:
        got = repr(parts.path) if parts.path else "none"
        raise TwinError(f"{said}: the path must be {CONNECT_PATH}, got {got} ({form})")
    return url


def _check_resolves(url: str) -> None:
    """Refuse a viewer URL whose host does not resolve: rerun would retry it in the writer process for the whole
    run, log Rust errors, and the command still exit 0. A host that resolves but where no viewer listens stays
    a warning at the end (the viewer may start later)."""
    import socket
    from urllib.parse import urlsplit

    host = urlsplit(url).hostname or ""
    try:
        socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)
    except (OSError, UnicodeError) as exc:  # socket.gaierror; an IDNA-invalid name raises UnicodeError
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise TwinError(f"--rerun connect: host {host!r} does not resolve ({reason})") from None


#: The layout each command asks for: which panels it fills. A panel nothing is logged to is left out.
LAYOUTS = {
    "estimate": "one estimate (twin estimate): the 3D view and its properties",
    "scene": "a built scene (twin build): the 3D view",
    "twin": "a twin on its own (twin run): the 3D view and the end-effector force",
    "remote": "the remote C (twin remote): the 3D view, the end-effector force and the events",
    "sync": "a twin following a remote (twin local, twin demo): all of the above and the divergence",
}


def blueprint(layout: str = "sync"):  # type: ignore[no-untyped-def]
    """The default layout for ``layout`` (a key of :data:`LAYOUTS`): the 3D scene on the left, plots on the right.

    Raises:
        TwinError: an unknown layout.
    """
    import rerun.blueprint as rrb

    if layout not in LAYOUTS:
        raise TwinError(f"unknown rerun layout {layout!r}; expected one of {', '.join(LAYOUTS)}")
    # The 3D view's title is its legend: it names only the sides this recording has.
    scene = {"estimate": "estimate: cloud (green), mesh (blue), OBB (yellow outline)",
             "remote": "remote C (orange)", "sync": "remote C (orange) and twin C' (blue)"}.get(layout, "twin C' (blue)")
    view = rrb.Spatial3DView(origin="/world", name=scene)
    force = rrb.TimeSeriesView(origin="/plots/ee_force", name="end-effector force, N")
    events = rrb.TextLogView(origin="/events", name="sync events")
    if layout == "estimate":
        side = [rrb.TextDocumentView(origin="/world/estimate", name="properties")]
    elif layout == "scene":
        side = []
    elif layout == "twin":
        side = [force]
    elif layout == "remote":
        side = [force, events]
    else:
        side = [rrb.TimeSeriesView(origin="/plots/divergence", name="divergence |C' - C|, mm"), force, events]
    root = view if not side else rrb.Horizontal(view, rrb.Vertical(*side), column_shares=[3, 2])
    return rrb.Blueprint(
        root,
        rrb.TimePanel(timeline="sim_time", play_state="following"),  # opens at the latest state
        collapse_panels=True,
    )


class RerunLog:
    """A rerun recording written by a child process. ``RerunLog()`` logs nothing.

    The loop's process only copies what is to be shown into a queue; building rerun's archetypes and
    rerun's own encoding run in the child, so they do not hold this process's GIL while the loop waits
    for it. Use as a context manager or call :meth:`close`, which waits until everything queued is written.
    """

    def __init__(self, target: RerunTarget | None = None, *, layout: str = "sync", recording_id: str | None = None,
                 queue_size: int = 4096) -> None:
        if layout not in LAYOUTS:
            raise TwinError(f"unknown rerun layout {layout!r}; expected one of {', '.join(LAYOUTS)}")
        self.period = 1.0 / (target.rate_hz if target is not None else DEFAULT_RATE_HZ)
        self.dropped = 0  # items not logged because the queue was full
        self.logged = 0  # items the writer logged (known after close)
        self._next_frame = -np.inf
        self._proc = None
        if target is not None:
            ctx = mp.get_context("spawn")
            self._queue = ctx.Queue(queue_size)
            self._result = ctx.Queue(1)
            self._proc = ctx.Process(target=_writer_main, args=(target, layout, recording_id, self._queue, self._result),
                                     name="rerun-log", daemon=True)
            self._proc.start()

    @classmethod
    def open(cls, target: RerunTarget | None, *, layout: str = "sync", recording_id: str | None = None) -> RerunLog:
        """A log to ``target`` (None: off), shown in the viewer with the default ``layout`` (see :data:`LAYOUTS`).

        Raises:
            TwinError: ``spawn`` without a display, ``connect`` to a host that does not resolve, or an unknown
                layout.
        """
        if target is not None and target.mode == "spawn":
            _check_display()
        if target is not None and target.mode == "connect" and target.address is not None:
            _check_resolves(target.address)
        return cls(target, layout=layout, recording_id=recording_id)

    @property
    def enabled(self) -> bool:
        return self._proc is not None

    def __enter__(self) -> RerunLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Write what is queued, flush and disconnect. Idempotent; never raises for the writer's sake."""
        if self._proc is None:
            return
        proc, self._proc = self._proc, None
        try:
            self._queue.put(None, timeout=5)
        except queue.Full:
            pass
        outcome = None
        deadline = time.monotonic() + WRITER_CLOSE_S
        while outcome is None and time.monotonic() < deadline:
            try:
                outcome = self._result.get(timeout=0.2)
            except queue.Empty:
                if not proc.is_alive():
                    break
        if isinstance(outcome, int):
            self.logged = outcome
        else:
            log.warning("rerun: %s", outcome or f"the writer process ended without finishing the recording "
                                                f"(exit code {proc.exitcode})")
            self._queue.cancel_join_thread()  # nobody will read what is left
        proc.join(timeout=10)
        if proc.is_alive():
            proc.terminate()
        if self.dropped:
            log.warning("rerun: %d items dropped (the writer fell behind)", self.dropped)

    # -- what callers log ----------------------------------------------------------------------------

    def due(self, sim_time: float) -> bool:
        """True at most ``rate_hz`` times per simulated second: the caller then logs a :meth:`frame`."""
        # Simulated time is a sum of float steps: 0.051 may come out as 0.0509999.
        if self._proc is None or sim_time < self._next_frame - _TIME_SLACK:
            return False
        following = self._next_frame + self.period
        self._next_frame = following if following > sim_time else sim_time + self.period
        return True

    def frame(self, twin, *, side: str = "twin",  # type: ignore[no-untyped-def]
              remote: dict[str, tuple[np.ndarray, np.ndarray] | None] | None = None) -> None:
        """Every object's pose in ``twin`` (a :class:`twin.sim.Twin`), the end effector and its force.

        ``remote`` maps ids to where the remote (C) last said the object is (position, quaternion w x y z,
        already mapped onto the twin's body): logged under world/remote with the divergence.
        """
        if self._proc is None:
            return
        poses = {i: twin.pose(i) for i in twin.object_ids()}
        ee = force = None
        if twin.has_end_effector:
            ee, force = twin.data.mocap_pos[0].copy(), twin.end_effector_force()
        others = None if remote is None else {i: p for i, p in remote.items() if p is not None}
        self._put(twin.time, "frame", side, poses, others, ee, force)

    def estimate(self, name: str, est: PhysicalEstimate, cloud: np.ndarray | None = None) -> None:
        """One estimate in its cloud's frame (``twin estimate``): cloud, normals, mesh, OBB, properties."""
        if self._proc is None:
            return
        self._put(0.0, "geometry", f"world/estimate/{name}", "estimate", _slim(est), np.zeros(3),
                  (est.vertices, est.faces), (), _display(cloud, est))

    def object(self, side: str, obj, *, sim_time: float = 0.0, cloud: np.ndarray | None = None,  # type: ignore[no-untyped-def]
               pose: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """One :class:`twin.objects.TwinObject`: its geometry in its body frame, and its pose.

        Args:
            side: 'twin' or 'remote'.
            cloud: (n, 3) metres in the estimate's frame (the frame of ``obj.estimate.vertices``); default:
                the points the estimate was built from.
            pose: (position, quaternion w x y z) to show it at; default ``obj.position`` and ``obj.quat``.
        """
        if self._proc is None:
            return
        path = f"world/{side}/{obj.id}"
        pos, quat = pose if pose is not None else (obj.position, obj.quat)
        est = obj.estimate
        self._put(sim_time, "geometry", path, side, _slim(est), est.mass.center_of_mass, obj.visual, obj.hulls,
                  _display(cloud, est))
        self._put(sim_time, "pose", path, np.array(pos, dtype=float), np.array(quat, dtype=float))

    def model_geometry(self, twin, *, side: str = "twin") -> None:  # type: ignore[no-untyped-def]
        """Each object's visual mesh and hulls as compiled in ``twin``'s model, and the table.

        For a twin loaded from XML (``twin build`` output), where no estimate is at hand: no cloud,
        normals, OBB or properties.
        """
        if self._proc is None:
            return
        import mujoco

        m = twin.model
        table = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "table")
        if table >= 0:
            half = m.geom_size[table]
            self.table(tuple(2 * half), float(m.geom_pos[table][2] + half[2]))
        for object_id in twin.object_ids():
            body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, object_id)
            path, hulls = f"world/{side}/{object_id}", 0
            for g in range(m.body_geomadr[body], m.body_geomadr[body] + m.body_geomnum[body]):
                if m.geom_type[g] != mujoco.mjtGeom.mjGEOM_MESH:
                    continue
                mesh = m.geom_dataid[g]
                v = m.mesh_vert[m.mesh_vertadr[mesh]:m.mesh_vertadr[mesh] + m.mesh_vertnum[mesh]]
                f = m.mesh_face[m.mesh_faceadr[mesh]:m.mesh_faceadr[mesh] + m.mesh_facenum[mesh]]
                # MuJoCo re-centres each mesh on its own frame; the geom's pose puts it back in the body's.
                v = v @ rotation(m.geom_quat[g]).T + m.geom_pos[g]
                if m.geom_group[g] == VISUAL_GROUP:
                    self._put(twin.time, "mesh", f"{path}/mesh", (v, f.copy()), _MESH_RGBA[side])
                elif m.geom_group[g] == COLLISION_GROUP:
                    self._put(twin.time, "mesh", f"{path}/hulls/{hulls}", (v, f.copy()), _hull_rgba(hulls))
                    hulls += 1
            self._put(twin.time, "pose", path, *twin.pose(object_id))

    def ghost(self, obj, *, sim_time: float = 0.0) -> None:  # type: ignore[no-untyped-def]
        """The twin's picture of where C has the object: its own mesh, translucent, under world/remote."""
        if self._proc is None:
            return
        self._put(sim_time, "mesh", f"world/remote/{obj.id}/mesh", obj.visual, _MESH_RGBA["remote"])

    def removed(self, side: str, object_id: str, sim_time: float) -> None:
        if self._proc is None:
            return
        self._put(sim_time, "clear", f"world/{side}/{object_id}")

    def table(self, size: tuple[float, float, float], height: float) -> None:
        """The support: a box of full ``size`` (m) whose top is at ``height`` (m)."""
        if self._proc is None:
            return
        self._put(0.0, "table", np.asarray(size, float), float(height))

    def event(self, sim_time: float, text: str, level: str = "INFO") -> None:
        """A sync event for the log view; ``level`` is rerun's (TRACE, DEBUG, INFO, WARN, ERROR)."""
        if self._proc is None:
            return
        self._put(sim_time, "text", text, level)

    def _put(self, sim_time: float, what: str, *args: object) -> None:
        try:
            self._queue.put_nowait((sim_time, time.time(), what, args))
        except queue.Full:
            self.dropped += 1


def _writer_main(target: RerunTarget, layout: str, recording_id: str | None, items, result) -> None:  # type: ignore[no-untyped-def]
    """The child process: open the recording, log every queued item, report how many (or what failed)."""
    import os
    import signal
    import sys

    import rerun as rr

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle; it then closes us
    try:
        stream = rr.RecordingStream(APP_ID, recording_id=recording_id)
        if target.mode == "spawn":
            # rerun looks for its viewer on PATH; ours is beside this interpreter, which may not be on it.
            os.environ["PATH"] = os.path.dirname(sys.executable) + os.pathsep + os.environ.get("PATH", "")
            stream.spawn(default_blueprint=blueprint(layout))
        elif target.mode == "save":
            stream.save(target.address, default_blueprint=blueprint(layout))
        else:
            stream.connect_grpc(target.address, default_blueprint=blueprint(layout))
    except Exception as exc:  # reported to the parent, which warns and goes on without rerun
        result.put(f"could not open the recording ({target.mode}): {exc}".splitlines()[0])
        return
    writer = _Writer(stream)
    while (item := items.get()) is not None:
        writer.log(*item)
    try:
        writer.send_rows()
        stream.flush()
        stream.disconnect()
    except Exception as exc:  # e.g. nobody listening at a connect address
        result.put(f"could not deliver the recording ({target.mode} {target.address or ''}): {exc}".splitlines()[0])
        return
    result.put(writer.logged)


class _Writer:
    """Turns queued items into rerun calls (in the writer process)."""

    def __init__(self, stream) -> None:  # type: ignore[no-untyped-def]
        self.stream = stream
        self.logged = 0
        self._now = (0.0, 0.0)  # (sim, wall) of the item being logged
        self._rows: dict[tuple[str, str], list] = {}
        self._batch_start = 0.0
        self._force_named = False

    def log(self, sim_time: float, wall: float, what: str, args: tuple) -> None:
        self._now = (sim_time, wall)
        self.stream.set_time("sim_time", duration=sim_time)
        self.stream.set_time("wall_time", timestamp=wall)
        try:
            getattr(self, f"_{what}")(*args)
            self.logged += 1
        except Exception:  # one bad item must not end the recording
            log.exception("rerun: could not log %s", what)

    def _pose(self, path: str, pos: np.ndarray, quat: np.ndarray) -> None:
        """One pose now (an object appearing); per-frame poses go through :meth:`_row`."""
        import rerun as rr

        self.stream.log(path, rr.Transform3D(translation=pos, quaternion=rr.Quaternion(xyzw=to_xyzw(quat))))

    def _frame(self, side: str, poses: dict, remote: dict | None, ee: np.ndarray | None,
               force: np.ndarray | None) -> None:
        # Frames are gathered into columns and sent every BATCH_SECONDS: one send per entity per batch
        # instead of one log call per entity per frame (rerun's per-call overhead dominated the latter).
        for object_id, (pos, quat) in poses.items():
            self._row("pose", f"world/{side}/{object_id}", np.concatenate([pos, to_xyzw(quat)]))
        for object_id, (pos, quat) in (remote or {}).items():
            self._row("pose", f"world/remote/{object_id}", np.concatenate([pos, to_xyzw(quat)]))
            if object_id in poses:
                gap = 1e3 * float(np.linalg.norm(poses[object_id][0] - pos))
                self._row("scalars", f"plots/divergence/{object_id}", np.array([gap]))
        if ee is not None and force is not None:
            self._row("point", "world/end_effector", ee)
            self._row("arrow", "world/end_effector/force", np.concatenate([ee, force * FORCE_SCALE]))
            self._row("scalars", "plots/ee_force", force)
            if not self._force_named:  # the three series are x, y, z in the legend, not ee_force[0..2]
                self.stream.log("plots/ee_force", _force_series(), static=True)
                self._force_named = True
        if self._now[1] - self._batch_start >= BATCH_SECONDS:
            self.send_rows()

    def _row(self, kind: str, path: str, values: np.ndarray) -> None:
        self._rows.setdefault((kind, path), []).append((*self._now, values))

    def send_rows(self) -> None:
        import rerun as rr

        for (kind, path), rows in self._rows.items():
            sim = np.array([r[0] for r in rows])
            wall = np.array([r[1] for r in rows])
            v = np.array([r[2] for r in rows])
            n = len(rows)
            if kind == "pose":
                columns = rr.Transform3D.columns(translation=v[:, :3], quaternion=v[:, 3:])
            elif kind == "scalars":
                columns = rr.Scalars.columns(scalars=v.ravel()).partition(np.full(n, v.shape[1]))
            elif kind == "point":
                columns = rr.Points3D.columns(positions=v, radii=np.full(n, 0.005),
                                              colors=np.tile(np.array(_EE_RGB, np.uint8), (n, 1)))
            else:
                columns = rr.Arrows3D.columns(origins=v[:, :3], vectors=v[:, 3:],
                                              colors=np.tile(np.array(_FORCE_RGB, np.uint8), (n, 1)))
            rr.send_columns(path, indexes=[rr.TimeColumn("sim_time", duration=sim),
                                           rr.TimeColumn("wall_time", timestamp=wall)],
                            columns=columns, recording=self.stream)
        self._rows.clear()
        self._batch_start = self._now[1]

    def _geometry(self, path: str, side: str, est: PhysicalEstimate, com: np.ndarray,
                  mesh: tuple[np.ndarray, np.ndarray], hulls, cloud: np.ndarray | None) -> None:  # type: ignore[no-untyped-def]
        import rerun as rr

        s = self.stream
        self._mesh(f"{path}/mesh", mesh, _MESH_RGBA[side])
        if hulls:
            s.log(f"{path}/hulls", rr.Clear(recursive=True))  # a replaced object may have had more parts
        for k, (v, f) in enumerate(hulls):
            s.log(f"{path}/hulls/{k}", rr.Mesh3D(vertex_positions=v, triangle_indices=f, albedo_factor=_hull_rgba(k)))
        box = est.obb
        s.log(f"{path}/obb", rr.Boxes3D(centers=[box.center - com], half_sizes=[box.extents / 2],
                                        quaternions=[rr.Quaternion(xyzw=_matrix_xyzw(box.rotation))],
                                        colors=[(230, 200, 40)], radii=0.0008, fill_mode="majorwireframe"))
        # One short label per object, on its centre of mass, shown on hover only: drawn always, the labels
        # of neighbouring objects overlap (8 objects on a table did). The whole estimate is in .../properties.
        m = est.mass
        label = f"{_leaf(path)} {m.mass:.3g} kg" if m.mass < 100 else f"{_leaf(path)} {m.mass:,.0f} kg"
        s.log(f"{path}/com", rr.Points3D([np.zeros(3)], radii=0.003, colors=[(255, 255, 255)], labels=[label],
                                         show_labels=False))
        s.log(f"{path}/properties", rr.TextDocument(_properties(est, len(hulls)), media_type="text/markdown"))
        if cloud is not None:
            n = est.points_in or len(cloud)
            s.log(f"{path}/cloud", rr.Points3D(cloud - com, radii=0.0008, colors=[_CLOUD_RGB],
                                               labels=[f"{n:,} points" + (f" ({len(cloud):,} shown)" if n > len(cloud) else "")],
                                               show_labels=False))
        if est.points is not None and est.normals is not None:  # already thinned to DISPLAY_NORMALS
            length = 0.03 * float(est.obb.extents.max())
            s.log(f"{path}/normals", rr.Arrows3D(origins=est.points - com, vectors=est.normals * length,
                                                 colors=[(80, 120, 255)], radii=0.0003))

    def _mesh(self, path: str, mesh: tuple[np.ndarray, np.ndarray], rgba: tuple[int, ...]) -> None:
        import rerun as rr

        self.stream.log(path, rr.Mesh3D(vertex_positions=mesh[0], triangle_indices=mesh[1], albedo_factor=rgba))

    def _clear(self, path: str) -> None:
        import rerun as rr

        self.stream.log(path, rr.Clear(recursive=True))

    def _table(self, size: np.ndarray, height: float) -> None:
        import rerun as rr

        self.stream.log("world/table", rr.Boxes3D(centers=[[0, 0, height - size[2] / 2]], half_sizes=[size / 2],
                                                  colors=[(140, 100, 75)], fill_mode="solid"), static=True)

    def _text(self, text: str, level: str) -> None:
        import rerun as rr

        self.stream.log("events", rr.TextLog(text, level=level))


def _force_series():  # type: ignore[no-untyped-def]
    import rerun as rr

    return rr.SeriesLines(names=["x", "y", "z"], colors=[(220, 60, 60), (60, 170, 60), (70, 110, 230)])


def _hull_rgba(k: int) -> tuple[int, int, int, int]:
    """Hull k in the model's own palette (as MuJoCo's viewer shows it), a little more opaque."""
    r, g, b, _ = hull_colour(k)
    return round(255 * r), round(255 * g), round(255 * b), 170


def _leaf(path: str) -> str:
    return path.rsplit("/", 1)[-1]


def _display(cloud: np.ndarray | None, est: PhysicalEstimate) -> np.ndarray | None:
    """What to show as the cloud: the input's display subset, else the points the surface was built from."""
    if cloud is not None:
        return display_subset(cloud)
    return None if est.points is None else display_subset(est.points)


def _slim(est: PhysicalEstimate) -> PhysicalEstimate:
    """The estimate without what the writer does not draw (the full mesh, all points): less to pickle."""
    from dataclasses import replace

    k = 1 if est.points is None else max(1, len(est.points) // DISPLAY_NORMALS)
    return replace(est, vertices=np.empty((0, 3)), faces=np.empty((0, 3), np.int64),
                   points=None if est.points is None else est.points[::k],
                   normals=None if est.normals is None else est.normals[::k])


def _matrix_xyzw(rotation: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(rotation).as_quat()  # scipy's order is x y z w, rerun's too


def _properties(est: PhysicalEstimate, hulls: int) -> str:
    m = est.mass
    com = ", ".join(f"{x:.4f}" for x in m.center_of_mass)
    moments = ", ".join(f"{x:.4g}" for x in m.principal_moments)
    rows = [("method", est.method), ("mass", f"{m.mass:.4g} kg"), ("volume", f"{m.volume * 1e6:.4g} cm³"),
            ("density", f"{m.density:g} kg/m³" + (f" ({est.material})" if est.material else "")),
            ("centre of mass (estimate frame)", f"[{com}] m"), ("principal moments", f"{moments} kg m²"),
            ("points", f"{est.points_in:,} in, {est.points_used:,} used"), ("watertight", str(est.watertight)),
            ("collision hulls", str(hulls))]
    return "\n".join(["| | |", "|---|---|", *(f"| {k} | {v} |" for k, v in rows)])


def _check_display() -> None:
    import os
    import sys

    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise TwinError("--rerun spawn needs a display (DISPLAY is not set); use --rerun save FILE.rrd "
                        "and open it later with 'rerun FILE.rrd'")
