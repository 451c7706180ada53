"""Where a noisy cloud's volume bias comes from: thinning, curvature and creases.

    .venv/bin/python bench/noise_bias.py      # output in bench/results/noise_bias.txt

Isotropic Gaussian noise (sigma 0.25 and 0.5 mm) on 100,000 area-weighted surface points of a 15 mm
sphere and a 60 mm cube, each in a random pose, estimated with 'auto' (no normals):
- "as estimated": what ``estimate`` does (it thins to its point budget, by a random subset where the
  noise is thicker than half a voxel);
- "one per voxel": the cloud first thinned as ``estimate`` thins clean clouds, one point per voxel
  (``voxel_subsample``) down to the same budget;
- "noise lift": the volume the noise itself adds on a sphere, 3 sigma^2 / R^2 (points moved along the
  surface by sigma sit sigma^2 / R outside it on average), for reference;
- on the cube, the reconstructed surface's mean distance outside the true faces, near the edges and away
  from them, and the excess cross-section along the edges (the excess volume near them per metre of edge);
- a 40 mm tetrahedron at sigma 0.5 and 1 mm, three draws: where creases are much of the shape;
- a 20 x 16 x 12 cm box, 200,000 points at sigma 0.5 mm in six poses, thinned as ``estimate`` thins (one point
  per voxel, on voxels turned off the box frame's axes: ``downsample.LATTICE_TURN``) and on voxels along the
  axes (the turn set to none, as before it): the volume, the points the answer was built from, and the
  reconstructed faces' mean offset outside the true ones, away from the edges.

Then small objects as the camera feed sees them (``SMALL``): spheres of 5-15 mm radius and a 7 mm-radius
rod, points about 1.2 mm apart (a 1280 x 720 camera at 1.5 m), sigma 0.5 and 1 mm, median over
``SMALL_SEEDS`` draws: how far the estimate holds as the noise becomes a good share of the radius (the
clutter's hex nut in bench/cameras.py is a 7 mm-radius ring seen at 1 mm).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import estimation.downsample as downsample  # noqa: E402
from estimation import estimate  # noqa: E402
from estimation import tolerances as tol  # noqa: E402
from estimation.cloud import PointCloud  # noqa: E402
from estimation.downsample import voxel_subsample  # noqa: E402
from estimation.spacing import point_spacing  # noqa: E402
from scenes.sampling import sample_surface  # noqa: E402

POINTS = 100_000
SIGMAS = (0.00025, 0.0005)
RESULTS = ROOT / "bench" / "results" / "noise_bias.txt"

#: The tetrahedron's sigmas (metres) and draws.
CREASE_SIGMAS = (0.0005, 0.001)
CREASE_SEEDS = 3

#: The box's extents (metres), points, poses, and how far from an edge (metres) a vertex counts as on a face.
BOX = (0.2, 0.16, 0.12)
BOX_POINTS = 200_000
BOX_POSES = 6
FACE_MARGIN = 0.006

#: Small objects at a camera's spacing (metres) and sigmas (metres); the median of SMALL_SEEDS draws.
SMALL_SPACING = 0.0012
SMALL_SIGMAS = (0.0005, 0.001)
SMALL_SEEDS = 5


def _posed(mesh: trimesh.Trimesh, seed: int) -> tuple[trimesh.Trimesh, np.ndarray, np.ndarray]:
    rotation = Rotation.random(random_state=seed).as_matrix()
    shift = np.array([0.1, 0.2, 0.3])
    posed = mesh.copy()
    posed.apply_transform(np.vstack([np.hstack([rotation, shift[:, None]]), [0, 0, 0, 1]]))
    return posed, rotation, shift


def _per_voxel(cloud: PointCloud) -> PointCloud:
    """The cloud thinned one point per voxel to the estimator's budget (as it thins clean clouds)."""
    spacing = point_spacing(cloud.points)
    keep = voxel_subsample(cloud.points, spacing * np.sqrt(tol.VOXELS_PER_AREA * len(cloud) / tol.POINT_BUDGET))
    return PointCloud(cloud.points[keep])


def _error(volume: float, truth: float) -> str:
    return f"{100 * (volume / truth - 1):+7.3f}"


def sphere_rows() -> list[str]:
    radius = 0.015
    mesh, _, _ = _posed(trimesh.creation.icosphere(subdivisions=5, radius=radius), 3)
    rows = []
    for sigma in SIGMAS:
        cloud = sample_surface(mesh, POINTS, seed=[5], noise_sigma=sigma, with_normals=False)
        rows.append(f"sphere 15 mm  sigma {sigma * 1e3:.2f} mm | as estimated {_error(estimate(cloud, 1000.0).volume, mesh.volume)} % "
                    f"| one per voxel {_error(estimate(_per_voxel(cloud), 1000.0).volume, mesh.volume)} % "
                    f"| noise lift {100 * 3 * sigma**2 / radius**2:+7.3f} %")
    return rows


