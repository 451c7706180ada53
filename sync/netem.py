"""An emulated network link for the in-process transport: delay, jitter, loss, a bandwidth cap. Seeded.

This kernel has no ``netem``, so the emulation lives in the transport: :class:`sync.inprocess.InProcessBus`
asks a :class:`LinkModel` when (and whether) each publication arrives, and hands it over at that time of
its clock. One model per direction; each has its own random generator, so a seed gives the same arrival
times every run, and changing one direction's conditions does not change the other's draws.

A packet (one publication to one receiving side, ``len(payload)`` bytes; keys and headers are not counted)
goes through, in order:

1. **The bandwidth cap** (``rate_bps``): a FIFO queue in front of a transmitter that sends
   ``8 * size / rate_bps`` seconds per packet. With ``queue_bytes``, a packet that would make the backlog
   (bytes queued and not yet sent) exceed it is dropped at the tail.
2. **Loss**: independent (``loss``) or bursty (``burst``, Gilbert-Elliott). A lost packet has still used
   the transmitter's time: it was sent, and lost further on.
3. **Propagation**: ``delay`` plus jitter, drawn from ``distribution``; ``delay`` is the mean one-way
   delay and ``jitter`` its standard deviation, whatever the distribution:

   - ``"normal"``: ``delay + jitter * N(0, 1)``, redrawn if below zero. Allowed only while
     ``jitter <= delay / 3``, so at most 0.13 % of draws are redrawn and the mean and spread stay what was
     asked (a wider normal truncated at zero would have a larger mean and a smaller spread than configured).
   - ``"exponential"``: ``delay - jitter + Exp(jitter)``: a fixed path delay plus a memoryless queueing
     delay, the usual model of waiting behind cross traffic; never below ``delay - jitter``, with a long
     right tail (p99 = ``delay + 3.6 * jitter``). Needs ``jitter <= delay``.

4. **Order** (``reorder``): by default a direction is FIFO, a packet never overtakes an earlier one (it is
   held until the one before it has arrived), as on the single TCP session Zenoh uses between remote and
   twin. Jitter then delays some packets beyond their draw when packets are closer together than the jitter.
   ``reorder=True`` lets each packet arrive at its own draw, as UDP might.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

import numpy as np

from estimation.errors import TwinError

#: Jitter distributions :class:`Conditions` accepts.
DISTRIBUTIONS = ("normal", "exponential")

#: A truncated normal keeps its configured mean and spread only if zero is this many sigmas below the mean.
NORMAL_SIGMAS = 3.0

#: Relative slack on the jitter limit: the limit is a float quotient (0.3 / 3 is 0.09999999999999999), and
#: jitter given as exactly delay / 3 must pass; a part in a billion is far below any timing that matters.
JITTER_LIMIT_SLACK = 1e-9

#: The longest one-way delay, seconds: an hour, as long as a replay runs (``sync.recording.MAX_REPLAY_SECONDS``),
#: beyond which nothing sent would arrive within the session; 1e308 s made an arrival time infinite and the
#: in-process transport's nanosecond clock an OverflowError.
MAX_DELAY_S = 3600.0

#: The slowest bandwidth cap, bit/s: below it one message's transmission time overflows the clock's
#: nanoseconds (1e-300 bit/s did); 1 bit/s is already no usable link.
MIN_RATE_BPS = 1.0

#: Network seeds: what numpy's SeedSequence takes, non-negative, kept to 64 bits.
MAX_SEED = 2**64 - 1


class ConditionsError(TwinError, ValueError):
    """Network conditions that cannot be emulated: negative delay, loss outside [0, 1], and the like."""


def _number(name: str, value: float, *, low: float = 0.0, high: float = math.inf, open_low: bool = False) -> float:
    """``value`` as a float, checked finite and in [low, high] (or (low, high]); else one line naming it."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):  # "0.05" from a file stays text, not 0.05
        raise ConditionsError(f"{name} must be a number, got {value!r}")
    x = float(value)
    below = x <= low if open_low else x < low
    if not math.isfinite(x) or below or x > high:
        bounds = f"{'(' if open_low else '['}{low:g}, {high:g}]"
        raise ConditionsError(f"{name} must be finite and in {bounds}, got {value!r}")
    return x


