"""Time, as one object every loop, link and runtime reads: real for live runs, simulated for headless ones.

Nothing in the runtime calls ``time`` directly: it asks its clock. :class:`RealClock` is the machine's
clock; :class:`SimClock` stands still until someone advances it (a headless driver after each step, or a
paced loop's wait), so a whole session of remote and twin can run faster than real time and give the same
result every time.
"""

from __future__ import annotations

import math
import time
from typing import Protocol

from estimation.errors import SettingsError


class Clock(Protocol):
    """What the runtime needs of time.

    ``now()`` is monotonic seconds (for rates, deadlines, staleness); ``stamp_ns()`` is the sender's wall
    time in nanoseconds written into messages (latency across machines needs synchronised clocks);
    ``sleep(s)`` waits (a simulated clock just moves on); ``realtime`` says whether waiting takes real time.
    """

    realtime: bool

    def now(self) -> float: ...

    def stamp_ns(self) -> int: ...

    def sleep(self, seconds: float) -> None: ...


class RealClock:
    """The machine's clock: ``time.perf_counter`` for intervals, ``time.time_ns`` for stamps."""

    realtime = True

    def now(self) -> float:
        return time.perf_counter()

    def stamp_ns(self) -> int:
        return time.time_ns()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


class SimClock:
    """A clock that moves only when told: ``advance(dt)`` or ``sleep(dt)``. Starts at ``start`` seconds.

    Stamps are the simulated time in nanoseconds, so message latencies in a headless run are simulated
    latencies (zero unless an emulated network delays the message).
    """

    realtime = False

    def __init__(self, start: float = 0.0) -> None:
        self._t = _seconds(start, "start")

    def now(self) -> float:
        return self._t

    def stamp_ns(self) -> int:
        return round(self._t * 1e9)

    def sleep(self, seconds: float) -> None:
        if _seconds(seconds, "sleep") > 0:
            self._t += seconds

    def advance(self, seconds: float) -> None:
        """Move time forward by ``seconds`` (>= 0)."""
        if _seconds(seconds, "advance") < 0:
            raise SettingsError(f"a clock does not go back ({seconds} s)")
        self._t += seconds

    def advance_to(self, t: float) -> None:
        """Move time forward to ``t`` seconds (no-op if already past it)."""
        self._t = max(self._t, _seconds(t, "advance_to"))


def _seconds(value: float, what: str) -> float:
    """``value`` as seconds: a finite number (NaN or infinity would stop a simulated clock for good).

    Raises:
        SettingsError: naming ``what``.
    """
    from estimation.contracts import check_number  # numpy: not at import, which the CLI's start pays for

    return check_number(value, f"simulated clock {what}: seconds", low=-math.inf, error=SettingsError)


#: The clock of live commands.
REAL_CLOCK = RealClock()
