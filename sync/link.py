"""One side's end of the link: publish encoded messages (counting bytes) and receive decoded ones.

Receiving is where bad input from the network stops: anything :func:`~sync.messages.decode` rejects is
dropped, counted and logged, never passed on and never raised into Zenoh's threads.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from sync.messages import Message, MessageError, decode, encode

log = logging.getLogger(__name__)

#: Malformed messages logged at WARNING before the rest go to DEBUG (a flood must not flood the log).
_WARN_LIMIT = 10


@dataclass
class LinkCounters:
    """What went over this side's link. Updated from Zenoh's threads; read them from anywhere."""

    messages_sent: int = 0
    bytes_sent: int = 0
    messages_received: int = 0
    bytes_received: int = 0
    dropped_malformed: int = 0
    last_received: float = 0.0  # time.monotonic() of the last good message, 0 if none


class Link:
    """Wraps a Zenoh session: :meth:`put` encodes and counts, :meth:`subscribe` decodes and filters."""

    def __init__(self, session) -> None:  # type: ignore[no-untyped-def]
        self.session = session
        self.counters = LinkCounters()
        self._lock = threading.Lock()
        self._handles: list[object] = []

    def put(self, key: str, msg: Message) -> bytes:
        """Publish ``msg`` on ``key``; returns the encoded bytes (for caching replies)."""
        data = encode(msg)
        self.put_bytes(key, data)
        return data

    def put_bytes(self, key: str, data: bytes) -> None:
        self.session.put(key, data)
        with self._lock:
            self.counters.messages_sent += 1
            self.counters.bytes_sent += len(data)

    def subscribe(self, key: str, handler: Callable[[str, Message], None]) -> None:
        """Call ``handler(key, message)`` for each good message on ``key`` (from a Zenoh thread)."""
        self._handles.append(self.session.declare_subscriber(key, lambda s: self.receive(str(s.key_expr),
                                                                                          s.payload.to_bytes(),
                                                                                          handler)))

    def queryable(self, key: str, answer: Callable[[str], list[tuple[str, bytes]]]) -> None:
        """Answer queries on ``key`` with the (key, encoded bytes) pairs ``answer(selector key)`` returns."""

        def on_query(query) -> None:  # type: ignore[no-untyped-def]
            try:
                for reply_key, data in answer(str(query.key_expr)):
                    query.reply(reply_key, data)
                    with self._lock:
                        self.counters.messages_sent += 1
                        self.counters.bytes_sent += len(data)
            except Exception:  # a failing answer must not kill Zenoh's thread; the querier times out
                log.exception("answering a query on %s failed", key)

        self._handles.append(self.session.declare_queryable(key, on_query))

    def query(self, selector: str, handler: Callable[[str, Message], None], timeout: float = 2.0) -> int:
        """Ask ``selector``; each good reply goes to ``handler``. Returns the number of good replies."""
        good = 0
        for reply in self.session.get(selector, timeout=timeout):
            if reply.ok is None:
                continue
            if self.receive(str(reply.ok.key_expr), reply.ok.payload.to_bytes(), handler):
                good += 1
        return good

    def receive(self, key: str, data: bytes, handler: Callable[[str, Message], None]) -> bool:
        """Decode and hand over one payload; malformed ones are dropped and counted. True if handled."""
        try:
            msg = decode(data)
        except MessageError as exc:
            with self._lock:
                self.counters.dropped_malformed += 1
                n = self.counters.dropped_malformed
            (log.warning if n <= _WARN_LIMIT else log.debug)("dropped malformed message on %s: %s", key, exc)
            return False
        with self._lock:
            self.counters.messages_received += 1
            self.counters.bytes_received += len(data)
            self.counters.last_received = time.monotonic()
        try:
            handler(key, msg)
        except Exception:  # the handler's bug must not become Zenoh's crash
            log.exception("handling a message on %s failed", key)
        return True

    def close(self) -> None:
        for h in self._handles:
            try:
                h.undeclare()  # type: ignore[attr-defined]
            except Exception:  # already closed with the session
                pass
        self._handles.clear()
