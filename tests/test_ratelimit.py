"""Rate-limited warnings: a flood of one bad input is a few log lines; another reason still gets through."""

from __future__ import annotations

import logging

import pytest

from sync.clock import SimClock
from sync.inprocess import InProcessBus
from sync.link import Link
from sync.ratelimit import RateLimitedLog

LOGGER = "tests.ratelimit"


def _warnings(caplog) -> list[str]:  # type: ignore[no-untyped-def]
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]


def test_a_burst_then_one_a_period_with_the_count_held_back(caplog):
    clock = SimClock()
    rl = RateLimitedLog(logging.getLogger(LOGGER), clock, burst=3, period=10.0)
    with caplog.at_level(logging.DEBUG, logger=LOGGER):
        loud = [rl.warning("nan", "bad %d", i) for i in range(100)]
        assert loud == [True] * 3 + [False] * 97
        clock.advance(10.0)
        assert rl.warning("nan", "bad %d", 100)
        assert not rl.warning("nan", "bad %d", 101)  # the next period has begun
    assert _warnings(caplog) == ["bad 0", "bad 1", "bad 2", "bad 100 (97 more like it held back; see DEBUG)"]
    debug = [r.getMessage() for r in caplog.records if r.levelno == logging.DEBUG]
    assert len(debug) == 98 and debug[0] == "bad 3" and debug[-1] == "bad 101"  # nothing lost at DEBUG


def test_one_noisy_reason_does_not_silence_another(caplog):
    rl = RateLimitedLog(logging.getLogger(LOGGER), SimClock(), burst=2, period=60.0)
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        for _ in range(50):
            rl.warning("flood", "flood")
        assert rl.warning("rare", "rare one")
    assert _warnings(caplog) == ["flood", "flood", "rare one"]


@pytest.mark.parametrize(("burst", "period"), [(0, 1.0), (1, 0.0), (1, float("nan"))])
def test_a_budget_that_logs_nothing_is_refused(burst, period):
    with pytest.raises(ValueError, match="burst must be >= 1 and period > 0"):
        RateLimitedLog(logging.getLogger(LOGGER), burst=burst, period=period)


def test_a_flood_of_malformed_messages_is_counted_in_full_and_logged_in_part(caplog):
    clock = SimClock()
    bus = InProcessBus()
    link = Link(bus.transport(), clock)
    got = []
    link.subscribe("twin/s/**", lambda key, msg: got.append(msg))
    sender = bus.transport()
    with caplog.at_level(logging.WARNING, logger="sync.link"):
        for _ in range(1000):
            sender.put("twin/s/objects/a/pose", b"\x00garbage")
        sender.put("twin/s/objects/a/pose", b"")
    assert got == []
    assert link.counters.dropped_malformed == 1001
    reasons = link.counters.dropped_by_reason
    assert sum(reasons.values()) == 1001 and len(reasons) >= 1
    lines = _warnings(caplog)
    # Each reason's first burst, no more: a thousand bad messages are a handful of lines.
    assert len(lines) <= link.dropped_log.burst * len(reasons)
    assert all(line.startswith("dropped malformed message on twin/s/objects/a/pose") for line in lines)
