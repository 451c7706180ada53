"""What Zenoh's priorities and express flag do to pose latency and CPU on loopback: measured, and not used
(``sync.zenoh_transport.ZenohTransport.put`` publishes at Zenoh's default; docs/sync.md).

    .venv/bin/python bench/zenoh_qos.py [--repeats 4] [--seconds 5]   # output in bench/results/zenoh_qos.txt

A publisher process and a subscriber (this process), peer sessions on a free loopback port as the live
commands open them (``sync.zenoh_transport.make_config``). The publisher sends pose-sized messages (208 bytes,
its clock in the first 8) on a 1 kHz loop; the subscriber takes each message's age on arrival (one machine,
one monotonic clock). Two loads:

1. 20 poses a tick (a 20-object scene, every object moving): messages received of those sent, both processes'
   CPU seconds, latency p50 / p99; for Zenoh's default (priority DATA, batched), the interactive-high and the
   real-time priorities, and real-time with ``express`` (not batched).
2. One pose a tick while 8 MB clouds go out ten times a second on another key: latency p50 / p99 / max of the
   poses, with every message at the default priority and with the poses at interactive-high, the clouds at
   DATA_LOW (Zenoh keeps a queue per priority on a link: the poses need not wait behind a cloud's fragments).

Configurations alternate within each repeat, in this one process, so machine load hits all alike; the table
gives the median over repeats.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages, not an installed copy

POSE_BYTES = 200  # plus the 8-byte clock: about a Pose message's size
CLOUD_BYTES = 8_000_000
CLOUD_EVERY = 0.1  # seconds
WARM_UP = 0.5  # seconds of messages left out at the start
LOADS = {
    "20 poses a tick": {"default": ({}, {}), "interactive-high priority": ({"priority": "INTERACTIVE_HIGH"}, {}),
                        "real-time priority": ({"priority": "REAL_TIME"}, {}),
                        "real-time, express": ({"priority": "REAL_TIME", "express": True}, {})},
    "1 pose a tick, 8 MB clouds at 10 Hz": {"default": ({}, {}),
                                             "poses interactive-high, clouds DATA_LOW": (
                                                 {"priority": "INTERACTIVE_HIGH"}, {"priority": "DATA_LOW"})},
}


def _options(spec: dict) -> dict:
    import zenoh

    return {k: getattr(zenoh.Priority, v) if k == "priority" else v for k, v in spec.items()}


def publisher(endpoint: str, seconds: float, per_tick: int, clouds: bool, pose_qos: dict, cloud_qos: dict,
              ready, go, out) -> None:  # type: ignore[no-untyped-def]
    from sync.zenoh_transport import make_config, open_session

    session = open_session(make_config(listen=[endpoint]))
    pose_options, cloud_options = _options(pose_qos), _options(cloud_qos)
    keys = [f"twin/qos/objects/o{i}/pose" for i in range(per_tick)]
    blob = os.urandom(CLOUD_BYTES) if clouds else b""
    ready.set()
    go.wait()
    cpu, next_tick, last_cloud = time.process_time(), time.monotonic(), -1e9
    for _ in range(round(seconds * 1000)):
        next_tick += 0.001
        left = next_tick - time.monotonic()
        if left > 0:
            time.sleep(left)
        if clouds and time.monotonic() - last_cloud >= CLOUD_EVERY:
            last_cloud = time.monotonic()
            session.put("twin/qos/objects/big/cloud", blob, **cloud_options)
        for key in keys:
            session.put(key, time.monotonic_ns().to_bytes(8, "little") + b"x" * POSE_BYTES, **pose_options)
    out.put(time.process_time() - cpu)
    time.sleep(0.5)  # let the last messages out before the session closes
    session.close()


def run(seconds: float, per_tick: int, clouds: bool, pose_qos: dict, cloud_qos: dict) -> dict:
    """One publisher run: poses received, both sides' CPU seconds, latency percentiles (ms)."""
    from sync.zenoh_transport import free_port, make_config, open_session

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    ctx = mp.get_context("spawn")
    ready, go, out = ctx.Event(), ctx.Event(), ctx.Queue()
    proc = ctx.Process(target=publisher, args=(endpoint, seconds, per_tick, clouds, pose_qos, cloud_qos, ready, go, out))
    proc.start()
    if not ready.wait(60):
        raise SystemExit("the publisher did not start")
    session = open_session(make_config(connect=[endpoint]))
    ages: list[int] = []

    def on_sample(sample) -> None:  # type: ignore[no-untyped-def]
        if str(sample.key_expr).endswith("/pose"):
            ages.append(time.monotonic_ns() - int.from_bytes(sample.payload.to_bytes()[:8], "little"))

    session.declare_subscriber("twin/qos/**", on_sample)
    time.sleep(1.0)  # the subscription reaches the publisher
    cpu = time.process_time()
    go.set()
    publisher_cpu = out.get(timeout=seconds + 60)
    proc.join(30)
    subscriber_cpu = time.process_time() - cpu
    session.close()
    lat = np.asarray(ages[round(WARM_UP * 1000 * per_tick):], dtype=float) / 1e6
    return {"received": len(ages) / (round(seconds * 1000) * per_tick), "publisher_cpu": publisher_cpu,
            "subscriber_cpu": subscriber_cpu, "p50": float(np.percentile(lat, 50)),
            "p99": float(np.percentile(lat, 99)), "max": float(lat.max())}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=4)
    parser.add_argument("--seconds", type=float, default=5.0)
    args = parser.parse_args(argv)
    results: dict[tuple[str, str], list[dict]] = {}
    for _ in range(args.repeats):
        for load, configs in LOADS.items():
            per_tick, clouds = (20, False) if load.startswith("20") else (1, True)
            for name, (pose_qos, cloud_qos) in configs.items():
                results.setdefault((load, name), []).append(run(args.seconds, per_tick, clouds, pose_qos, cloud_qos))
                print(f"{load}, {name}: done", file=sys.stderr, flush=True)
    console = Console(width=150)
    table = Table(title=f"Zenoh on loopback, {args.seconds:g} s a run, median of {args.repeats} (alternating runs)")
    for col in ("load", "configuration", "received %", "publisher CPU s", "subscriber CPU s", "p50 ms", "p99 ms",
                "max ms", "p99 x default"):
        table.add_column(col, justify="right")
    for (load, name), runs in results.items():
        med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        base = statistics.median(r["p99"] for r in results[load, "default"])
        table.add_row(load, name, f"{100 * med['received']:.2f}", f"{med['publisher_cpu']:.2f}",
                      f"{med['subscriber_cpu']:.2f}", f"{med['p50']:.3f}", f"{med['p99']:.3f}", f"{med['max']:.2f}",
                      f"{med['p99'] / base:.2f}x")
    console.print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
