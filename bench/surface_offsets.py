"""Where a noisy estimate's surface sits against the truth, by distance from the true mesh's edges, and what
each band does to the centre of mass: the unseen-shapes bench's chair (or any of its shapes) at sigma 0.5 mm.

    .venv/bin/python bench/surface_offsets.py [--shape chair] [--seeds 0 1]   # output in bench/results/surface_offsets.txt

For each seed (a pose, as in bench/unseen_shapes.py), the estimate as ``estimate`` makes it and, as a control,
with the cloud thinned to the point budget by a random share instead of one point per voxel. 150,000 points
sampled over the reconstructed surface are each measured to the nearest point of the true mesh (Open3D's
ray-casting scene), signed outward; bands by that point's distance from the nearest true edge (dihedral over
30 degrees). Per band: its share of the area, the mean offset, the volume it adds (the offset times the area)
and the centre-of-mass shift that volume makes, along the estimate's actual error.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

import numpy as np
import trimesh

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from unseen_shapes import CONDITIONS, MAKERS, NOISE_SIGMA, RHO, make_solid  # noqa: E402

from estimation import estimate  # noqa: E402
from estimation.downsample import thin_to_budget  # noqa: E402
from scenes.sampling import sample_surface  # noqa: E402

# The module, not the package's function of the same name: the control swaps its thinning.
estimate_module = importlib.import_module("estimation.estimate")

RESULTS = ROOT / "bench" / "results" / "surface_offsets.txt"
SAMPLES = 150_000
BANDS = ((0.0, 0.001), (0.001, 0.003), (0.003, 0.006), (0.006, np.inf))  # metres from the nearest edge
EDGE_ANGLE_DEG = 30.0


def _closest(true: trimesh.Trimesh, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    import open3d as o3d

    from scenes.shapes import surface_scene

    found = surface_scene(true).compute_closest_points(o3d.core.Tensor(points.astype(np.float32)))
    return found["points"].numpy().astype(float), found["primitive_ids"].numpy().astype(int)


def _edge_distance(true: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    sharp = true.face_adjacency_angles > np.radians(EDGE_ANGLE_DEG)
    ends = true.face_adjacency_edges[sharp]
    a, b = true.vertices[ends[:, 0]], true.vertices[ends[:, 1]]
    ab = b - a
    length2 = np.maximum((ab**2).sum(axis=1), 1e-30)
    out = np.full(len(points), np.inf)
    for start in range(0, len(points), 4000):
        p = points[start:start + 4000]
        best = np.full(len(p), np.inf)
        for k in range(0, len(a), 64):
            t = np.clip(np.einsum("pkj,kj->pk", p[:, None, :] - a[None, k:k + 64], ab[k:k + 64]) / length2[k:k + 64], 0, 1)
            foot = a[None, k:k + 64] + t[..., None] * ab[None, k:k + 64]
            best = np.minimum(best, np.linalg.norm(p[:, None, :] - foot, axis=2).min(axis=1))
        out[start:start + 4000] = best
    return out


def _random_share(points, spacing, noise, budget, **kw):  # type: ignore[no-untyped-def]
    """``thin_to_budget``'s own random share, taken whatever the noise (as it takes it past half a voxel)."""
    return thin_to_budget(points, spacing, np.inf, budget, **kw)


def rows(name: str, seed: int) -> list[str]:
    solid = make_solid(name, seed)
    true = solid.mesh
    cloud = sample_surface(true, 200_000, seed=[seed, list(MAKERS).index(name), CONDITIONS.index("noise 0.5 mm, no normals")],
                           noise_sigma=NOISE_SIGMA, with_normals=False)  # the unseen bench's noisy cloud
    out = []
    for label in ("one point per voxel (as estimated)", "a random share (control)"):
        saved = estimate_module.thin_to_budget
        if label.startswith("a random"):
            estimate_module.thin_to_budget = _random_share
        try:
            est = estimate(cloud, RHO)
        finally:
            estimate_module.thin_to_budget = saved
        error = est.mass.center_of_mass - true.center_mass
        along = error / max(float(np.linalg.norm(error)), 1e-30)
        rec = trimesh.Trimesh(est.vertices, est.faces, process=False)
        samples, _ = trimesh.sample.sample_surface(rec, SAMPLES, seed=1)
        closest, tri = _closest(true, samples)
        offset = np.einsum("ij,ij->i", samples - closest, true.face_normals[tri])
        edge = _edge_distance(true, closest)
        area = rec.area / SAMPLES
        out.append(f"{name} seed {seed}, {label}: volume {100 * (est.volume / true.volume - 1):+.3f} %, centre of mass "
                   f"{1e3 * np.linalg.norm(error):.3f} mm off")
        for low, high in BANDS:
            band = (edge >= low) & (edge < high)
            volume = offset[band] * area
            shift = ((samples[band] - true.center_mass) * volume[:, None]).sum(axis=0) / true.volume
            span = f"{1e3 * low:.0f}-{1e3 * high:.0f} mm" if np.isfinite(high) else f"over {1e3 * low:.0f} mm"
            out.append(f"    {span:>9s} from an edge: area {100 * band.mean():5.1f} %, mean offset {1e3 * offset[band].mean():+.4f} mm, "
                       f"volume {100 * volume.sum() / true.volume:+.4f} %, centre of mass {1e3 * (shift @ along):+.3f} mm along the error")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--shape", default="chair", choices=list(MAKERS))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    lines = [f"bench/surface_offsets.py: {args.shape}, sigma {NOISE_SIGMA * 1e3:g} mm, no normals, 200,000 points; offsets outward"]
    for seed in args.seeds:
        for line in rows(args.shape, seed):
            print(line, flush=True)
            lines.append(line)
    args.out.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
