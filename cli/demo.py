"""``twin demo``: the remote scene and the local twin on this machine, synchronised over Zenoh.

The remote (C) runs in its own process: the ground truth of scenes/data/paper_table.toml, listening on
a free loopback port in peer mode. The local twin (C') connects, joins late (it asks the remote for the
scene), estimates every cloud in a worker process, adds each object while its loop runs at 1 kHz, then
the operator pushes objects for ``duration`` seconds: commands go to the remote, poses come back when they
leave the deadband. Nothing to start by hand, no router.
"""

from __future__ import annotations

import dataclasses
import multiprocessing as mp
import queue
import time
from pathlib import Path

import numpy as np
from rich.console import Console

from estimation.errors import TwinError
from twin.debuglog import OFF
from twin.rerunlog import RerunLog

#: What streaming raw clouds would cost: float32 x y z per point, at a depth camera's frame rate.
RAW_BYTES_PER_POINT, RAW_STREAM_HZ = 12, 30.0


def default_scene() -> Path:
    from scenes.scenefile import scene_data

    return scene_data() / "paper_table.toml"


def remote_record_path(record: Path) -> Path:
    """Where the demo's remote process records its side, beside the twin's ``record``: ``x.mcap`` ->
    ``x.remote.mcap`` (the one place that name is made)."""
    return Path(record).with_suffix(".remote.mcap")


def check_demo_records(record: Path, inputs: tuple[Path | None, ...] = ()) -> None:
    """Refuse, before anything starts, a ``record`` or its remote sibling (:func:`remote_record_path`) that
    the recordings must not replace: an input, a folder, a device, a file that is not a recording this program
    wrote.

    Raises:
        TwinError: naming ``--record``, the file and why.
    """
    from cli.outputs import check_record_file

    check_record_file(Path(record), inputs)
    sibling = remote_record_path(record)
    check_record_file(sibling, inputs, f"--record {record}: the remote's side goes to")


def remote_sensor(name: str, scene):  # type: ignore[no-untyped-def]
    """The remote's sensor for ``--sensor name`` (:func:`scenes.headless.sensor_for`): None (the Remote's default,
    the surface sensor) or the scene's default camera rig, scanning in the background (these remotes run live)."""
    from scenes.headless import sensor_for

    return sensor_for(name, scene, background=True)


def _remote_main(scene_path: str, endpoint: str, zenoh_config: str | None, ready, stop, results,  # type: ignore[no-untyped-def]
                 record: str | None = None, sensor: str = "surface", discard=None) -> None:
    """The remote's process: ``ready`` set once its scene is published, runs until ``stop``, then puts its
    counters (or ``{"error": ...}``) on ``results``; its recording is kept unless ``discard`` was set (the twin
    never started)."""
    from cli.record import open_recorder, recording_transport
    from scenes.remote import Remote
    from scenes.scenefile import load_scene
    from sync.clock import REAL_CLOCK
    from sync.zenoh_transport import ZenohTransport, make_config, open_session
    from twin.workers import die_with_parent

    die_with_parent()  # a killed demo must not leave its remote listening
    try:
        session = open_session(make_config(listen=[endpoint], config_file=zenoh_config, insecure_flag=None))
    except TwinError as exc:  # a config Zenoh or the checks refuse: the parent says it, in one line (not a traceback)
        results.put({"error": str(exc)})
        return
    recorder = None
    started = False
    try:
        try:
            recorder = open_recorder(None if record is None else Path(record), clock=REAL_CLOCK, command="demo",
                                     side="remote", scene_path=Path(scene_path), sensor=sensor)
            scene = load_scene(scene_path)
            remote = Remote(scene, recording_transport(ZenohTransport(session), recorder, "remote"),
                            recorder=recorder, sensor=remote_sensor(sensor, scene))
        except TwinError as exc:  # a scene the remote refuses: the parent says so, in one line
            results.put({"error": str(exc)})
            return
        started = True
        ready.set()
        stats = remote.run(24 * 3600.0, stop=stop)
        c = remote.link.counters
        said = {"bytes_sent": c.bytes_sent, "messages_sent": c.messages_sent, "pose_updates": remote.pose_updates,
                "points": remote.cloud_points(), "step_p99_ms": stats.p99 * 1e3,
                "dropped_malformed": c.dropped_malformed, "unseen_clouds": remote.unseen_clouds,
                "true_mass_kg": body_masses(remote.twin.model, remote.twin.object_ids())}
        feed = getattr(remote.sensor, "feed", None)  # the camera sensor's counters (scenes.cameras.FeedStats)
        if feed is not None:
            said["sensor_stats"] = dataclasses.asdict(feed.stats)
        remote.close()
        keep = discard is None or not discard.is_set()
        if recorder is not None and not keep:
            recorder.discard()  # the twin never started: an earlier FILE.remote.mcap stays as it was
        elif recorder is not None:
            try:  # before the results: a recording that could not be put in place is the parent's error
                recorder.close()
            except TwinError as exc:
                said = {"error": str(exc)}
        results.put(said)
    finally:
        session.close()
        if recorder is not None:
            recorder.close() if started and (discard is None or not discard.is_set()) else recorder.discard()


