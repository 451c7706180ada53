"""``--record`` on the live commands and ``twin replay``: sessions to MCAP files and back.

Recording (:mod:`sync.recording`) wraps a side's transport so every wire message is logged with its send
and receive times, and gives the runtimes a recorder for the operator's targets and force and the remote's
ground truth. Replay re-runs a recording headless (:class:`scenes.headless.Headless`) on the simulated
clock: the scene and the remote's sensor from the recording's metadata, the operator's targets from the recording (zero-order
hold on the twin's time) unless a script replaces them, network conditions from the recording or the
command line. Same recording and seed, same poses, bit for bit.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cli.outputs import check_output_folder, claim_output_folder, write_output
from estimation.errors import TwinError, refused_number
from sync.clock import Clock
from sync.netem import Conditions, GilbertElliott, Network
from sync.recording import (
    MAX_REPLAY_SECONDS,
    Recorder,
    Recording,
    RecordingError,
    RecordingTransport,
    check_recording_file,
    read_recording,
)
from sync.transport import Transport
from twin.trajectory import HeldTargets, Waypoints

log = logging.getLogger(__name__)

#: The file that marks a folder as ``twin replay``'s own: only such a folder (or an empty one) is written into.
REPLAY_MARKER = ".twin-replay"

#: The command, as its marker and its refusals name it.
REPLAY_COMMAND = "twin replay"

#: What ``twin replay --out`` writes there.
REPLAY_WRITES = ("replay.mcap", "summary.json")

#: When two step times are the same time: step times are float sums (a microsecond is far below a step).
_SAME_TIME = 1e-6


def open_recorder(path: Path | None, *, clock: Clock, command: str, side: str,
                  scene_path: Path | None = None, scene_name: str = "", sensor: str | None = None) -> Recorder | None:
    """A recorder for a live command (None without ``path``), with the session metadata it can know.

    ``sensor``: the remote's (``--sensor``, :data:`scenes.headless.SENSORS`), which replay rebuilds; None leaves
    it out (``twin local`` does not know what the remote senses with)."""
    if path is None:
        return None
    from scenes.headless import scene_metadata
    from scenes.scenefile import load_scene

    meta: dict[str, object] = {"scene_name": scene_name, "scene_toml": "", "scene_dir": ""}
    if scene_path is not None:
        meta.update(scene_metadata(load_scene(scene_path)))
    meta.update({"command": command, "side": side, "seeds": {}, "network": None})
    if sensor is not None:
        meta["sensor"] = sensor
    return Recorder(path, clock=clock, metadata=meta)


def recording_transport(transport: Transport, recorder: Recorder | None, side: str) -> Transport:
    """``transport``, logged to ``recorder`` if there is one."""
    return transport if recorder is None else RecordingTransport(transport, recorder, side)


def recorded_targets(recording: Recording) -> HeldTargets:
    """The operator's recorded targets, decoded once (:meth:`sync.recording.Recording.targets`), as a trajectory
    of twin time: each held from the time it was applied, as recorded. Empty (``times`` of length 0, never a
    target) if the recording has none.

    Raises:
        RecordingError: a malformed target record.
    """
    times, points = recording.targets()
    return HeldTargets(times, points, source=str(recording.path))


def recorded_scene(recording: Recording):  # type: ignore[no-untyped-def]
    """The recording's scene, rebuilt from the scene file text in its metadata.

    Raises:
        RecordingError: the recording carries no scene (``twin local`` records none: pass ``--scene``).
        SceneError: the text is not a valid scene here (e.g. a mesh path missing on this machine).
    """
    from scenes.scenefile import SceneError, parse_scene, scene_document

    text = recording.metadata.get("scene_toml", "")
    if not text:
        raise RecordingError(f"{recording.path}: the recording carries no scene file; give one with --scene")
    try:
        doc = scene_document(text, f"{recording.path}: the recorded scene")
    except SceneError as exc:
        raise RecordingError(str(exc)) from None
    base, refused = scene_folder(recording)
    try:
        return parse_scene(doc, base=base)
    except (OverflowError, RecursionError) as exc:  # e.g. an integer too large for a float
        raise RecordingError(f"{recording.path}: the recorded scene is not a valid scene ({exc})") from None
    except SceneError as exc:  # said of the recording, not of a file the user gave
        hint = "" if refused is None else (f"; it was recorded in {refused}, which is not read unasked: give the "
                                           f"scene file with --scene")
        raise SceneError(f"{recording.path}: the recorded scene is not a valid scene ({exc}){hint}") from None


def scene_folder(recording: Recording) -> tuple[Path, str | None]:
    """The folder the recorded scene's mesh and cloud paths are read from, and the recorded folder if it
    was not taken (else None).

    The recorded ``scene_dir`` is taken only when it is the recording's own folder or this installation's
    scene data; otherwise the recording's folder is used. A recording is a file handed around: one whose
    metadata named any folder would make replay read the files it names there (``/home/you/designs``) and
    put what it built from them into its output.
    """
    own = recording.path.resolve().parent
    recorded = recording.metadata.get("scene_dir") or ""
    if not recorded:
        return own, None
    try:
        folder = Path(recorded).resolve()
    except (OSError, RuntimeError, ValueError):  # a NUL byte, a link loop: not a folder to read
        return own, recorded
    from scenes.scenefile import scene_data

    if folder in (own, scene_data()):
        return folder, None
    return own, recorded


def recorded_sensor(recording: Recording) -> str:
    """The remote's sensor the recording names (its ``sensor`` metadata, one of :data:`scenes.headless.SENSORS`);
    "surface" for one that names none (``twin local``'s, and every recording made before the sensor was
    recorded, all of which the surface sensor made), said in a log line.

    Raises:
        RecordingError: a sensor replay does not know (another program's, or a headless session's own class).
    """
    from scenes.headless import SENSORS

    name = recording.metadata.get("sensor")
    if name is None:
        log.warning("%s: the recording names no sensor (twin local records none, and recordings made before the "
                    "sensor was recorded were all of the surface sensor): replaying with the surface sensor; "
                    "--sensor cameras replays a camera session", recording.path)
        return "surface"
    if name not in SENSORS:
        shown = name if len(name) <= 24 else name[:24] + "..."
        raise RecordingError(f"{recording.path}: the recorded sensor {shown!r} is not one replay knows "
                             f"({', '.join(SENSORS)}); give one with --sensor")
    return name


def recorded_network(recording: Recording) -> Network | None:
    """The emulated network a headless recording ran with (None: none, or a live recording)."""
    raw = recording.metadata.get("network", "null")
    try:
        doc = json.loads(raw)
        if not doc:
            return None
        if not isinstance(doc, dict):
            raise TypeError(f"a JSON {type(doc).__name__}, not an object")
        unknown = sorted(set(doc) - {"uplink", "downlink", "seed"})
        if unknown:  # a misspelt side would replay with no network at all, and say nothing
            raise ValueError(f"unknown key {unknown[0][:40]!r}; known: uplink, downlink, seed")
        sides = {}
        for side in ("uplink", "downlink"):
            c = doc.get(side)
            if c is not None and c.get("burst") is not None:
                c = {**c, "burst": GilbertElliott(**c["burst"])}
            sides[side] = None if c is None else Conditions(**c)
        return Network(**sides, seed=doc.get("seed", 0))
    except (ValueError, TypeError, AttributeError, OverflowError, RecursionError) as exc:
        raise RecordingError(f"{recording.path}: unreadable network metadata ({exc})") from None


def network_from_options(*, delay_ms: float | None, jitter_ms: float | None, loss_pct: float | None,
                         seed: int) -> Network | None:
    """Both directions under the same conditions (None when no option is given)."""
    if delay_ms is None and jitter_ms is None and loss_pct is None:
        return None
    c = Conditions(delay=(delay_ms or 0.0) * 1e-3, jitter=(jitter_ms or 0.0) * 1e-3, loss=(loss_pct or 0.0) / 100)
    return Network(uplink=c, downlink=c, seed=seed)


@dataclass(frozen=True)
class ReplayResult:
    """What :func:`replay` returns: the summary (the ``--json`` record) and the final poses as arrays."""

    summary: dict
    twin_poses: dict[str, np.ndarray]  # id -> (7,) position m and quaternion w x y z, world frame
    remote_poses: dict[str, np.ndarray]


def replay(path: str | Path, *, script: Path | None = None, units: str = "m", scene: Path | None = None,
           network: Network | None = None, seed: int | None = None, duration: float | None = None,
           out: Path | None = None, cache_dir: Path | None = None, sensor: str | None = None,
           progress: Callable[[str, float, float], None] | None = None) -> ReplayResult:
    """Re-run a recorded session headless on the simulated clock.

    Args:
        path: the recording.
        script: a trajectory CSV to use instead of the recorded targets.
        units: the units of the script's positions (m, cm, mm).
        scene: a scene file to use instead of the recorded one.
        sensor: the remote's sensor (:data:`scenes.headless.SENSORS`) to use instead of the recorded one
            (:func:`recorded_sensor`: "surface" for a recording that names none).
        network: conditions to use; None: the recording's (headless recordings), else none.
        seed: the network's seed (default: the recording's, else 0).
        duration: twin seconds to run (default: as long as the recorded session).
        out: a folder for ``summary.json`` and ``replay.mcap`` (the replay recorded).
        cache_dir: the CoACD cache.
        progress: called as ``progress(stage, done, total)``: ``("building", 0, 0)`` before the scene is built,
            then ``("replaying", simulated seconds done, seconds to run)`` every simulated second and at the end.

    Returns:
        The summary and the final poses.

    Raises:
        RecordingError: a missing, corrupt or unknown-version recording, one without a scene, or one naming a
            sensor replay does not know (without ``sensor``).
        TwinError: a bad script, scene, sensor or network conditions; a script or recorded target outside the
            operator's reach of the scene's table (:func:`twin.trajectory.check_reach`).
    """
    from dataclasses import replace

    from scenes.headless import SENSORS, Headless, sensor_for
    from scenes.scenefile import load_scene
    from twin.model import OPERATOR_REACH, scene_reach_corners
    from twin.trajectory import load_trajectory

    recording = read_recording(path)
    if recording.damage:
        log.info("%s", recording.damage)  # the summary's "damage"; `twin replay` prints it once, as a warning
    spec = load_scene(scene) if scene is not None else recorded_scene(recording)
    if sensor is not None and sensor not in SENSORS:
        raise TwinError(f"sensor must be one of {', '.join(SENSORS)}, got {sensor!r}")
    sensor = recorded_sensor(recording) if sensor is None else sensor
    trajectory: Waypoints | HeldTargets | None
    if script is not None:
        recorded, trajectory = None, load_trajectory(script, units=units)
    else:
        recorded = recorded_targets(recording)  # decoded once: the trajectory, its reach, the duration, the summary
        trajectory = recorded if len(recorded.times) else None
    if trajectory is not None:
        # The box the twin drops live device targets outside of (Local.workspace, from the scene the remote announces).
        trajectory.check_reach(scene_reach_corners(spec.table, spec.end_effector, OPERATOR_REACH))
    if network is None:
        network = recorded_network(recording)
    if network is not None and seed is not None:
        network = replace(network, seed=seed)
    asked = duration is not None
    duration = _recorded_duration(recording, recorded) if duration is None else duration
    if duration > MAX_REPLAY_SECONDS:
        what = (f"--duration {refused_number(duration, MAX_REPLAY_SECONDS)} s is" if asked else
                f"{recording.path}: the recorded session runs {refused_number(duration, MAX_REPLAY_SECONDS, digits=7)} s,")
        raise RecordingError(f"{what} more than a replay runs (at most {MAX_REPLAY_SECONDS:g} s)")
    if not duration > 0:
        damage = f"; {recording.damage.removeprefix(f'{recording.path}: ')}" if recording.damage else ""
        raise RecordingError(f"{recording.path}: nothing to replay (the recorded session lasted {duration:g} s){damage}")
    truth = recording.truth()
    record = None
    if out is not None:
        check_replay_out(out, recording.path, script, scene)
        claim_output_folder(out, marker=REPLAY_MARKER, command=REPLAY_COMMAND)
        record = out / "replay.mcap"
    wall0 = time.perf_counter()
    if progress is not None:
        progress("building", 0.0, 0.0)
    meta: dict[str, object] = {"command": "replay", "replayed": str(recording.path)}
    if scene is None:  # the recorded scene has no file of its own: carry its text on (the output replays too)
        meta.update(scene_name=spec.name, scene_toml=recording.metadata.get("scene_toml", ""),
                    scene_dir=str(scene_folder(recording)[0]))
    with Headless(spec, network=network, cache_dir=cache_dir, record=record, sensor=sensor_for(sensor, spec),
                  record_metadata=meta) as session:
        built = time.perf_counter() - wall0
        gaps: dict[str, list[float]] = {i: [] for i in truth}
        last: dict[str, tuple[float, np.ndarray, np.ndarray]] = {}  # id -> (t, replayed, recorded) at the last sample
        checks = np.unique(np.concatenate([t for t, _, _ in truth.values()] or [np.zeros(0)]))
        k = 0
        run0 = time.perf_counter()
        ticks = round(duration / session.dt)
        report_every = max(1, round(1.0 / session.dt))
        for tick in range(ticks):
            session.tick(trajectory)
            if progress is not None and ((tick + 1) % report_every == 0 or tick + 1 == ticks):
                # In the summary's figure, the duration, not the whole steps that cover it (1.6649 s read
                # "1.67" as 1,665 steps and "1.66" in the summary).
                done = duration if tick + 1 == ticks else min((tick + 1) * session.dt, duration)
                progress("replaying", done, duration)
            t = session.remote.twin.time
            while k < len(checks) and checks[k] < t - _SAME_TIME:
                k += 1  # a sample time this replay stepped past (another scene, another step)
            if k < len(checks) and abs(checks[k] - t) <= _SAME_TIME:
                k += 1
                _truth_gaps(session, truth, t, gaps, last)
        run_s = time.perf_counter() - run0
        twin = {i: np.concatenate(p) for i, p in session.poses().items()}
        remote = {i: np.concatenate(session.remote.twin.pose(i)) for i in session.remote._objects}
        report = session.local.report
    summary = _summary(recording, spec, duration, built, run_s, twin, remote, last, gaps, report, network, script,
                       trajectory is not None, sensor)
    if out is not None:
        from cli.main import to_json

        text = to_json(summary) + "\n"
        write_output(out, "summary.json", lambda tmp: tmp.write_text(text), marker=REPLAY_MARKER)
    return ReplayResult(summary, twin, remote)


def _recorded_duration(recording: Recording, recorded: HeldTargets | None) -> float:
    """Twin seconds the recorded session ran: from its end record, else its last target, else its truth.
    ``recorded``: its targets as :func:`recorded_targets` decoded them (None: not decoded, a script replaced them)."""
    end = recording.end_time()
    if end is not None:
        return end
    times = recording.targets()[0] if recorded is None else recorded.times
    if len(times):
        return float(times[-1]) + 1e-3
    spans = [t[-1] - t[0] for t, _, _ in recording.truth().values() if len(t)]
    return float(max(spans, default=0.0))


def _truth_gaps(session, truth, t: float, gaps: dict[str, list[float]], last: dict) -> None:  # type: ignore[no-untyped-def]
    """|replayed remote - recorded truth| of each object recorded at the remote's time ``t``."""
    for object_id, (times, positions, _) in truth.items():
        i = int(np.searchsorted(times, t - _SAME_TIME))
        if i < len(times) and abs(times[i] - t) <= _SAME_TIME and session.remote.twin.has(object_id):
            here = session.remote.twin.pose(object_id)[0].copy()
            gaps[object_id].append(float(np.linalg.norm(here - positions[i])))
            last[object_id] = (t, here, positions[i])


