"""What the operator does: end-effector targets as functions of twin time (world frame, metres)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

Trajectory = Callable[[float], np.ndarray]


def push_trajectory(start: np.ndarray, end: np.ndarray, duration: float) -> Trajectory:
    """A straight push from ``start`` to ``end`` over ``duration`` seconds, then hold."""
    start, end = np.asarray(start, float), np.asarray(end, float)

    def at(t: float) -> np.ndarray:
        s = min(1.0, max(0.0, t / duration))
        return start + s * (end - start)

    return at
