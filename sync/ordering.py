"""Newest wins, per sender, for senders nothing vouches for: marks that expire.

Ordered messages carry their sender's ``(epoch, seq)`` (:mod:`sync.messages`), and a receiver takes one only
if it is newer than the last it took from that sender. The remote's object messages have heartbeats that
state its counter, so the twin pulls a forged mark back to it (:mod:`twin.runtime`). A device driver's
targets and the twin's operator commands have no such witness, and a mark of ``(2**63 - 1, 2**63 - 1)``
(forged, or a driver whose clock jumped ahead) would refuse every later message of that sender for ever,
even after the real one restarts. So here the rule is:

    A message is taken if no message of its sender was taken in the last :data:`MARK_EXPIRY` seconds, or
    if its ``(epoch, seq)`` is larger than the last one taken.

A mark past the sender's real counter therefore holds it back for at most :data:`MARK_EXPIRY` seconds; after
a silence that long, a stale message that arrives is taken (only reordering longer than that could send
one). Past :data:`MAX_SENDERS` senders, the one taken from longest ago is forgotten, so forged sender ids
cannot grow memory.
"""

from __future__ import annotations

#: Seconds a sender's mark lasts after the last message taken from it: well above any reordering on a real
#: link (milliseconds), and a bound on how long a forged or future mark freezes a device (as a heartbeat
#: period bounds it for the remote's objects).
MARK_EXPIRY = 1.0

#: Senders (devices) remembered at once: more than any rig has; beyond it the least recent is forgotten.
MAX_SENDERS = 256


class Marks:
    """The newest ``(epoch, seq)`` taken from each sender, and when (seconds of the receiver's clock)."""

    def __init__(self, *, expiry: float = MARK_EXPIRY, capacity: int = MAX_SENDERS) -> None:
        if not expiry > 0 or capacity < 1:
            raise ValueError(f"expiry must be > 0 s and capacity >= 1, got {expiry}, {capacity}")
        self.expiry = expiry
        self.capacity = capacity
        self._marks: dict[str, tuple[int, int, float]] = {}  # sender -> (epoch, seq, taken at); least recent first

    def __len__(self) -> int:
        return len(self._marks)

    def newer(self, sender: str, epoch: int, seq: int, now: float) -> bool:
        """Whether a message ``(epoch, seq)`` from ``sender`` arriving at ``now`` (s) is to be taken (see the
        module's rule); the mark does not move until :meth:`take`."""
        mark = self._marks.get(sender)
        return mark is None or now - mark[2] >= self.expiry or (epoch, seq) > mark[:2]

    def take(self, sender: str, epoch: int, seq: int, now: float) -> bool:
        """Move ``sender``'s mark to ``(epoch, seq)`` taken at ``now`` (s). Returns whether another sender was
        forgotten to stay within the capacity."""
        self._marks.pop(sender, None)
        self._marks[sender] = (epoch, seq, now)
        if len(self._marks) <= self.capacity:
            return False
        del self._marks[next(iter(self._marks))]
        return True