def _summary(recording, spec, duration, built, run_s, twin, remote, last, gaps, report,  # type: ignore[no-untyped-def]
             network, script, operated: bool, sensor: str) -> dict:
    div = np.concatenate([np.asarray(g) for g in report.divergence.values()] or [np.zeros(0)]) * 1e3
    truth_gap = np.concatenate([np.asarray(g) for g in gaps.values()] or [np.zeros(0)]) * 1e3
    final_vs_truth = {  # at the last ground-truth sample this replay reached (the remote's time)
        object_id: {"time_s": t, "recorded_truth_m": recorded.tolist(), "replayed_m": replayed.tolist(),
                    "difference_mm": float(np.linalg.norm(replayed - recorded) * 1e3)}
        for object_id, (t, replayed, recorded) in sorted(last.items())}

    def stats(x: np.ndarray) -> dict:
        if len(x) == 0:
            return {"p50": None, "p99": None, "max": None}
        return {"p50": float(np.percentile(x, 50)), "p99": float(np.percentile(x, 99)), "max": float(x.max())}

    return {
        "recording": str(recording.path),
        "damage": recording.damage,
        "scene": spec.name,
        "sensor": sensor,
        "operator": "script" if script is not None else ("recorded" if operated else "none"),
        "network": None if network is None else {"uplink": _conditions(network.uplink),
                                                 "downlink": _conditions(network.downlink), "seed": network.seed},
        "duration_s": duration,
        "build_s": built,
        "run_s": run_s,
        "speed_x_realtime": duration / run_s if run_s > 0 else None,
        "objects": sorted(twin),
        "twin_final": {i: p.tolist() for i, p in sorted(twin.items())},
        "remote_final": {i: p.tolist() for i, p in sorted(remote.items())},
        "final_vs_recorded_truth": final_vs_truth,
        "remote_vs_recorded_truth_mm": stats(truth_gap),
        "twin_vs_remote_mm": stats(div),
        "pose_updates": report.pose_updates,
        "snaps": report.snaps,
        "holds": report.holds,
        "warned_objects": report.warned_objects,  # added from an estimate that warns (each logged as it went in)
    }


