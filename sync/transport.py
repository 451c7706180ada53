"""The seam between a runtime and the network: publish, subscribe, answer queries, ask.

A :class:`Transport` moves opaque bytes under key expressions (:mod:`sync.keys`); it knows nothing of the
message types. :class:`sync.link.Link` puts the wire format and its checks on top of any transport.
Two implementations: :class:`sync.zenoh_transport.ZenohTransport` (a Zenoh session, for live runs across
processes and machines) and :class:`sync.inprocess.InProcessTransport` (one process, no sockets, for
headless runs on a simulated clock).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

#: ``callback(key, payload)`` for each publication a subscription matches.
OnSample = Callable[[str, bytes], None]

#: ``answer(selector) -> [(key, payload), ...]``: a queryable's replies to one query.
Answer = Callable[[str], list[tuple[str, bytes]]]


class Transport(Protocol):
    """Bytes under keys. Callbacks may run on the transport's own threads: they must only enqueue."""

    def put(self, key: str, data: bytes) -> None:
        """Publish ``data`` under ``key`` (a key without wildcards)."""

    def subscribe(self, keyexpr: str, callback: OnSample) -> None:
        """Call ``callback`` for every publication whose key ``keyexpr`` matches, until :meth:`close`."""

    def queryable(self, keyexpr: str, answer: Answer) -> None:
        """Answer queries whose selector intersects ``keyexpr`` with what ``answer`` returns, less the replies
        whose keys the selector does not match."""

    def get(self, selector: str, timeout: float) -> list[tuple[str, bytes]]:
        """Ask every queryable that ``selector`` intersects; their replies, within ``timeout`` seconds."""

    def close(self) -> None:
        """Undeclare everything this transport declared (not the session it may wrap)."""
