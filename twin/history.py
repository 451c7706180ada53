"""The twin's recent past, so a pose from C is compared with C' at the same point of the operator's input.

C applies each operator command one network delay after C' did, and its poses take another delay to come
back: a pose from C describes the scene as C' had it a round trip ago. Compared with C' now, an object the
operator is pushing looks a round trip behind, and correcting towards it pulls the object back into the
operator's hand (felt as a wall that stiffens with the delay). So each pose says which moment of the twin
it answers to (:attr:`sync.messages.Pose.answers_ns`, on the twin's own clock: no clock synchronisation),
and the twin corrects only what differs from its own state at that moment, less the corrections it has
applied since.

:class:`History` keeps, per step, every object's state and the corrections applied to it so far, for a
window of steps; the runtime (:mod:`twin.runtime`) writes and reads it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: Columns of a state row: position (3, m), quaternion (4, w x y z), linear and angular velocity (3 + 3,
#: m/s and rad/s, world axes); then the corrections applied so far (3 + 3 + 3 + 3: position, rotation
#: vector, linear and angular velocity), summed.
STATE, CORRECTION = 13, 12


class History:
    """A ring of the last ``capacity`` steps: (stamp on the twin's clock, ns; each object's state row).

    Valid for one set of objects in one order (``key``, compared by identity; ``rows``: object id -> its
    row): :meth:`start` with another key empties it, as a new model or an added object changes which rows
    mean what.
    """

    def __init__(self, capacity: int) -> None:
        if capacity < 0:
            raise ValueError(f"history capacity must be >= 0, got {capacity}")
        self.capacity = capacity
        self.key: object = None
        self.rows: dict[str, int] = {}
        self._stamps = np.zeros(capacity, dtype=np.int64)
        self._rows = np.zeros((capacity, 0, STATE + CORRECTION))
        self._applied = np.zeros((0, CORRECTION))  # corrections applied so far, per object (row order)
        self._count = 0
        self._next = 0

    def start(self, key: object, ids: Sequence[str]) -> None:
        """Begin again for the objects ``ids`` (rows, in this order) known by ``key`` (None: none); a no-op
        when ``key`` is current."""
        if key is self.key:
            return
        self.key = key
        self.rows = {i: k for k, i in enumerate(ids)}
        self._rows = np.zeros((self.capacity, len(ids), STATE + CORRECTION))
        self._applied = np.zeros((len(ids), CORRECTION))
        self._count = self._next = 0

    def record(self, stamp_ns: int, state: np.ndarray) -> None:
        """Keep ``state`` ((objects, 13) rows, see :data:`STATE`) as of ``stamp_ns``, with the corrections so far."""
        if self.capacity == 0:
            return
        k = self._next
        self._stamps[k] = stamp_ns
        self._rows[k, :, :STATE] = state
        self._rows[k, :, STATE:] = self._applied
        self._next = (k + 1) % self.capacity
        self._count = min(self._count + 1, self.capacity)

    def corrected(self, rows: np.ndarray | list[int], amount: np.ndarray) -> None:
        """Count corrections ``amount`` ((n, 12), see :data:`CORRECTION`) as applied to objects ``rows`` (n,),
        each row at most once."""
        self._applied[rows] += amount

    def at(self, stamp_ns: int, tolerance_ns: int) -> tuple[np.ndarray, np.ndarray] | None:
        """(every object's state row (objects, 13), the corrections applied since (objects, 12)) at the
        recorded step nearest ``stamp_ns``; None when no step is within ``tolerance_ns`` of it (older than
        the window, not yet recorded, or a stamp no honest remote sends)."""
        if self._count == 0:
            return None
        stamps = self._stamps[: self._count]
        k = int(np.argmin(np.abs(stamps - stamp_ns)))
        if abs(int(stamps[k]) - stamp_ns) > tolerance_ns:
            return None
        row = self._rows[k]
        return row[:, :STATE], self._applied - row[:, STATE:]