def _conditions(c: Conditions | None) -> dict | None:
    if c is None:
        return None
    return {"delay_ms": c.delay * 1e3, "jitter_ms": c.jitter * 1e3, "loss_pct": c.loss * 100,
            "distribution": c.distribution}


def print_summary(summary: dict) -> None:
    """The human-readable form of a replay summary."""
    lines = [f"replayed {summary['recording']} ({summary['scene']}, {summary['sensor']} sensor, operator "
             f"{summary['operator']}): "
             f"{summary['duration_s']:.2f} s simulated in {summary['run_s']:.2f} s "
             f"({summary['speed_x_realtime']:.1f}x real time; build {summary['build_s']:.1f} s)",
             f"objects {', '.join(summary['objects'])}; pose updates {summary['pose_updates']}, "
             f"snaps {summary['snaps']}, holds {summary['holds']}"]
    d = summary["twin_vs_remote_mm"]
    if d["max"] is not None:
        lines.append(f"twin - remote: p50 {d['p50']:.2f} mm, p99 {d['p99']:.2f} mm, max {d['max']:.2f} mm")
    g = summary["remote_vs_recorded_truth_mm"]
    if g["max"] is not None:
        lines.append(f"replayed remote - recorded truth: p50 {g['p50']:.3f} mm, p99 {g['p99']:.3f} mm, "
                     f"max {g['max']:.3f} mm")
    for object_id, f in summary["final_vs_recorded_truth"].items():
        lines.append(f"  {object_id}: final {f['difference_mm']:.3f} mm from the recorded truth")
    print("\n".join(lines))


def check_replay_inputs(path: Path) -> None:
    """Refuse a missing file, a folder or a device before any work (the full read happens in :func:`replay`)."""
    check_recording_file(path)


def check_replay_out(out: Path, recording: Path, script: Path | None = None, scene: Path | None = None) -> None:
    """Refuse an ``--out`` folder replay must not write into: a user's own (not empty and without
    :data:`REPLAY_MARKER`), or one whose ``replay.mcap`` or ``summary.json`` is an input.

    Raises:
        TwinError: naming the folder and why.
    """
    check_output_folder(out, marker=REPLAY_MARKER, command=REPLAY_COMMAND, writes=REPLAY_WRITES,
                        inputs=(recording, script, scene))
