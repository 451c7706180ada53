"""The interval where the points cannot pin the volume down: the clouds of tests/test_honest_intervals.py.

    .venv/bin/python bench/honest_intervals.py      # output in bench/results/honest_intervals.txt

A mug (8 cm across, 5 mm base, a handle) of 100,000 surface points with none on its inner floor, the same with
every point, and a 40.5 mm cube of 60,000 points written with three decimals in metres (whole millimetres), with
the same cube turned and not rounded beside it. Per cloud: the volume error, the interval as errors, whether the
truth is inside, the coordinates' lattice step and the warnings. Run it in another checkout to see that code's
figures (it imports the packages beside it).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation
from trimesh.transformations import rotation_matrix

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's packages, not an installed copy

RESULTS = ROOT / "bench" / "results" / "honest_intervals.txt"


def mug() -> trimesh.Trimesh:
    outer = trimesh.creation.cylinder(radius=0.04, height=0.09, sections=128)
    inner = trimesh.creation.cylinder(radius=0.036, height=0.09, sections=128)
    inner.apply_translation([0.0, 0.0, 0.005])
    handle = trimesh.creation.torus(major_radius=0.027, minor_radius=0.006, major_sections=64, minor_sections=24)
    handle.apply_transform(rotation_matrix(np.pi / 2, [1, 0, 0]))
    handle.apply_translation([0.0535, 0.0, 0.0])
    return outer.difference(inner).union(handle)


def clouds() -> list[tuple[str, np.ndarray, float]]:
    """(name, points (n, 3) metres, true volume m^3), as the tests build them."""
    cup = mug()
    points = trimesh.sample.sample_surface(cup, 100_000, seed=0)[0]
    r = np.hypot(points[:, 0], points[:, 1])
    floor = (np.abs(points[:, 2] - (-0.045 + 0.005)) < 2e-4) & (r < 0.036 - 1e-4)
    cube = trimesh.creation.box((0.0405, 0.0405, 0.0405))
    on_cube = trimesh.sample.sample_surface(cube, 60_000, seed=1)[0]
    return [("mug, inner floor unseen", points[~floor], cup.volume), ("mug, every point", points, cup.volume),
            ("40.5 mm cube, whole mm", np.round(on_cube, 3), cube.volume),
            ("40.5 mm cube, turned", on_cube @ Rotation.random(random_state=2).as_matrix().T, cube.volume)]


def main() -> int:
    from estimation import estimate, make_cloud
    from estimation.lattice import lattice_step

    lines = [f"bench/honest_intervals.py ({ROOT.name}): volume error and interval, % of the true volume", ""]
    for name, points, truth in clouds():
        result = estimate(make_cloud(points), 1000.0)
        low, high = result.volume_bounds_m3
        lines.append(f"{name:26s} {100 * (result.volume / truth - 1):+7.2f} %  interval {100 * (low / truth - 1):+7.2f}.."
                     f"{100 * (high / truth - 1):+7.2f} %  truth inside: {'yes' if low <= truth <= high else 'NO'}  "
                     f"lattice {1000 * lattice_step(points):g} mm")
        lines.extend(f"    {w}" for w in result.warnings)
        print(lines[-1 - len(result.warnings)], flush=True)
    RESULTS.write_text("\n".join(lines) + "\n")
    print(f"written to {RESULTS}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
