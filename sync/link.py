"""One side's end of the wire: publish encoded messages (counting bytes), receive checked ones.

Receiving is where bad input from the network stops: anything :func:`~sync.messages.decode` rejects, and
any message on a key that is not its own (:func:`sync.keys.carried_by`: another type's key, another object's
or scene's, a key deeper or shallower than the layout's), is dropped, counted per reason and logged,
rate-limited per reason (:class:`~sync.ratelimit.RateLimitedLog`), never passed on and never raised into the
transport's threads.
"""

from __future__ import annotations

import logging
import threading
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

from sync.clock import REAL_CLOCK, Clock
from sync.keys import carried_by
from sync.messages import Message, MessageError, SceneInfo, decode, encode
from sync.ratelimit import RateLimitedLog, TokenBucket
from sync.transport import Transport

log = logging.getLogger(__name__)

#: Characters of a key a log line shows.
_KEY_LOGGED = 200

Handler = Callable[[str, Message], None]


@dataclass
class LinkCounters:
    """What went over this side's link. Updated from the transport's threads; read them from anywhere."""

    messages_sent: int = 0
    bytes_sent: int = 0
    messages_received: int = 0
    bytes_received: int = 0
    dropped_malformed: int = 0  # every message dropped: decode's reasons, and the receiver's (see Link.dropped)
    dropped_by_reason: Counter = field(default_factory=Counter)
    last_received: float | None = None  # clock.now() of the last good message
    queries_refused: int = 0  # queries answered with nothing: past the queryable's budget


class Link:
    """Messages over a :class:`~sync.transport.Transport`: :meth:`put` encodes and counts,
    :meth:`subscribe` and :meth:`query` decode, check and count."""

    def __init__(self, transport: Transport, clock: Clock = REAL_CLOCK) -> None:
        self.transport = transport
        self.clock = clock
        self.counters = LinkCounters()
        self.dropped_log = RateLimitedLog(log, clock)  # a flood of bad messages must not flood the log
        self._lock = threading.Lock()

    def put(self, key: str, msg: Message) -> bytes:
        """Publish ``msg`` on ``key``; returns the encoded bytes (for caching replies)."""
        data = encode(msg)
        self.transport.put(key, data)
        self._sent(data)
        return data

    def subscribe(self, key: str, handler: Handler) -> None:
        """Call ``handler(key, message)`` for each good message on ``key`` (from the transport's thread)."""
        self.transport.subscribe(key, lambda k, data: self.receive(k, data, handler))

    def queryable(self, key: str, answer: Callable[[str], list[tuple[str, bytes]]],
                  budget: TokenBucket | None = None) -> None:
        """Answer queries on ``key`` with the (key, encoded bytes) pairs ``answer(selector)`` returns; past
        ``budget``, with nothing (the asker times out; counted in :attr:`LinkCounters.queries_refused`)."""

        def counted(selector: str) -> list[tuple[str, bytes]]:
            if budget is not None and not budget.take():
                with self._lock:
                    self.counters.queries_refused += 1
                self.dropped_log.warning("query-over-budget", "query on %s refused: more than %d at once or "
                                         "%g per second", selector[:_KEY_LOGGED], budget.burst, budget.rate)
                return []
            replies = answer(selector)
            for _, data in replies:
                self._sent(data)
            return replies

        self.transport.queryable(key, counted)

    def query(self, selector: str, handler: Handler, timeout: float = 2.0) -> int:
        """Ask ``selector``; each good reply goes to ``handler``. Returns the number of good replies."""
        return sum(self.receive(key, data, handler) for key, data in self.transport.get(selector, timeout))

    def receive(self, key: str, data: bytes, handler: Handler) -> bool:
        """Decode, check and hand over one payload; bad ones are dropped and counted. True if handled."""
        try:
            msg = decode(data)
            _check_key(key, msg)
        except MessageError as exc:
            # A subscription to ``.../**`` passes keys of any length: only so much of one is logged.
            self.dropped(exc.reason, "dropped malformed message on %s: %s", key[:_KEY_LOGGED], exc)
            return False
        with self._lock:
            self.counters.messages_received += 1
            self.counters.bytes_received += len(data)
            self.counters.last_received = self.clock.now()
        try:
            handler(key, msg)
        except Exception:  # the handler's bug must not become the transport's crash
            log.exception("handling a message on %s failed", key)
        return True

    def dropped(self, reason: str, msg: str, *args: object, exc_info: bool = False) -> None:
        """Count a received message dropped for ``reason`` and log ``msg % args``, rate-limited per reason.

        For the receiver's own checks after decoding too (e.g. the twin's ``"handler-error"``), so every drop
        is in one counter."""
        with self._lock:
            self.counters.dropped_malformed += 1
            self.counters.dropped_by_reason[reason] += 1
        self.dropped_log.warning(reason, msg, *args, exc_info=exc_info)

    def close(self) -> None:
        self.transport.close()

    def _sent(self, data: bytes) -> None:
        with self._lock:
            self.counters.messages_sent += 1
            self.counters.bytes_sent += len(data)


def _check_key(key: str, msg: Message) -> None:
    """Raise ``wrong-key`` unless ``key`` is exactly the key ``msg``'s type travels on, naming its object (or, for
    a :class:`~sync.messages.SceneInfo`, its scene)."""
    carried = carried_by(key)
    tag = type(msg).__struct_config__.tag
    if carried is None or carried[1] != tag:
        raise MessageError("wrong-key", f"a {type(msg).__name__} on a key that carries "
                                        f"{'no message' if carried is None else repr(carried[1])}")
    scene, _, object_id = carried
    named = getattr(msg, "object_id", None)
    if named is not None and named != object_id:
        raise MessageError("wrong-key", f"a message about {named!r} on another object's key")
    if isinstance(msg, SceneInfo) and msg.name != scene:
        raise MessageError("wrong-key", f"scene {msg.name!r} described on scene {scene!r}'s key")
