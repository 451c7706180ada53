"""Budgets that a flood of input cannot overrun: log lines (:class:`RateLimitedLog`) and answers
(:class:`TokenBucket`).

:class:`RateLimitedLog`: each reason (``"non-finite"``, ``"wrong-key"``, ``"out-of-scene"``, ...) has its own budget: the first
``burst`` go to WARNING; after that, at most one WARNING per ``period`` seconds of the given clock, saying how
many of that reason were held back since the last one. Held-back lines go to DEBUG, so nothing is lost to
anyone who asks for it. One noisy reason never silences another.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass

from sync.clock import REAL_CLOCK, Clock


@dataclass
class _Budget:
    logged: int = 0
    held: int = 0  # held back since the last WARNING of this reason
    next_at: float = 0.0


class RateLimitedLog:
    """Per-reason rate limiting in front of a :class:`logging.Logger`; safe to call from any thread."""

    def __init__(self, logger: logging.Logger, clock: Clock = REAL_CLOCK, *, burst: int = 10,
                 period: float = 60.0) -> None:
        if burst < 1 or not period > 0:
            raise ValueError(f"burst must be >= 1 and period > 0, got {burst}, {period}")
        self.logger = logger
        self.clock = clock
        self.burst = burst
        self.period = period
        self._budgets: dict[str, _Budget] = {}
        self._lock = threading.Lock()

    def warning(self, reason: str, msg: str, *args: object, exc_info: bool = False) -> bool:
        """Log ``msg % args`` for ``reason`` at WARNING if its budget allows, else at DEBUG; with ``exc_info``,
        the exception being handled goes with it (its traceback), at whichever level.

        Returns:
            Whether it went out at WARNING.
        """
        now = self.clock.now()
        with self._lock:
            b = self._budgets.setdefault(reason, _Budget())
            loud = b.logged < self.burst or now >= b.next_at
            if loud:
                held, b.held = b.held, 0
                b.logged += 1
                if b.logged >= self.burst:
                    b.next_at = now + self.period
            else:
                b.held += 1
        if not loud:
            self.logger.debug(msg, *args, exc_info=exc_info)
        elif held:
            self.logger.warning(msg + " (%d more like it held back; see DEBUG)", *args, held, exc_info=exc_info)
        else:
            self.logger.warning(msg, *args, exc_info=exc_info)
        return loud


class TokenBucket:
    """At most ``burst`` events at once and ``rate`` per second of ``clock`` on average; safe from any thread.

    The remote answers a state query with every cloud it has (megabytes): without a budget, a peer asking in
    a loop turns the remote's uplink into a stream of clouds (``tests/test_security.py``).
    """

    def __init__(self, burst: int, rate: float, clock: Clock = REAL_CLOCK) -> None:
        if burst < 1 or not rate > 0:
            raise ValueError(f"burst must be >= 1 and rate > 0, got {burst}, {rate}")
        self.burst, self.rate, self.clock = burst, rate, clock
        self._tokens = float(burst)
        self._at = clock.now()
        self._lock = threading.Lock()

    def take(self) -> bool:
        """Spend one token if there is one: whether the event may go ahead."""
        now = self.clock.now()
        with self._lock:
            self._tokens = min(self.burst, self._tokens + max(0.0, now - self._at) * self.rate)
            self._at = max(self._at, now)
            if self._tokens < 1:
                return False
            self._tokens -= 1
            return True