def run_demo(*, duration: float = 5.0, scene_path: Path | None = None, zenoh_config: str | None = None,
             progress: bool = True, rlog: RerunLog = OFF, hold: bool = True, record: Path | None = None,
             sensor: str = "surface") -> dict:
    """Run both sides and return the summary (the ``--json`` record).

    ``record``: an ``.mcap`` file for the twin's side (its wire messages both ways, the operator's targets
    and force, the scene file); the remote process writes its side, with the ground truth, beside it as
    ``<name>.remote.mcap``. Either replays with ``twin replay``.

    ``sensor``: the remote's, 'surface' or 'cameras' (``twin demo --sensor``).

    ``hold``: pin objects the remote reports at rest while the operator leaves them alone (:mod:`twin.hold`).

    ``rlog``: where the twin's side logs (its objects, its poses beside the remote poses it received,
    divergence, force, sync events). The remote process logs nothing.
    """
    from cli.record import open_recorder, recording_transport
    from scenes.scenefile import load_scene
    from sync.clock import REAL_CLOCK
    from sync.zenoh_transport import SessionError, ZenohTransport, free_port, make_config, open_session
    from twin.decompose import ProgressBar
    from twin.hold import HoldSettings
    from twin.runtime import Local, LocalSettings
    from twin.trajectory import push_trajectory

    console = Console(quiet=not progress, stderr=True)
    scene_path = scene_path or default_scene()
    push_by = np.asarray(load_scene(scene_path).push, dtype=float)  # here too: a bad scene fails before the remote starts
    if record is not None:  # both files, before the remote starts: a refused one costs nothing
        check_demo_records(record, (scene_path, Path(zenoh_config) if zenoh_config else None))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    ctx = mp.get_context("spawn")
    ready, stop, discard, results = ctx.Event(), ctx.Event(), ctx.Event(), ctx.Queue()
    remote_record = None if record is None else str(remote_record_path(record))
    remote = ctx.Process(target=_remote_main, args=(str(scene_path), endpoint, zenoh_config, ready, stop, results,
                                                    remote_record, sensor, discard))
    console.print(f"[bold]tactile-twin demo[/bold]: remote scene {scene_path.name} on {endpoint} (peer mode)")
    t0 = time.perf_counter()
    remote.start()
    try:
        while not ready.wait(0.2):
            if not remote.is_alive():
                try:
                    said = results.get(timeout=1.0)
                except queue.Empty:
                    said = {}
                if "error" in said:
                    raise TwinError(said["error"])
                raise SessionError("the remote process exited before it was ready (see its error above)")
    except BaseException:
        remote.terminate()
        raise
    console.print(f"remote ready in {time.perf_counter() - t0:.1f} s (ground truth built, clouds published)")
    try:
        session = open_session(make_config(connect=[endpoint], config_file=zenoh_config, insecure_flag=None))
    except BaseException:  # the remote runs for a day unless told: it printed the error, then never exited
        discard.set()
        stop.set()
        remote.join(timeout=10)
        if remote.is_alive():
            remote.terminate()
        raise
    recorder = open_recorder(record, clock=REAL_CLOCK, command="demo", side="twin", scene_path=scene_path,
                             sensor=sensor)
    local = None
    try:
        t_join = time.perf_counter()
        local = Local(recording_transport(ZenohTransport(session), recorder, "twin"),
                      settings=LocalSettings(workers=2, hold=HoldSettings(enabled=hold)), rlog=rlog, recorder=recorder)
        expected = local.expected
        console.print(f"twin joined late and got {expected} clouds; estimating them while the loop runs at 1 kHz")
        # Camera clouds take seconds each to estimate and decompose (a 20-object scene, minutes): say how far.
        bar, shown = ProgressBar(progress, expected, "objects touchable in the twin"), [0]

        def touchable() -> bool:
            count = len(local.objects)
            while shown[0] < min(count, expected):
                bar.advance()
                shown[0] += 1
            # local.expected, not the count at joining: a cloud the twin refused (out of its scene box, or one
            # its estimator rejects) leaves it, and waiting for it held the demo for ten minutes.
            return count >= local.expected and not local.adding

        try:
            local.run(600.0, until=touchable)
        finally:
            bar.close()
        sync_s = time.perf_counter() - t_join
        refused = expected - len(local.objects)
        console.print(f"all {len(local.objects)} objects touchable in the twin after {sync_s:.1f} s"
                      + (f" ({refused} cloud(s) refused: see the warnings above)" if refused > 0 else ""))
        start = local.twin.data.mocap_pos[0].copy()
        push = push_trajectory(start, start + push_by, duration, start_time=local.twin.time)
        # The latency target is the push phase's (the live stack's own); poses while objects were being
        # estimated (keyframes, competing with the estimation workers for the two cores) are reported apart.
        pushed_from = len(local.report.pose_latency)
        stats = local.run(duration, trajectory=push)
        session_s = time.perf_counter() - t_join
        report, counters = local.report, local.link.counters
        drift = {i: float(np.linalg.norm(local.twin.pose(i)[0] - r[0])) for i in local.objects
                 if (r := local.remote_pose(i)) is not None}
        estimated = body_masses(local.twin.model, local.objects)
        estimates = object_estimates(local)
        poses = {i: local.twin.pose(i) for i in local.objects}
    finally:
        if local is None:
            discard.set()  # before stop: the remote then drops its recording too
        stop.set()
        if local is not None:
            local.close()
        session.close()
        if recorder is not None and local is None:
            recorder.discard()  # the twin never started: leave any earlier file at --record as it was
        elif recorder is not None:
            recorder.close(twin_time_s=local.twin.time)
    remote_stats = results.get(timeout=60)
    remote.join(timeout=10)
    if remote.is_alive():
        remote.terminate()
    if "error" in remote_stats:  # the remote ran but could not finish its recording
        raise TwinError(remote_stats["error"])
    raw = sum(remote_stats["points"].values()) * RAW_BYTES_PER_POINT * RAW_STREAM_HZ * session_s
    lat_all = np.asarray(report.pose_latency) * 1e3
    lat = lat_all[pushed_from:] if len(lat_all) > pushed_from else np.zeros(1)
    joining = lat_all[:pushed_from] if pushed_from else np.zeros(1)
    gaps = np.concatenate([np.asarray(g) for g in report.divergence.values()] or [np.zeros(1)]) * 1e3
    out = {
        "objects_synced": report.objects_synced,
        "pose_updates": report.pose_updates,
        "bytes_sent": remote_stats["bytes_sent"] + counters.bytes_sent,
        "raw_stream_bytes": int(raw),
        "bandwidth_ratio": raw / max(1, remote_stats["bytes_sent"] + counters.bytes_sent),
        "pose_latency_p50_ms": float(np.percentile(lat, 50)),  # while pushing, publish to applied
        "pose_latency_p99_ms": float(np.percentile(lat, 99)),
        "pose_latency_max_ms": float(lat.max()),
        "poses_while_pushing": int(len(lat_all) - pushed_from),
        "pose_latency_while_adding_p99_ms": float(np.percentile(joining, 99)),
        "poses_while_adding": int(pushed_from),
        "pose_stamps_off": report.stamps_off,  # poses whose stamp was no latency (twin.runtime.LATENCY_RANGE)
        "dropped_malformed": counters.dropped_malformed + remote_stats["dropped_malformed"],
        "add_latency_s": [round(x, 3) for x in report.add_latency],
        "worst_step_while_adding_ms": report.worst_step_while_adding * 1e3,
        "step_p50_ms": stats.p50 * 1e3,
        "step_p99_ms": stats.p99 * 1e3,
        "missed_deadlines": stats.missed,
        "stale_events": report.stale_events,
        "divergence_p50_mm": float(np.percentile(gaps, 50)),
        "divergence_p99_mm": float(np.percentile(gaps, 99)),
        "divergence_max_mm": float(gaps.max()),
        "divergence_max_mm_by_object": {i: round(max(g) * 1e3, 2) for i, g in report.divergence.items() if g},
        "snaps": report.snaps,
        "lost_by_sensor": report.unseen,
        "holds": report.holds,
        "warned_objects": report.warned_objects,
        # objects the remote's sensor never observed apart, so never published (scenes.remote.Remote.unseen_clouds)
        "unseen_clouds": remote_stats["unseen_clouds"],
        "sensor_stats": remote_stats.get("sensor_stats"),  # cameras: scans, unseen, merged, lost tracks ...
        "session_s": session_s,
        "twin_minus_remote_m": drift,
        "per_object": object_records(report, estimated, poses, drift, remote_stats.get("true_mass_kg"),
                                     estimates=estimates),
    }
    # The summary is the result: stdout (progress went to stderr); with --json, the caller prints the record.
    Console(quiet=not progress).print(
        f"pushed for {duration:g} s: {out['poses_while_pushing']} pose corrections, latency p50 "
        f"{out['pose_latency_p50_ms']:.3f} ms, p99 {out['pose_latency_p99_ms']:.3f} ms (while objects were "
        f"added: {out['poses_while_adding']}, p99 {out['pose_latency_while_adding_p99_ms']:.3f} ms)\n"
        f"bytes sent {out['bytes_sent']:,} vs {out['raw_stream_bytes']:,} for raw clouds at 30 Hz "
        f"({out['bandwidth_ratio']:,.0f}x less); malformed dropped {out['dropped_malformed']}\n"
        f"twin loop: p50 {out['step_p50_ms']:.3f} ms, p99 {out['step_p99_ms']:.3f} ms per step; worst step while "
        f"an object was being added {out['worst_step_while_adding_ms']:.1f} ms\n"
        f"twin - remote (every 10 ms, all objects): p50 {out['divergence_p50_mm']:.1f} mm, p99 "
        f"{out['divergence_p99_mm']:.1f} mm, max {out['divergence_max_mm']:.1f} mm; {out['snaps']} snaps, "
        f"{out['holds']} holds"
        + (f"\nthe remote's sensor lost sight of objects {out['lost_by_sensor']} time(s); the twin simulated them "
           f"alone from then (not in the divergence)" if out["lost_by_sensor"] else "")
        + (f"\nthe estimates of {', '.join(sorted(i for i, e in estimates.items() if e.warnings))} came with warnings "
           f"(on stderr as each was added; per_object in --json)" if any(e.warnings for e in estimates.values())
           else ""))
    return out


