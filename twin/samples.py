"""A bounded, evenly spaced sample of a series that may run for hours.

The twin's loop times every step, and its report keeps each pose's latency and each object's divergence:
at 1 kHz that is millions of values an hour, and a list of Python floats holds 32 bytes each. A
:class:`Samples` keeps every value until it holds ``capacity`` of them; then it drops every other one and
from there keeps every second value offered, then every fourth, and so on. What it holds is always every
``stride``-th value of the whole series (from the first), so percentiles over it are those of a uniform
subsample, at most ``capacity`` long.
"""

from __future__ import annotations

#: Values kept at most, per series: a million floats (32 MB as a list) is some 17 minutes at 1 kHz in full,
#: and a uniform subsample of any longer run.
CAPACITY = 1_000_000


class Samples(list):  # type: ignore[type-arg]
    """A list of floats that :meth:`append` keeps to at most ``capacity`` values, evenly spaced over the
    series (see the module docstring); ``offered`` counts every value appended, kept or not."""

    def __init__(self, capacity: int = CAPACITY) -> None:
        super().__init__()
        if capacity < 2:
            raise ValueError(f"capacity must be at least 2, got {capacity}")
        self.capacity = capacity
        self.stride = 1
        self.offered = 0

    def append(self, value: float) -> None:  # type: ignore[override]
        if self.offered % self.stride == 0:
            super().append(value)
            if len(self) > self.capacity:
                del self[1::2]
                self.stride *= 2
        self.offered += 1
