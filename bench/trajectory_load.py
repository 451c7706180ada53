"""Reading a long operator script and looking targets up in it, against the evaluation it replaced.

    .venv/bin/python bench/trajectory_load.py > bench/results/trajectory_load.txt

A 1,000,000-row ``t,x,y,z`` CSV (a 1 kHz script of 1000 s, 39 MB at 6 decimals) is written to a temporary folder and read
with ``twin.trajectory.load_trajectory`` (best of 3, wall seconds, and the process's peak memory growth); then
10,000 target look-ups at random times, against the baseline in the same process: ``np.interp`` over the
times and each column of the (n, 3) positions, which is how a target was found before (each call copies the
columns it reads).
"""

from __future__ import annotations

import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages, not an installed copy

ROWS = 1_000_000
LOOKUPS = 10_000


def main() -> int:
    from twin.trajectory import load_trajectory

    t = np.arange(ROWS) * 1e-3
    xyz = np.c_[0.3 * np.sin(t), 0.2 * np.cos(t), 0.8 + 0.01 * np.sin(3 * t)]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "script.csv"
        np.savetxt(path, np.c_[t, xyz], delimiter=",", header="t,x,y,z", comments="", fmt="%.6f")
        size = path.stat().st_size
        rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        loads = []
        for _ in range(3):
            start = time.perf_counter()
            trajectory = load_trajectory(path)
            loads.append(time.perf_counter() - start)
        grew = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0) / 1024
    # As the evaluation before kept them: the times a contiguous copy, the positions an (n, 3) table whose
    # columns np.interp reads strided, so each call copies every waypoint of each column.
    times, points = trajectory.times.copy(), trajectory.points.copy()

    def before(at: float) -> np.ndarray:
        return np.array([np.interp(at, times, points[:, k]) for k in range(3)])

    queries = np.random.default_rng(0).uniform(0, t[-1], LOOKUPS)
    timings = {}
    for name, lookup in (("binary search (load_trajectory's)", trajectory), ("np.interp on columns (before)", before)):
        n = LOOKUPS if lookup is trajectory else LOOKUPS // 100  # the baseline is ~1000x slower a call
        start = time.perf_counter()
        for q in queries[:n]:
            lookup(q)
        timings[name] = (time.perf_counter() - start) / n
    assert np.allclose(trajectory(queries[0]), before(queries[0]))
    print(f"bench/trajectory_load.py: a {ROWS:,}-row script, {size / 1e6:.0f} MB\n")
    print(f"load_trajectory: {min(loads):.2f} s (best of 3; {', '.join(f'{s:.2f}' for s in loads)}), peak memory "
          f"grew {grew:.0f} MB")
    fast, slow = timings.values()
    for name, seconds in timings.items():
        print(f"one look-up, {name}: {seconds * 1e6:,.1f} us")
    print(f"look-up ratio: {slow / fast:,.0f}x faster than the baseline")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
