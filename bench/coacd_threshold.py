"""What CoACD's concavity threshold costs: the numbers behind ``twin.decompose.FAST_THRESHOLD``.

    .venv/bin/python bench/coacd_threshold.py > bench/results/coacd_threshold.txt

One torus (``trimesh.creation.torus(0.05, 0.02, 48 x 24 sections)``: 2,304 faces, a concave shape CoACD cannot
take whole) decomposed with the project's CoACD settings at each threshold, one process, one core: wall and
CPU seconds and the hulls made. The default threshold is the baseline the ratio column divides by.
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages, not an installed copy

THRESHOLDS = (0.08, 0.05, 0.03, 0.02, 0.015, 0.012, 0.01)


def main() -> int:
    import trimesh

    from twin.decompose import DEFAULT_SETTINGS, FAST_THRESHOLD, _run_coacd, concavity

    mesh = trimesh.creation.torus(major_radius=0.05, minor_radius=0.02, major_sections=48, minor_sections=24)
    print(f"bench/coacd_threshold.py: a torus of {len(mesh.faces):,} faces (concavity "
          f"{concavity(mesh.vertices, mesh.faces):.3f}); default threshold {DEFAULT_SETTINGS.threshold:g}, warned "
          f"below {FAST_THRESHOLD:g}\n")
    print(f"{'threshold':>9s} {'wall s':>7s} {'CPU s':>7s} {'hulls':>5s} {'x default':>9s}")
    base = None
    for threshold in sorted({DEFAULT_SETTINGS.threshold, *THRESHOLDS}, reverse=True):
        settings = replace(DEFAULT_SETTINGS, threshold=threshold)
        cpu, wall = time.process_time(), time.perf_counter()
        hulls = _run_coacd(mesh.vertices, mesh.faces, settings)
        cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
        base = base or wall
        print(f"{threshold:9g} {wall:7.1f} {cpu:7.1f} {len(hulls):5d} {wall / base:8.1f}x", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
