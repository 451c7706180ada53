"""The one paced loop: a body run at a fixed rate against a clock, with its timing.

Live commands pace against :class:`sync.clock.RealClock` (sleeping to each deadline); headless runs
against a :class:`sync.clock.SimClock`, where waiting just moves simulated time on. The remote scene, the
twin's runtime and ``twin run`` all use :func:`run_loop`, and take their physics steps per iteration from
:func:`steps_per_iteration`: one rule, so a loop's ``duration`` is simulated seconds and its pacing real.
"""

from __future__ import annotations

import math
import numbers
import sys
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from estimation.contracts import shown
from estimation.errors import TwinError
from sync.clock import REAL_CLOCK, Clock
from twin.samples import Samples

#: How far (relative) a rate may be from a whole number of physics steps per iteration and still be taken as
#: that rate: the rates :func:`steps_per_iteration` names are printed to 6 significant digits (333.333 Hz
#: is 1000/3 Hz within 1e-6). The loop then paces at the exact rate, so this never drifts from real time.
RATE_TOLERANCE = 1e-5


class LoopError(TwinError, ValueError):
    """A loop rate or duration no loop can run: not a number, not finite, not positive, or a rate that is not
    a whole number of physics steps per iteration."""


def check_duration(duration: object) -> float:
    """``duration`` as a float, seconds, if it is a finite number at least 0.

    Raises:
        LoopError: not a real number (a string, a bool), not finite, or negative.
    """
    if isinstance(duration, bool) or not isinstance(duration, numbers.Real):
        raise LoopError(f"duration must be a number of seconds, got {duration!r}")
    value = _float(duration)
    if not math.isfinite(value) or value < 0:
        raise LoopError(f"duration must be a finite number of seconds, at least 0, got {_said(duration, value)}")
    return value


def check_rate(rate: object) -> float:
    """``rate`` as a float, Hz, if it is a finite number above 0.

    Raises:
        LoopError: not a real number, not finite, or not above 0.
    """
    if isinstance(rate, bool) or not isinstance(rate, numbers.Real):
        raise LoopError(f"rate must be a number of Hz, got {rate!r}")
    value = _float(rate)
    if not math.isfinite(value) or value <= 0:
        raise LoopError(f"rate must be a finite number of Hz above 0, got {_said(rate, value)}")
    return value


def _float(value: numbers.Real) -> float:
    """``value`` as a float; inf for an integer past the float range (``float(10**400)`` raises OverflowError)."""
    try:
        return float(value)
    except OverflowError:
        return math.inf if value > 0 else -math.inf


def _said(value: object, number: float) -> str:
    """How a refused ``value`` (``number`` as a float) is shown: ``:g``, or a huge integer by its size."""
    return shown(value) if math.isinf(number) and isinstance(value, numbers.Integral) else f"{number:g}"


def steps_per_iteration(rate: float, timestep: float) -> tuple[float, int]:
    """The physics steps of ``timestep`` seconds each iteration of a ``rate`` Hz loop takes, and the exact rate.

    An iteration must cover a whole number k of steps, so the rate is 1 / (k * timestep): 1000, 500, 333.333,
    250 ... Hz at 1 ms. Any other rate would simulate more or less than the loop's duration, and run faster or
    slower than the wall clock when paced (3000 Hz stepping 1 ms per iteration ran 3 s of physics a second).

    Args:
        rate: iterations per second, Hz.
        timestep: the model's physics step, seconds.

    Returns:
        ``(exact_rate, k)``: the rate to pace at (``rate`` within :data:`RATE_TOLERANCE`) and the steps per
        iteration.

    Raises:
        LoopError: a rate that is not a finite number above 0, or not 1 / (k * timestep) for a whole k >= 1.
    """
    rate = check_rate(rate)
    physics = 1.0 / timestep
    steps = physics / rate
    if not math.isfinite(steps):  # 1e-320 Hz: no whole number of steps
        raise LoopError(f"rate {rate:g} Hz is too slow for any loop (an iteration would take for ever)")
    k = max(1, round(steps))
    if abs(k - steps) <= RATE_TOLERANCE * k:
        return physics / k, k
    works = ", ".join(f"{physics / j:.6g}" for j in range(1, 5))
    step = f"{timestep * 1e3:g} ms" if timestep < 1 else f"{timestep:g} s"
    if steps < 1:
        raise LoopError(f"rate {rate:g} Hz is faster than the physics: an iteration takes at least one {step} step, "
                        f"so {physics:.6g} Hz at most; the rates that work are {physics:.6g} Hz divided by a whole "
                        f"number ({works}, ...)")
    low, high = physics / math.ceil(steps), physics / math.floor(steps)
    raise LoopError(f"rate {rate:g} Hz is not a whole number of {step} physics steps per iteration: use "
                    f"{physics:.6g} Hz divided by a whole number ({works}, ...); the nearest are {high:.6g} and {low:.6g} Hz")


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

    The loop runs ``round(duration * rate)`` iterations: a loop stepping physics takes its rate from
    :func:`steps_per_iteration`, so that is ``duration`` simulated seconds to a whole iteration.

    After each call the loop waits out the rest of the period: ``wait(seconds_left)`` if given (it must
    return by the deadline; the twin's runtime handles messages meanwhile), else ``clock.sleep``. A body
    that overruns its period counts as a missed deadline and the next one starts at once.

    Raises:
        LoopError: a rate or duration that is not a finite number (a duration at least 0, a rate above 0), or a
            duration above 0 that is shorter than half an iteration (it would run none).
    """
    rate, duration = check_rate(rate), check_duration(duration)
    n = round(duration * rate)
    if n == 0 and duration > 0:
        raise LoopError(f"duration {duration:g} s is shorter than one iteration at {rate:g} Hz "
                        f"({1 / rate:g} s each): nothing would run")
    pacer = Pacer(rate, clock)
    sleep = clock.sleep if wait is None else wait
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