def body_masses(model, object_ids) -> dict[str, float]:  # type: ignore[no-untyped-def]
    """Object id -> the mass (kg) of its body in a compiled model."""
    import mujoco

    return {i: float(model.body_mass[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, i)]) for i in object_ids}


def object_estimates(local) -> dict:  # type: ignore[no-untyped-def]
    """Object id -> the :class:`estimation.PhysicalEstimate` each object in a :class:`twin.runtime.Local` went into
    the twin with (:meth:`twin.runtime.Local.twin_object`)."""
    return {i: obj.estimate for i in local.objects if (obj := local.twin_object(i)) is not None}


def object_records(report, estimated_mass_kg: dict[str, float], poses: dict[str, tuple[np.ndarray, np.ndarray]],  # type: ignore[no-untyped-def]
                   twin_minus_remote_m: dict[str, float], true_mass_kg: dict[str, float] | None = None, *,
                   estimates: dict | None = None) -> list[dict]:
    """One record per object in the twin, SI base units throughout (kg, m, s; the top-level summary's ``_ms``
    and ``_mm`` fields are older and say their units in their names too).

    ``report``: the twin's :class:`twin.runtime.LocalReport`. ``true_mass_kg``: the remote's truth, where
    known (the demo's remote has it; a real scene does not): adds ``true_mass_kg`` and ``mass_error_pct``
    (estimated minus true, percent of true). ``estimates``: id -> the :class:`estimation.PhysicalEstimate` the
    object went into the twin with (:func:`object_estimates`), for ``estimated_volume_m3``, ``volume_bounds_m3``
    ([low, high]; an infinite bound is JSON's null) and ``warnings`` (the estimate's; None where not known).
    """
    out = []
    for object_id, (position, quat) in poses.items():
        gaps = report.divergence.get(object_id) or []
        touchable = report.touchable_after.get(object_id)
        est = None if estimates is None else estimates.get(object_id)
        bounds = None if est is None else est.volume_bounds_m3
        record: dict = {
            "id": object_id,
            "estimated_mass_kg": estimated_mass_kg.get(object_id),
            "estimated_volume_m3": None if est is None else est.volume,
            "volume_bounds_m3": None if bounds is None else list(bounds),
            "warnings": None if est is None else list(est.warnings),
            "add_latency_s": None if touchable is None else touchable[1],  # cloud arrived -> touchable
            "add_latency_from_publish_s": None if touchable is None else touchable[0],
            "divergence_max_m": max(gaps) if gaps else None,
            "twin_minus_remote_m": twin_minus_remote_m.get(object_id),
            "position_m": position.tolist(),
            "quat_wxyz": quat.tolist(),
        }
        if true_mass_kg is not None and object_id in true_mass_kg:
            true, est = true_mass_kg[object_id], record["estimated_mass_kg"]
            record["true_mass_kg"] = true
            record["mass_error_pct"] = None if est is None else 100.0 * (est - true) / true
        out.append(record)
    return out
