"""The twin's loop under a message flood: step p99 and missed deadlines with and without one.

    .venv/bin/python bench/flood.py [--seconds 3] [--rates 0,1000,10000,max] > bench/results/flood.txt

A remote scene (two objects) and a twin on real Zenoh sessions over loopback TCP; a third session connects
straight to the twin and publishes, for ``--seconds``, a cycle of what a hostile or broken peer sends:
undecodable bytes, a pose filed under another object's key, a NaN pose and a valid but stale pose (older
epoch), all on an object's pose key. The twin runs its 1 kHz loop meanwhile (rate 0: no flood). Rates are
messages per second, paced in 1 ms batches; ``max`` publishes as fast as the flooder's thread can.
"sent" is what the flooder's puts took; Zenoh's default congestion control drops in transit what the link
cannot carry, so "dropped" plus "stale refused" is what reached the twin. The flooder shares the machine (and Python's GIL) with the twin and the remote: on two cores that is part
of what is measured.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages, not an installed copy

from scenes.remote import Remote
from scenes.scenefile import load_scene
from sync.keys import Keys
from sync.messages import VERSION, Pose, encode
from sync.zenoh_transport import ZenohTransport, free_port, make_config, open_session
from twin.runtime import Local, LocalSettings

#: The tests' two-object scene (a crate and a can on a table).
SCENE = Path(__file__).resolve().parent.parent / "tests" / "data" / "small.toml"


def _messages(keys: Keys, epoch: int) -> list[bytes]:
    def pose(object_id: str, position, epoch: int) -> bytes:  # type: ignore[no-untyped-def]
        return encode(Pose(v=VERSION, stamp_ns=1, object_id=object_id, epoch=epoch, seq=1, sim_time=0.0,
                           position=position, quat=(1.0, 0.0, 0.0, 0.0), linvel=(0.0, 0.0, 0.0),
                           angvel=(0.0, 0.0, 0.0)))

    return [b"\xc1" + bytes(range(64)), pose("can", (0.3, 0.0, 0.55), epoch + 1),
            pose("crate", (float("nan"), 0.0, 0.55), epoch + 1), pose("crate", (0.3, 0.0, 0.55), epoch - 1)]


def _flood(publisher, payloads: list[bytes], rate: float | None, seconds: float,
           stop: threading.Event, sent: list[int]) -> None:  # type: ignore[no-untyped-def]
    start = time.monotonic()
    i = 0
    while not stop.is_set() and time.monotonic() - start < seconds:
        batch = 1000 if rate is None else max(1, round(rate * 1e-3))
        for _ in range(batch):
            publisher.put(payloads[i % len(payloads)])
            i += 1
        if rate is not None:  # pace: the i-th message is due at start + i / rate
            ahead = start + i / rate - time.monotonic()
            if ahead > 0:
                time.sleep(ahead)
    sent[0] = i


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--rates", default="0,1000,10000,max")
    parser.add_argument("--cache", type=Path, default=Path("/tmp/tactile-twin-bench-coacd"))
    args = parser.parse_args(argv)
    rates = [None if r == "max" else float(r) for r in args.rates.split(",")]
    scene = load_scene(SCENE)
    keys = Keys(scene.name)
    remote_ep, twin_ep = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    server = open_session(make_config(listen=[remote_ep]))
    remote = Remote(scene, ZenohTransport(server), cache_dir=args.cache)
    stop_remote = threading.Event()
    remote_thread = threading.Thread(target=remote.run, args=(3600.0,), kwargs={"stop": stop_remote})
    remote_thread.start()
    client = open_session(make_config(connect=[remote_ep], listen=[twin_ep]))
    flooder = open_session(make_config(connect=[twin_ep]))
    local = Local(ZenohTransport(client), settings=LocalSettings(cache_dir=args.cache))
    rows = []
    try:
        local.run(60.0, until=lambda: len(local.objects) == 2 and not local.adding)
        publisher = flooder.declare_publisher(keys.object("crate", "pose"))
        deadline = time.monotonic() + 10
        while not publisher.matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.01)
        payloads = _messages(keys, remote.epoch)
        local.run(1.0)  # settle
        for rate in rates:
            dropped0 = local.link.counters.dropped_malformed
            stale0 = local.report.out_of_order
            t0 = local.twin.time
            stop, sent = threading.Event(), [0]
            thread = None
            if rate != 0:
                thread = threading.Thread(target=_flood, args=(publisher, payloads, rate, args.seconds, stop, sent))
                thread.start()
            stats = local.run(args.seconds)
            sim = local.twin.time - t0
            stop.set()
            if thread is not None:
                thread.join()
            local.run(0.5)  # let the queue drain before the next row
            rows.append(("none" if rate == 0 else "max" if rate is None else f"{rate:,.0f}", sent[0],
                         sent[0] / args.seconds, local.link.counters.dropped_malformed - dropped0,
                         local.report.out_of_order - stale0, stats.steps, stats.missed,
                         stats.p50 * 1e3, stats.p99 * 1e3, stats.max * 1e3, sim,
                         float(np.linalg.norm(local.twin.pose("crate")[0] - remote.twin.pose("crate")[0]))))
        publisher.undeclare()
    finally:
        local.close()
        stop_remote.set()
        remote_thread.join()
        remote.close()
        flooder.close()
        client.close()
        server.close()
    table = Table(title=f"twin loop (1 kHz) under a flood on an object's pose key, {args.seconds:g} s per row, "
                        "loopback, 2 cores shared by remote, twin and flooder")
    for col in ("flood msg/s", "sent", "sent/s", "dropped", "stale refused", "steps", "missed", "step p50 ms",
                "step p99 ms", "step max ms", "sim time s", "crate |twin-remote| mm"):
        table.add_column(col, justify="right")
    for (rate, sent, per_s, dropped, stale, steps, missed, p50, p99, mx, sim, err) in rows:
        table.add_row(rate, f"{sent:,}", f"{per_s:,.0f}", f"{dropped:,}", f"{stale:,}", f"{steps:,}", f"{missed:,}",
                      f"{p50:.3f}", f"{p99:.3f}", f"{mx:.2f}", f"{sim:.3f}", f"{err * 1e3:.1f}")
    Console(width=200).print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