@dataclass(frozen=True)
class GilbertElliott:
    """Bursty loss: a two-state Markov chain, one transition per packet (drawn after its loss).

    In the good state a packet is lost with probability ``loss_good``, in the bad state with ``loss_bad``;
    ``p`` is the probability of going good -> bad, ``r`` bad -> good. The chain spends a fraction
    ``p / (p + r)`` of packets in the bad state, so the stationary loss rate is

        loss = (r * loss_good + p * loss_bad) / (p + r)

    and, with the default ``loss_bad = 1`` and ``loss_good = 0`` (the Gilbert model), losses come in bursts
    of mean length ``1 / r`` packets, ``1 / p`` packets apart on average. The chain starts in the good state.
    """

    p: float
    r: float
    loss_bad: float = 1.0
    loss_good: float = 0.0

    def __post_init__(self) -> None:
        _number("burst.p", self.p, high=1.0)
        _number("burst.r", self.r, high=1.0, open_low=True)  # r = 0: a bad state never left, no stationary rate
        _number("burst.loss_bad", self.loss_bad, high=1.0)
        _number("burst.loss_good", self.loss_good, high=1.0)

    @property
    def stationary_loss(self) -> float:
        """The long-run fraction of packets lost."""
        return (self.r * self.loss_good + self.p * self.loss_bad) / (self.p + self.r)


@dataclass(frozen=True)
class Conditions:
    """One direction's link, all optional. Seconds, bit/s and bytes; see the module docstring for the model.

    Args:
        delay: mean one-way delay, seconds, from 0 to :data:`MAX_DELAY_S`.
        jitter: standard deviation of the one-way delay, seconds, >= 0 (and within what ``distribution``
            allows: ``delay / 3`` for ``"normal"``, ``delay`` for ``"exponential"``).
        distribution: ``"normal"`` or ``"exponential"`` (only read when ``jitter > 0``).
        reorder: let packets overtake each other (default: FIFO, never).
        loss: probability that a packet is lost, independently of the others, in [0, 1].
        burst: bursty loss instead (give ``loss`` or ``burst``, not both).
        rate_bps: bandwidth cap, bit/s, >= :data:`MIN_RATE_BPS` (None: unlimited, no queueing).
        queue_bytes: tail-drop limit of the queue in front of the cap, bytes, >= 1 (None: unlimited).

    Raises:
        ConditionsError: a value outside its range or not finite, an unknown distribution, jitter beyond
            what the distribution allows, both ``loss`` and ``burst``, or ``queue_bytes`` without a cap.
    """

    delay: float = 0.0
    jitter: float = 0.0
    distribution: str = "normal"
    reorder: bool = False
    loss: float = 0.0
    burst: GilbertElliott | None = None
    rate_bps: float | None = None
    queue_bytes: int | None = None

    def __post_init__(self) -> None:
        delay = _number("delay", self.delay, high=MAX_DELAY_S)
        jitter = _number("jitter", self.jitter)
        if self.distribution not in DISTRIBUTIONS:
            raise ConditionsError(f"distribution must be one of {', '.join(DISTRIBUTIONS)}, got {self.distribution!r}")
        limit = delay / NORMAL_SIGMAS if self.distribution == "normal" else delay
        if jitter > limit * (1 + JITTER_LIMIT_SLACK):
            raise ConditionsError(f"jitter {jitter:g} s is more than {self.distribution} jitter allows with a "
                                  f"{delay:g} s delay (at most {limit:g} s)")
        _number("loss", self.loss, high=1.0)
        if not isinstance(self.reorder, bool):
            raise ConditionsError(f"reorder must be true or false, got {self.reorder!r}")
        if self.burst is not None and not isinstance(self.burst, GilbertElliott):
            raise ConditionsError(f"burst must be a Gilbert-Elliott model, got {self.burst!r}")
        if self.burst is not None and self.loss > 0:
            raise ConditionsError("loss and burst both given: choose independent or bursty loss")
        if self.rate_bps is not None:
            _number("rate_bps", self.rate_bps, low=MIN_RATE_BPS)
        if self.queue_bytes is not None:
            if self.rate_bps is None:
                raise ConditionsError("queue_bytes needs rate_bps: without a cap nothing queues")
            _number("queue_bytes", self.queue_bytes, low=1.0)

    @property
    def expected_loss(self) -> float:
        """The long-run fraction of packets lost (not counting tail drops)."""
        return self.burst.stationary_loss if self.burst is not None else self.loss


