"""A transport inside one process: remote and twin on one bus, no sockets, driven by the caller's clock.

What a Zenoh session does between processes, done with function calls: a publication is handed to every
matching subscriber, a query to every intersecting queryable, synchronously and in declaration order. With
one thread stepping both sides on a :class:`sync.clock.SimClock`, a session is deterministic: the same
inputs give the same messages in the same order, so a headless run can be repeated bit for bit.
"""

from __future__ import annotations

from sync.keys import intersects
from sync.transport import Answer, OnSample


class InProcessBus:
    """The shared medium. Make one per headless session and a :meth:`transport` per side."""

    def __init__(self) -> None:
        self._subscribers: list[tuple[InProcessTransport, str, OnSample]] = []
        self._queryables: list[tuple[InProcessTransport, str, Answer]] = []
        self.published = 0  # publications put on the bus
        self.bytes = 0

    def transport(self) -> InProcessTransport:
        return InProcessTransport(self)

    def _put(self, key: str, data: bytes) -> None:
        self.published += 1
        self.bytes += len(data)
        for _, expr, callback in list(self._subscribers):
            if intersects(expr, key):
                callback(key, data)

    def _get(self, selector: str) -> list[tuple[str, bytes]]:
        replies: list[tuple[str, bytes]] = []
        for _, expr, answer in list(self._queryables):
            if intersects(expr, selector):
                replies.extend((k, d) for k, d in answer(selector) if intersects(selector, k))
        return replies

    def _close(self, owner: InProcessTransport) -> None:
        self._subscribers = [s for s in self._subscribers if s[0] is not owner]
        self._queryables = [q for q in self._queryables if q[0] is not owner]


class InProcessTransport:
    """One side's :class:`sync.transport.Transport` on an :class:`InProcessBus`."""

    def __init__(self, bus: InProcessBus) -> None:
        self.bus = bus

    def put(self, key: str, data: bytes) -> None:
        self.bus._put(key, bytes(data))

    def subscribe(self, keyexpr: str, callback: OnSample) -> None:
        self.bus._subscribers.append((self, keyexpr, callback))

    def queryable(self, keyexpr: str, answer: Answer) -> None:
        self.bus._queryables.append((self, keyexpr, answer))

    def get(self, selector: str, timeout: float) -> list[tuple[str, bytes]]:
        """Replies at once: everything in this process answers synchronously (``timeout`` is not needed)."""
        return self.bus._get(selector)

    def close(self) -> None:
        self.bus._close(self)
