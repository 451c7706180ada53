"""The emulated link, configured vs measured: mean and p99 one-way delay, loss, throughput.

    .venv/bin/python bench/netem.py [--seconds 60] [--rate 1000] [--size 200] [--seed 0]

Each condition gets the traffic of a remote publishing poses: ``--size``-byte packets ``--rate`` times a
second (1.6 Mbit/s by default) for ``--seconds`` of simulated time, through one
:class:`sync.netem.LinkModel`. "Expected" is the closed form for the configuration (mean and p99 of the
delay distribution, the stationary loss rate, min(offered, cap)); "-" where none applies: FIFO order
holds a packet behind a later-drawn earlier one, so FIFO rows measure more than the distribution's own
mean and p99, which is the cost of never reordering; a saturated cap's delay is the full queue's, and
its loss column counts tail drops (in the long run, the offered load beyond the cap). Measured
throughput is delivered bits over the time from the first send to the last arrival.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages, not an installed copy

from sync.netem import Conditions, GilbertElliott, LinkModel

Z99 = 2.3263  # standard normal 99th percentile

CONDITIONS: list[tuple[str, Conditions]] = [
    ("10 ms", Conditions(delay=0.010)),
    ("50 ms ± 10 normal, reorder", Conditions(delay=0.050, jitter=0.010, reorder=True)),
    ("50 ms ± 10 normal, FIFO", Conditions(delay=0.050, jitter=0.010)),
    ("50 ms ± 15 exponential, reorder", Conditions(delay=0.050, jitter=0.015, distribution="exponential",
                                                   reorder=True)),
    ("25 ms, 2 % loss", Conditions(delay=0.025, loss=0.02)),
    ("25 ms, GE p=0.01 r=0.25", Conditions(delay=0.025, burst=GilbertElliott(p=0.01, r=0.25))),
    ("10 ms, cap 2 Mbit/s", Conditions(delay=0.010, rate_bps=2e6)),
    ("10 ms, cap 1 Mbit/s, 20 kB queue", Conditions(delay=0.010, rate_bps=1e6, queue_bytes=20_000)),
]


def expected(c: Conditions, offered_bps: float, size: int) -> tuple[float | None, float | None, float, float]:
    """(mean delay s, p99 delay s, loss fraction, throughput bit/s) from the configuration alone."""
    loss = c.expected_loss
    throughput = offered_bps * (1 - loss) if c.rate_bps is None else min(offered_bps, c.rate_bps) * (1 - loss)
    if c.rate_bps is not None and offered_bps >= c.rate_bps:
        # Saturated: with a finite queue, the excess is dropped at the tail in the long run.
        dropped = 1 - c.rate_bps / offered_bps if c.queue_bytes is not None else 0.0
        return None, None, 1 - (1 - loss) * (1 - dropped), throughput
    serialise = 0.0 if c.rate_bps is None else 8 * size / c.rate_bps
    if c.jitter == 0:
        return c.delay + serialise, c.delay + serialise, loss, throughput
    if not c.reorder:
        return None, None, loss, throughput
    if c.distribution == "normal":
        return c.delay, c.delay + Z99 * c.jitter, loss, throughput
    return c.delay, c.delay + (math.log(100) - 1) * c.jitter, loss, throughput


def measure(c: Conditions, *, seconds: float, rate: float, size: int, seed: int) -> tuple[float, float, float, float]:
    """(mean delay s, p99 delay s, loss fraction, throughput bit/s) of the traffic through one model."""
    model = LinkModel(c, np.random.default_rng(seed))
    sent = np.arange(round(seconds * rate)) / rate
    arrived = np.array([np.nan if (a := model.send(t, size)) is None else a for t in sent])
    ok = ~np.isnan(arrived)
    delay = (arrived - sent)[ok]
    span = arrived[ok].max() - sent[0]
    return float(delay.mean()), float(np.percentile(delay, 99)), 1 - ok.mean(), ok.sum() * size * 8 / span


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="simulated seconds of traffic a condition")
    parser.add_argument("--rate", type=float, default=1000.0, help="packets a second")
    parser.add_argument("--size", type=int, default=200, help="bytes a packet")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    offered = args.rate * args.size * 8

    def ms(x: float | None) -> str:
        return "-" if x is None else f"{x * 1e3:.2f}"

    table = Table(title=f"{args.size} B packets at {args.rate:g}/s ({offered / 1e6:g} Mbit/s offered), "
                        f"{args.seconds:g} s simulated, seed {args.seed}: expected / measured")
    for col in ("condition", "mean ms", "p99 ms", "loss %", "throughput Mbit/s"):
        table.add_column(col, justify="left" if col == "condition" else "right")
    for name, c in CONDITIONS:
        e_mean, e_p99, e_loss, e_tp = expected(c, offered, args.size)
        m_mean, m_p99, m_loss, m_tp = measure(c, seconds=args.seconds, rate=args.rate, size=args.size, seed=args.seed)
        table.add_row(name, f"{ms(e_mean)} / {ms(m_mean)}", f"{ms(e_p99)} / {ms(m_p99)}",
                      f"{e_loss * 100:.2f} / {m_loss * 100:.2f}", f"{e_tp / 1e6:.3f} / {m_tp / 1e6:.3f}")
    Console(width=130).print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