@dataclass(frozen=True)
class Network:
    """Conditions for both directions of a remote-twin session, and the seed of their random draws.

    ``downlink`` carries the remote's messages to the twin (clouds, poses, heartbeats), ``uplink`` the
    twin's operator commands to the remote. None: that direction delivers at once.
    """

    uplink: Conditions | None = None
    downlink: Conditions | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.seed, bool) or not isinstance(self.seed, numbers.Integral) or not 0 <= self.seed <= MAX_SEED:
            raise ConditionsError(f"seed must be an integer in [0, {MAX_SEED}], got {self.seed!r}")

    def models(self) -> tuple[LinkModel | None, LinkModel | None]:
        """(uplink, downlink) models, each with its own generator spawned from ``seed``."""
        up, down = np.random.SeedSequence(self.seed).spawn(2)
        return (None if self.uplink is None else LinkModel(self.uplink, np.random.default_rng(up)),
                None if self.downlink is None else LinkModel(self.downlink, np.random.default_rng(down)))


@dataclass
class LinkStats:
    """What one direction did. Seconds and bytes."""

    sent: int = 0  # packets offered to the link
    delivered: int = 0  # packets given an arrival time (the bus counts them when due)
    lost: int = 0  # by loss, independent or bursty
    dropped: int = 0  # at the tail of a full queue
    bytes_sent: int = 0
    bytes_delivered: int = 0
    queue_delay: float = 0.0  # total time delivered packets waited for the transmitter
    delay_total: float = 0.0  # total one-way time of delivered packets, queue and propagation included
    delay_max: float = 0.0

    @property
    def mean_delay(self) -> float:
        return self.delay_total / self.delivered if self.delivered else math.nan

    @property
    def mean_queue_delay(self) -> float:
        return self.queue_delay / self.delivered if self.delivered else math.nan


@dataclass
class LinkModel:
    """One direction of an emulated link: :meth:`send` says when a packet arrives, or that it does not.

    Args:
        conditions: the link.
        rng: its own generator (see :meth:`Network.models`); a model is deterministic given it.
    """

    conditions: Conditions
    rng: np.random.Generator
    stats: LinkStats = field(default_factory=LinkStats)
    _busy_until: float = -math.inf  # when the transmitter finishes the last packet queued
    _last_arrival: float = -math.inf
    _bad: bool = False  # Gilbert-Elliott state

    def send(self, t: float, size: int) -> float | None:
        """A packet of ``size`` bytes offered at time ``t`` (seconds, non-decreasing between calls).

        Returns:
            Its arrival time in seconds, or None if it is lost or dropped.
        """
        c, s = self.conditions, self.stats
        s.sent += 1
        s.bytes_sent += size
        start = t
        if c.rate_bps is not None:
            start = max(t, self._busy_until)
            backlog = (start - t) * c.rate_bps / 8.0  # bytes the transmitter has yet to send
            if c.queue_bytes is not None and backlog + size > c.queue_bytes:
                s.dropped += 1
                return None
            self._busy_until = start + 8.0 * size / c.rate_bps
            leaves = self._busy_until
        else:
            leaves = t
        if self._lost():
            s.lost += 1
            return None
        arrival = leaves + self._propagation()
        if not c.reorder:
            arrival = max(arrival, self._last_arrival)
            self._last_arrival = arrival
        s.delivered += 1
        s.bytes_delivered += size
        s.queue_delay += start - t
        s.delay_total += arrival - t
        s.delay_max = max(s.delay_max, arrival - t)
        return arrival

    def _lost(self) -> bool:
        c = self.conditions
        if c.burst is None:
            return c.loss > 0 and bool(self.rng.random() < c.loss)
        g = c.burst
        lost = bool(self.rng.random() < (g.loss_bad if self._bad else g.loss_good))
        self._bad = bool(self.rng.random() < (1.0 - g.r if self._bad else g.p))
        return lost

    def _propagation(self) -> float:
        c = self.conditions
        if c.jitter == 0:
            return c.delay
        if c.distribution == "exponential":
            return c.delay - c.jitter + float(self.rng.exponential(c.jitter))
        while True:  # normal, redrawn below zero (rare: jitter <= delay / 3)
            d = c.delay + c.jitter * float(self.rng.standard_normal())
            if d >= 0:
                return d
