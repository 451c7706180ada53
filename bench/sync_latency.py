"""Synchronisation latency over Zenoh on loopback: pose updates, and a new object's time to touchable.

    .venv/bin/python bench/sync_latency.py [--seconds 10] [--points 200000] [--json]

Two processes, as in ``twin demo``: the remote (C) in a child process listening on a free loopback port
in peer mode, the twin (C') in this one. Three measurements:

1. Pose latency, publish to applied in the twin: the remote moves a crate kinematically on a 10 cm
   circle at 0.2 m/s (so it leaves the 1 mm deadband every 5 ms) for ``--seconds``; each pose's stamp is
   compared with the wall clock when the twin applies it (same machine, same clock). Run twice: with
   the remote's 1 Hz keyframes (the default) and without.
2. Cold: the remote adds a torus sampled with ``--points`` points while the twin runs, with the twin's
   CoACD cache empty: seconds from the cloud's publish stamp to the object being touchable (estimated,
   decomposed, compiled in, swapped into the running loop), and the twin's worst step meanwhile.
3. Warm: a second twin joins late with the same cache; the remote hands it the same cloud (the
   queryable keeps the published bytes), so CoACD is a cache hit: seconds from the cloud received to
   touchable.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import sys
import tempfile
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

SCENE = {
    "name": "latency",
    "table": {"size": [1.0, 0.8, 0.04], "height": 0.5},
    "end_effector": {"radius": 0.02, "position": [-0.4, -0.3, 0.6]},
    "objects": [{"id": "crate", "primitive": {"type": "box", "size": [0.12, 0.08, 0.06]}, "material": "wood_pine",
                 "position": [0.0, 0.0], "points": 8000}],
}
CIRCLE_RADIUS, CIRCLE_SPEED, HOVER = 0.10, 0.20, 0.05  # m, m/s, m above the table


def remote_main(endpoint: str, points: int, keyframe_s: float, ready, add, stop) -> None:  # type: ignore[no-untyped-def]
    from scenes.remote import Remote
    from scenes.scenefile import ObjectSpec, parse_scene
    from sync.zenoh_transport import ZenohTransport, make_config, open_session
    from twin.loop import run_loop

    session = open_session(make_config(listen=[endpoint]))
    remote = Remote(parse_scene(SCENE), ZenohTransport(session), keyframe_s=keyframe_s)
    centre = remote.twin.pose("crate")[0] + np.array([0.0, 0.0, HOVER])
    omega = CIRCLE_SPEED / CIRCLE_RADIUS
    ready.set()
    added = False

    def body() -> None:
        nonlocal added
        t = remote.twin.time
        c, s = np.cos(omega * t), np.sin(omega * t)
        remote.twin.set_pose("crate", centre + CIRCLE_RADIUS * np.array([c, s, 0.0]), np.array([1.0, 0, 0, 0]),
                             forward=False)
        remote.twin.set_velocity("crate", CIRCLE_SPEED * np.array([-s, c, 0.0]), np.zeros(3))
        remote.step()
        if add.is_set() and not added:
            added = True
            remote.add(ObjectSpec(id="torus", source="primitive", value={"type": "torus", "size": [0.08, 0.03]},
                                  material="ceramic", position=(0.25, 0.2), points=points))

    run_loop(body, rate=1000.0, duration=24 * 3600.0, until=stop.is_set)
    remote.close()
    session.close()


def twin(endpoint: str, cache: Path):  # type: ignore[no-untyped-def]
    from sync.zenoh_transport import ZenohTransport, make_config, open_session
    from twin.runtime import Local, LocalSettings

    session = open_session(make_config(connect=[endpoint]))
    local = Local(ZenohTransport(session), settings=LocalSettings(cache_dir=cache))
    return local, session


def wait_for(local, object_id: str, timeout: float) -> None:  # type: ignore[no-untyped-def]
    local.run(timeout, until=lambda: object_id in local.objects and not local.adding)
    if object_id not in local.objects:
        raise SystemExit(f"{object_id} did not arrive in {timeout:g} s")


def pose_latency(seconds: float, keyframe_s: float, points: int, cache: Path, *, add_object: bool) -> dict:
    from sync.zenoh_transport import free_port

    ctx = mp.get_context("spawn")
    ready, add, stop = ctx.Event(), ctx.Event(), ctx.Event()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = ctx.Process(target=remote_main, args=(endpoint, points, keyframe_s, ready, add, stop))
    proc.start()
    out: dict = {}
    try:
        if not ready.wait(120):
            raise SystemExit("the remote did not start")
        local, session = twin(endpoint, cache)
        try:
            wait_for(local, "crate", 120)
            local.report.pose_latency.clear()
            local.run(seconds)
            lat = np.asarray(local.report.pose_latency) * 1e3
            out = {"keyframe_s": keyframe_s, "poses": len(lat), "p50_ms": float(np.percentile(lat, 50)),
                   "p99_ms": float(np.percentile(lat, 99)), "max_ms": float(lat.max())}
            if add_object:
                local.report.worst_step_while_adding = 0.0
                add.set()
                wait_for(local, "torus", 600)
                out["cold_publish_to_touchable_s"], out["cold_received_to_touchable_s"] = \
                    local.report.touchable_after["torus"]
                out["cold_worst_step_ms"] = local.report.worst_step_while_adding * 1e3
                late, late_session = twin(endpoint, cache)  # same cache: CoACD hits
                try:
                    wait_for(late, "torus", 600)
                    out["warm_received_to_touchable_s"] = late.report.touchable_after["torus"][1]
                    out["warm_worst_step_ms"] = late.report.worst_step_while_adding * 1e3
                finally:
                    late.close()
                    late_session.close()
        finally:
            local.close()
            session.close()
    finally:
        stop.set()
        proc.join(30)
        if proc.is_alive():
            proc.terminate()
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--points", type=int, default=200_000)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        with_keyframes = pose_latency(args.seconds, 1.0, args.points, Path(tmp) / "coacd", add_object=True)
        without = pose_latency(args.seconds, 0.0, args.points, Path(tmp) / "coacd", add_object=False)
    if args.json:
        print(json.dumps({"seconds": args.seconds, "points": args.points, "keyframes": with_keyframes,
                          "no_keyframes": without}))
        return 0
    console = Console()
    table = Table(title=f"pose latency, publish to applied, loopback, {args.seconds:g} s of a circling crate")
    for col in ("remote keyframes", "poses", "p50 ms", "p99 ms", "max ms"):
        table.add_column(col, justify="right")
    for r in (with_keyframes, without):
        table.add_row("1 Hz" if r["keyframe_s"] else "off", str(r["poses"]), f"{r['p50_ms']:.3f}",
                      f"{r['p99_ms']:.3f}", f"{r['max_ms']:.2f}")
    console.print(table)
    r = with_keyframes
    table = Table(title=f"a new object ({args.points:,}-point torus) until touchable in the running twin")
    for col in ("CoACD cache", "seconds", "measured from", "worst twin step meanwhile, ms"):
        table.add_column(col, justify="right")
    table.add_row("cold", f"{r['cold_publish_to_touchable_s']:.2f}", "remote publishes the cloud",
                  f"{r['cold_worst_step_ms']:.1f}")
    table.add_row("cold", f"{r['cold_received_to_touchable_s']:.2f}", "twin receives the cloud", "")
    table.add_row("warm", f"{r['warm_received_to_touchable_s']:.2f}", "twin receives the cloud (late join)",
                  f"{r['warm_worst_step_ms']:.1f}")
    console.print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
