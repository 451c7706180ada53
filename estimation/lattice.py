"""Coordinates rounded to a lattice: a file written with a fixed number of decimals, or in whole millimetres.

Rounding moves each point by up to half a step along each axis. On a face tilted to the axes the moves
average out; on a face along them every point moves the same way, and the face with them: a 40.5 mm cube
rounded to whole millimetres is a 40 mm cube to the points (-3.6 % of its volume), and no estimate can tell.
"""

from __future__ import annotations

import numpy as np

#: Points looked at: enough to meet every value a lattice of an object's size takes, cheap on 50 M points.
SAMPLE = 20_000

#: How near a whole number of steps a coordinate must be, in steps (float32 files hold ~7 digits).
TOLERANCE = 1e-3


def lattice_step(points: np.ndarray) -> float:
    """The step (metres) of the lattice every point's coordinates lie on, in the points' own axes: the largest
    of the three axes' steps; 0 where an axis' coordinates lie on none (a sensor's cloud, any rotated cloud).

    An axis' step is the smallest gap between its distinct sampled values, kept if every one of them is a whole
    number of steps from the smallest (one value off the lattice, and there is none: nothing is claimed).
    """
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) > SAMPLE:
        pts = pts[np.random.default_rng(0).choice(len(pts), SAMPLE, replace=False)]
    steps = []
    for values in pts.T:
        distinct = np.unique(values)
        if len(distinct) < 3:
            return 0.0
        step = float(np.diff(distinct).min())
        turns = (distinct - distinct[0]) / step
        if not np.all(np.abs(turns - np.round(turns)) <= TOLERANCE):
            return 0.0
        steps.append(step)
    return max(steps)