def cube_rows() -> list[str]:
    half = 0.03
    mesh, rotation, shift = _posed(trimesh.creation.box([2 * half] * 3), 3)
    rows = []
    for sigma in SIGMAS:
        cloud = sample_surface(mesh, POINTS, seed=[5], noise_sigma=sigma, with_normals=False)
        est = estimate(cloud, 1000.0)
        local = np.abs((est.vertices - shift) @ rotation)  # cube frame, folded into one octant
        ordered = np.sort(local, axis=1)
        beyond = np.maximum(local - half, 0.0)
        outside = np.where((local <= half).all(axis=1), ordered[:, 2] - half, np.linalg.norm(beyond, axis=1))
        to_edge = half - ordered[:, 1]  # along the face to the nearest edge (negative: beyond it)
        surface = trimesh.Trimesh(est.vertices, est.faces, process=False)
        area = np.zeros(len(est.vertices))
        np.add.at(area, est.faces.ravel(), np.repeat(surface.area_faces / 3, 3))
        near, far = to_edge < 0.002, to_edge > 0.004
        # Excess volume near the edges beyond what the faces' own offset explains, per metre of edge.
        excess = float(np.sum((outside[near] - np.average(outside[far], weights=area[far])) * area[near])) / (24 * half)
        rows.append(f"cube 60 mm    sigma {sigma * 1e3:.2f} mm | as estimated {_error(est.volume, mesh.volume)} % "
                    f"| surface outside the faces: within 2 mm of an edge {1e6 * np.average(outside[near], weights=area[near]):6.1f} um, "
                    f"beyond 4 mm {1e6 * np.average(outside[far], weights=area[far]):5.1f} um "
                    f"| excess cross-section along the edges {excess * 1e6:5.3f} mm^2")
    return rows


def crease_rows() -> list[str]:
    """A 40 mm regular tetrahedron (dihedral angle 70.5 degrees, a sixth of its volume within 2 mm of an
    edge): what the creases' bias does where they are most of the shape, over ``CREASE_SEEDS`` draws."""
    corners = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]]) * 0.04 / np.sqrt(8)  # edge 40 mm
    mesh, _, _ = _posed(trimesh.Trimesh(corners).convex_hull, 3)
    rows = []
    for sigma in CREASE_SIGMAS:
        errors = [estimate(sample_surface(mesh, POINTS, seed=[5, seed], noise_sigma=sigma, with_normals=False),
                           1000.0).volume / mesh.volume - 1 for seed in range(CREASE_SEEDS)]
        rows.append(f"tetrahedron 40 mm  sigma {sigma * 1e3:.2f} mm | " + "  ".join(f"{100 * e:+7.3f} %" for e in errors))
    return rows


def box_rows() -> list[str]:
    half = np.array(BOX) / 2
    rows = []
    for seed in range(BOX_POSES):
        mesh, rotation, shift = _posed(trimesh.creation.box(BOX), seed)
        cloud = sample_surface(mesh, BOX_POINTS, seed=[5, seed], noise_sigma=0.0005, with_normals=False)
        cells = []
        for turn in (downsample.LATTICE_TURN, np.eye(3)):
            saved, downsample.LATTICE_TURN = downsample.LATTICE_TURN, turn
            try:
                est = estimate(cloud, 1000.0)
            finally:
                downsample.LATTICE_TURN = saved
            past = np.abs((est.vertices - shift) @ rotation) - half  # box frame, folded: > 0 outside a face
            face = np.argmax(past, axis=1)
            away = np.sort(past, axis=1)[:, 1] < -FACE_MARGIN  # the second nearest face is far: not near an edge
            offset = float(np.mean(past[away, face[away]]))
            cells.append(f"{_error(est.volume, mesh.volume)} % ({est.points_used:7,} points, faces {1e3 * offset:+6.3f} mm)")
        rows.append(f"box 20 x 16 x 12 cm pose {seed} | voxels turned {cells[0]} | along the axes {cells[1]}")
    return rows


def small_rows() -> list[str]:
    shapes = [(f"sphere r {r * 1e3:.0f} mm", trimesh.creation.icosphere(subdivisions=5, radius=r), r)
              for r in (0.005, 0.007, 0.010, 0.015)]
    shapes.append(("rod r 7 mm x 40", trimesh.creation.cylinder(radius=0.007, height=0.04, sections=128), 0.007))
    rows = []
    for name, shape, radius in shapes:
        mesh, _, _ = _posed(shape, 3)
        count = int(mesh.area / SMALL_SPACING**2)
        for sigma in SMALL_SIGMAS:
            errors = [estimate(sample_surface(mesh, count, seed=[seed], noise_sigma=sigma, with_normals=False),
                               1000.0).volume / mesh.volume - 1 for seed in range(SMALL_SEEDS)]
            rows.append(f"{name:16s} {count:5d} points  sigma {sigma * 1e3:.1f} mm (sigma / r {sigma / radius:.2f}) "
                        f"| median {100 * np.median(errors):+6.2f} %  range {100 * min(errors):+6.2f} .. {100 * max(errors):+6.2f} %")
    return rows


def main() -> None:
    lines = [f"bench/noise_bias.py: {POINTS:,} points, isotropic Gaussian noise, 'auto' without normals", ""]
    for row in sphere_rows() + cube_rows() + crease_rows() + box_rows():
        print(row, file=sys.stderr, flush=True)
        lines.append(row)
    lines += ["", f"small objects, points {SMALL_SPACING * 1e3:.1f} mm apart, median of {SMALL_SEEDS} draws"]
    for row in small_rows():
        print(row, file=sys.stderr, flush=True)
        lines.append(row)
    RESULTS.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
