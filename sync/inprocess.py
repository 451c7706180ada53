"""A transport inside one process: remote and twin on one bus, no sockets, driven by the caller's clock.

What a Zenoh session does between processes, done with function calls: a publication is handed to every
matching subscriber, a query to every intersecting queryable, synchronously and in declaration order. With
one thread stepping both sides on a :class:`sync.clock.SimClock`, a session is deterministic: the same
inputs give the same messages in the same order, so a headless run can be repeated bit for bit.

An emulated network (:mod:`sync.netem`) sits between named transports: give the bus a clock and a
:class:`sync.netem.LinkModel` per (sender name, receiver name). A publication over such a pair is then
scheduled, not delivered: :meth:`InProcessBus.deliver_due` hands over, in arrival order, everything due by
the clock's ``now()``; the caller pumps it (:class:`scenes.headless.Headless` does so at the start of each
tick, before either side steps, so a message is handled on the first step at or after its arrival).
Pairs without a model still deliver at once. Queries are never delayed: a query is the late joiner's
handshake and :meth:`InProcessTransport.get` returns its replies synchronously (a delayed reply would need
the asker to pump the clock while it waits, which nothing in a headless run does).
"""

from __future__ import annotations

import heapq
from collections.abc import Mapping

from sync.clock import Clock
from sync.keys import intersects
from sync.netem import LinkModel
from sync.transport import Answer, OnSample


class InProcessBus:
    """The shared medium. Make one per headless session and a :meth:`transport` per side.

    Args:
        clock: the time scheduled deliveries are due on; needed with ``links``.
        links: ``{(sender, receiver): model}``, transport names as given to :meth:`transport`. A pair not
            listed delivers at once.

    Raises:
        ValueError: ``links`` without a ``clock``.
    """

    def __init__(self, clock: Clock | None = None, links: Mapping[tuple[str, str], LinkModel] | None = None) -> None:
        if links and clock is None:
            raise ValueError("an InProcessBus with links needs a clock to schedule deliveries on")
        self.clock = clock
        self.links = dict(links or {})
        self._subscribers: list[tuple[InProcessTransport, str, OnSample]] = []
        self._queryables: list[tuple[InProcessTransport, str, Answer]] = []
        # (due ns, order of scheduling, receiver, key, payload, callbacks): a heap, earliest first
        self._pending: list[tuple[int, int, InProcessTransport, str, bytes, list[OnSample]]] = []
        self._scheduled = 0
        self.published = 0  # publications put on the bus
        self.bytes = 0

    def transport(self, name: str = "") -> InProcessTransport:
        """A new side on the bus; ``name`` picks its links (a nameless side has none)."""
        return InProcessTransport(self, name)

    @property
    def in_flight(self) -> int:
        """Packets scheduled and not yet delivered."""
        return len(self._pending)

    def deliver_due(self) -> int:
        """Hand every scheduled publication due by ``clock.now()`` to its subscribers, earliest first.

        Returns:
            The number of packets delivered (a packet: one publication to one receiving transport).
        """
        if not self._pending:
            return 0
        assert self.clock is not None
        now, delivered = _ns(self.clock.now()), 0
        while self._pending and self._pending[0][0] <= now:
            _, _, receiver, key, data, callbacks = heapq.heappop(self._pending)
            if receiver.closed:
                continue
            delivered += 1
            for callback in callbacks:
                callback(key, data)
        return delivered

    def _put(self, sender: InProcessTransport, key: str, data: bytes) -> None:
        self.published += 1
        self.bytes += len(data)
        held: dict[int, tuple[InProcessTransport, list[OnSample]]] = {}  # receiver id -> its callbacks
        for owner, expr, callback in list(self._subscribers):
            if not intersects(expr, key):
                continue
            if (sender.name, owner.name) in self.links:
                held.setdefault(id(owner), (owner, []))[1].append(callback)
            else:
                callback(key, data)
        for owner, callbacks in held.values():  # one packet per receiving side, however many subscriptions
            self._schedule(sender, owner, key, data, callbacks)

    def _schedule(self, sender: InProcessTransport, receiver: InProcessTransport, key: str, data: bytes,
                  callbacks: list[OnSample]) -> None:
        assert self.clock is not None
        arrival = self.links[sender.name, receiver.name].send(self.clock.now(), len(data))
        if arrival is None:
            return
        self._scheduled += 1
        heapq.heappush(self._pending, (_ns(arrival), self._scheduled, receiver, key, data, callbacks))

    def _get(self, selector: str) -> list[tuple[str, bytes]]:
        replies: list[tuple[str, bytes]] = []
        for _, expr, answer in list(self._queryables):
            if intersects(expr, selector):
                replies.extend((k, d) for k, d in answer(selector) if intersects(selector, k))
        return replies

    def _close(self, owner: InProcessTransport) -> None:
        owner.closed = True
        self._subscribers = [s for s in self._subscribers if s[0] is not owner]
        self._queryables = [q for q in self._queryables if q[0] is not owner]


def _ns(t: float) -> int:
    """Seconds to whole nanoseconds, as :meth:`sync.clock.SimClock.stamp_ns` rounds: a packet due at
    ``t + 0.05`` is due at the tick whose clock reads ``t + 0.05``, whatever float sums made the two."""
    return round(t * 1e9)


class InProcessTransport:
    """One side's :class:`sync.transport.Transport` on an :class:`InProcessBus`."""

    def __init__(self, bus: InProcessBus, name: str = "") -> None:
        self.bus = bus
        self.name = name
        self.closed = False

    def put(self, key: str, data: bytes) -> None:
        self.bus._put(self, key, bytes(data))

    def subscribe(self, keyexpr: str, callback: OnSample) -> None:
        self.bus._subscribers.append((self, keyexpr, callback))

    def queryable(self, keyexpr: str, answer: Answer) -> None:
        self.bus._queryables.append((self, keyexpr, answer))

    def get(self, selector: str, timeout: float) -> list[tuple[str, bytes]]:
        """Replies at once, never delayed by a link: everything in this process answers synchronously
        (``timeout`` is not needed)."""
        return self.bus._get(selector)

    def close(self) -> None:
        self.bus._close(self)
