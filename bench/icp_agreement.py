"""estimation.fusion.register (point-to-plane ICP in numpy) against Open3D's registration_icp, and its repeatability.

    .venv/bin/python bench/icp_agreement.py > bench/results/icp_agreement.txt

register() replaced Open3D's ICP in session 39 because Open3D sums its normal equations across threads in no fixed
order: the same clouds gave different last bits from run to run. This prints, for seeded boxes, balls and half-seen
bars (1 mm noise, a 0.05 rad turn and a few mm shift, two correspondence distances), the fitness of each and the
largest difference of their transforms, then how many distinct transforms each gives in 20 runs of one case, and
their times (median of 5, ms, in this process; Open3D's first call, its import, is paid before).
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from estimation import tolerances as tol
from estimation.fusion import register


def open3d_icp(source: np.ndarray, target: np.ndarray, init: np.ndarray, max_distance: float) -> tuple[np.ndarray, float]:
    """Open3D's point-to-plane ICP as register() ran it until session 39 (about the target's centroid)."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    pivot = target.mean(axis=0)
    shift, back = np.eye(4), np.eye(4)
    shift[:3, 3], back[:3, 3] = -pivot, pivot
    a = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source - pivot))
    b = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(target - pivot))
    b.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=min(tol.NORMAL_NEIGHBOURS, len(target))))
    out = reg.registration_icp(a, b, max_distance, shift @ init @ back, reg.TransformationEstimationPointToPlane(),
                               reg.ICPConvergenceCriteria(max_iteration=50))
    return back @ np.asarray(out.transformation) @ shift, float(out.fitness)


def cases(rng: np.random.Generator):  # type: ignore[no-untyped-def]
    def box(n: int, half: list[float], c: np.ndarray) -> np.ndarray:
        u = rng.uniform(-1, 1, (n, 3))
        face = rng.integers(0, 3, n)
        u[np.arange(n), face] = np.sign(u[np.arange(n), face])
        return u * half + c

    def ball(n: int, c: np.ndarray, r: float) -> np.ndarray:
        d = rng.normal(size=(n, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        d = d[d[:, 2] > -0.3]
        return c + d * (r + rng.normal(0, 0.001, (len(d), 1)))

    for k in range(12):
        c = rng.uniform(-1, 1, 3)
        if k % 3 == 0:
            name, src, tgt = "box", box(3000, [0.05, 0.03, 0.02], c), box(8000, [0.05, 0.03, 0.02], c)
        elif k % 3 == 1:
            name, src, tgt = "ball 2 cm", ball(300, c, 0.02), ball(900, c, 0.02)
        else:
            name, src = "bar, half seen", box(3000, [0.1, 0.02, 0.02], c)
            tgt = box(5000, [0.1, 0.02, 0.02], c)
            tgt = tgt[tgt[:, 0] > c[0]]
        tgt = tgt + rng.normal(0, 0.001, tgt.shape)
        init = np.eye(4)
        a = rng.normal(0, 0.05)
        init[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
        init[:3, 3] = rng.normal(0, 0.005, 3)
        yield f"{k:2d} {name}", src, tgt, init


def main() -> int:
    open3d_icp(np.random.default_rng(0).normal(size=(50, 3)), np.random.default_rng(1).normal(size=(50, 3)), np.eye(4), 1.0)
    rng = np.random.default_rng(0)
    print(f"{'case':18s} {'reach mm':>8s} {'fitness numpy':>13s} {'fitness Open3D':>14s} {'max |dT|':>9s}")
    rows = list(cases(rng))
    for label, src, tgt, init in rows:
        for reach in (0.005, 0.03):
            ours = register(src, tgt, init=init, max_distance=reach)
            theirs, fitness = open3d_icp(src, tgt, init, reach)
            print(f"{label:18s} {1000 * reach:8.0f} {ours.fitness:13.4f} {fitness:14.4f} "
                  f"{np.abs(ours.transform - theirs).max():9.1e}")
    label, src, tgt, init = rows[0]
    ours = {register(src, tgt, init=init, max_distance=0.01).transform.tobytes() for _ in range(20)}
    theirs = {open3d_icp(src, tgt, init, 0.01)[0].tobytes() for _ in range(20)}
    print(f"\n20 runs of case {label.strip()} (10 mm reach): {len(ours)} distinct transform(s) with numpy, "
          f"{len(theirs)} with Open3D")
    times = {}
    for name, run in (("numpy", lambda: register(src, tgt, init=init, max_distance=0.01)),
                      ("Open3D", lambda: open3d_icp(src, tgt, init, 0.01))):
        samples = []
        for _ in range(5):
            t0 = time.perf_counter()
            run()
            samples.append(time.perf_counter() - t0)
        times[name] = 1000 * statistics.median(samples)
    print(f"one fit of case {label.strip()}, median of 5: numpy {times['numpy']:.1f} ms, Open3D {times['Open3D']:.1f} ms "
          f"(normals fitted once per target in both; a track's several fits share them in numpy, icp_target)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
