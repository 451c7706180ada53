"""The one paced loop: a body run at a fixed rate against a clock, with its timing.

Live commands pace against :class:`sync.clock.RealClock` (sleeping to each deadline); headless runs
against a :class:`sync.clock.SimClock`, where waiting just moves simulated time on. The remote scene, the
twin's runtime and ``twin run`` all use :func:`run_loop`.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sync.clock import REAL_CLOCK, Clock
from twin.samples import Samples


@dataclass(frozen=True)
class LoopStats:
    """Timing of a paced loop, seconds of the loop's clock."""

    steps: int
    p50: float
    p99: float
    max: float
    missed: int
    wall: float


class Pacer:
    """Deadlines of a fixed-rate loop and the time each iteration's work took.

    ``begin()`` before the work, ``end()`` after it; ``end`` returns the seconds left until the next
    deadline (negative: the deadline was missed). The caller decides how to wait.
    """

    def __init__(self, rate: float, clock: Clock = REAL_CLOCK) -> None:
        self.period = 1.0 / rate
        self.clock = clock
        self.start = clock.now()
        self.iterations = 0
        self.missed = 0
        self.work = Samples()  # seconds each iteration's work took (a uniform subsample past a million)
        self._t0 = self.start

    def begin(self) -> None:
        self._t0 = self.clock.now()

    def end(self) -> float:
        t1 = self.clock.now()
        self.work.append(t1 - self._t0)
        self.iterations += 1
        left = self.start + self.iterations * self.period - t1
        if left < 0:
            self.missed += 1
        return left

    def stats(self) -> LoopStats:
        w = np.asarray(self.work) if self.work else np.zeros(1)
        return LoopStats(self.iterations, float(np.percentile(w, 50)), float(np.percentile(w, 99)), float(w.max()),
                         self.missed, self.clock.now() - self.start)


def run_loop(body: Callable[[], None], *, rate: float, duration: float, clock: Clock = REAL_CLOCK,
             until: Callable[[], bool] | None = None, wait: Callable[[float], None] | None = None) -> LoopStats:
    """Call ``body()`` ``rate`` times a second for ``duration`` seconds (or until ``until()`` is true).

    After each call the loop waits out the rest of the period: ``wait(seconds_left)`` if given (it must
    return by the deadline; the twin's runtime handles messages meanwhile), else ``clock.sleep``. A body
    that overruns its period counts as a missed deadline and the next one starts at once.
    """
    pacer = Pacer(rate, clock)
    sleep = clock.sleep if wait is None else wait
    n = round(duration * rate)
    switch = sys.getswitchinterval()
    if clock.realtime:
        # A thread that wants the GIL (a Zenoh callback carrying a pose) waits up to the switch interval,
        # 5 ms by default: five periods of a 1 kHz loop. A tenth of a period bounds that wait instead.
        sys.setswitchinterval(min(switch, pacer.period / 10))
    try:
        while pacer.iterations < n and not (until is not None and until()):
            pacer.begin()
            body()
            left = pacer.end()
            if left > 0:
                sleep(left)
    finally:
        sys.setswitchinterval(switch)
    return pacer.stats()
