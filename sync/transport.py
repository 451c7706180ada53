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

#: What one :meth:`Transport.get` takes in before it stops reading: replies come from any peer that declares a
#: matching queryable, and a hostile one could answer with replies without end. A full scene is two replies
#: per object (its cloud and its pose) for up to 1000 objects (:data:`scenes.scenefile.MAX_OBJECTS`), and a
#: 1M-point cloud of a 10 cm ball encodes to 2.1 MB (3.1 MB with normals); past either cap the rest of the
#: replies are not read (logged).
MAX_REPLIES = 4096
MAX_REPLY_BYTES = 2**30


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
