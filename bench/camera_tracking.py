"""Tracking with the cameras while objects move: pushed at speed, pushed into another, pushed off the table.

    .venv/bin/python bench/camera_tracking.py      # output in bench/results/camera_tracking.txt

Each scenario is a headless session (scenes.headless: remote and twin on one simulated clock, repeatable)
of a crate and a can on a 1 m table; the operator pushes the crate 30 cm at 0.1, 0.3 or 0.6 m/s, or into
the can, or off the table's end, then holds still for 1.5 s. Three remote sensors, each run in this process:
- ``surface``: the simulator's own poses (what the twin gets with perfect sensing: the baseline for C'-C);
- ``cameras, gate only``: the camera tracker with its prediction, re-acquisition and coarse ICP pass
  switched off (``scenes.association.MAX_SPEED``, ``VELOCITY_WINDOW`` and ``CENTROID_TURNS`` to 0 or none, ``COARSE_FACTOR``
  1): the association and ICP start of before commit 76544b1 (what the wire says of a lost object,
  ``Pose.seen``, is the same for both);
- ``cameras``: the tracker as it is (scenes.sensing.CameraSensor, 3 Kinect-model cameras, a scan every
  0.5 s).
At every scan, each object's track (when the tracker says it saw it) is compared with where the object's
frame truly is (its capture frame moved by the body's true motion since); C'-C is the twin's body against
the remote's, every 10 ms, all objects.
"""

from __future__ import annotations

import sys
import time
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

#: The scene (a crate pushed along x; its can moved per scenario).
SCENE = ROOT / "scenes" / "data" / "crate_and_can.toml"

#: The end effector starts 22 cm short of moving the crate (its left face, less its radius).
SLACK = 0.22

#: name, can position, how far the crate is pushed (m), at what speed (m/s).
SCENARIOS = (
    ("30 cm at 0.1 m/s", (0.2, 0.2), 0.30, 0.1),
    ("30 cm at 0.3 m/s", (0.2, 0.2), 0.30, 0.3),
    ("30 cm at 0.6 m/s", (0.2, 0.2), 0.30, 0.6),
    ("into the can, 0.1 m/s", (0.22, 0.03), 0.30, 0.1),
    ("off the table, 0.3 m/s", (0.2, 0.2), 0.80, 0.3),
)

HOLD_S = 1.5


@contextmanager
def gate_only():
    """The camera tracker without prediction, re-acquisition or coarse pass (module constants)."""
    import scenes.association as association
    import scenes.sensing as sensing

    saved = [(association, "MAX_SPEED")] + [(sensing, k) for k in ("VELOCITY_WINDOW", "CENTROID_TURNS", "COARSE_FACTOR")]
    values = [getattr(module, k) for module, k in saved]
    association.MAX_SPEED, sensing.VELOCITY_WINDOW, sensing.CENTROID_TURNS, sensing.COARSE_FACTOR = 0.0, 0.0, (), 1.0
    try:
        yield
    finally:
        for (module, k), v in zip(saved, values, strict=True):
            setattr(module, k, v)


def run(scene, push: float, speed: float, sensor_name: str) -> dict:  # type: ignore[no-untyped-def]
    from scenes.headless import Headless
    from scenes.sensing import CameraSensor
    from twin.poses import rotation
    from twin.trajectory import push_trajectory

    sensor = None if sensor_name == "surface" else CameraSensor.for_scene(scene)
    errors, gaps = [], []
    t0 = time.perf_counter()
    with Headless(scene, sensor=sensor) as s:
        ids = [o.id for o in scene.objects]
        s.run(0.5)
        start = {i: s.remote.twin.pose(i) for i in ids}
        frames = {}
        if sensor is not None:
            # The frame each track moves: the one the first observation put on the object.
            frames = {i: sensor.track(s.remote, i) for i in ids}
            frames = {i: (t.position, *start[i]) for i, t in frames.items()}
        ee = s.local.twin.data.mocap_pos[0].copy()
        duration = (push + SLACK) / speed
        trajectory = push_trajectory(ee, ee + np.array([push + SLACK, 0.0, 0.0]), duration,
                                     start_time=s.local.twin.time)
        scans = 0 if sensor is None else sensor.feed.stats.scans
        ticks = round((duration + HOLD_S) / s.dt)
        every = round(0.01 / s.dt)
        for k in range(ticks):
            s.tick(trajectory)
            if sensor is not None and sensor.feed.stats.scans != scans:
                scans = sensor.feed.stats.scans
                for i in ids:
                    track = sensor.track(s.remote, i)
                    if not track.seen:
                        continue
                    p0, c0, q0 = frames[i]
                    c, q = s.remote.twin.pose(i)
                    truth = rotation(q) @ rotation(q0).T @ (p0 - c0) + c
                    errors.append(float(np.linalg.norm(track.position - truth)))
            if k % every == 0:
                gaps += [float(np.linalg.norm(s.local.twin.pose(i)[0] - s.remote.twin.pose(i)[0])) for i in ids]
        stats = None if sensor is None else sensor.feed.stats
        return {"errors": errors, "gaps": gaps, "stats": stats, "wall": time.perf_counter() - t0,
                "unseen_reports": s.remote.unseen_reports}


def main() -> None:
    console = Console(width=200, record=True)
    table = Table(title="camera tracking while pushed (3 Kinect-model cameras, a scan every 0.5 s; headless)")
    for col in ("scenario", "remote sensor", "scans", "track error p50 / max mm", "unseen / ICP lost",
                "merged", "said lost", "C'-C p50 / p99 / max mm", "wall s"):
        table.add_column(col, justify="right")
    from scenes.scenefile import load_scene

    base = load_scene(SCENE)
    for name, (can_x, can_y), push, speed in SCENARIOS:
        scene = replace(base, objects=tuple(replace(o, position=(can_x, can_y)) if o.id == "can" else o
                                            for o in base.objects))
        for sensor_name in ("surface", "cameras, gate only", "cameras"):
            console.print(f"{name}: {sensor_name}", style="dim")
            if sensor_name == "cameras, gate only":
                with gate_only():
                    r = run(scene, push, speed, "cameras")
            else:
                r = run(scene, push, speed, sensor_name)
            st, e, g = r["stats"], np.array(r["errors"]) * 1e3, np.array(r["gaps"]) * 1e3
            table.add_row(name, sensor_name, "-" if st is None else str(st.scans),
                          f"{np.median(e):.1f} / {e.max():.1f}" if len(e) else "-",
                          "-" if st is None else f"{st.unseen} / {st.lost_tracks}",
                          "-" if st is None else str(st.merged), str(r["unseen_reports"]),
                          f"{np.median(g):.1f} / {np.percentile(g, 99):.1f} / {g.max():.1f}",
                          f"{r['wall']:.1f}")
    console.print(table)
    out = ROOT / "bench" / "results" / "camera_tracking.txt"
    out.write_text(console.export_text(), encoding="utf-8")
    print(f"written to {out.relative_to(ROOT)}", file=sys.stderr)


if __name__ == "__main__":
    main()
