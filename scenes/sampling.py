"""Surface sampling: what a perfect full-view scanner would see, like the paper's CloudCompare samples."""

from __future__ import annotations

import numpy as np
import trimesh

from estimation.cloud import PointCloud


def sample_surface(
    mesh: trimesh.Trimesh,
    count: int,
    *,
    seed: int | np.random.Generator | None = 0,
    noise_sigma: float = 0.0,
    with_normals: bool = True,
) -> PointCloud:
    """Uniform area-weighted random points on ``mesh`` with their face normals.

    Args:
        mesh: a watertight mesh, metres.
        count: number of points.
        seed: seed or generator; the same seed gives the same cloud.
        noise_sigma: standard deviation (metres) of isotropic Gaussian noise added to every point.
        with_normals: keep the face normals (a scanner with viewpoint-based normals) or drop them.
    """
    rng = np.random.default_rng(seed)
    points, face = trimesh.sample.sample_surface(mesh, count, seed=rng)
    if noise_sigma > 0:
        points = points + rng.normal(scale=noise_sigma, size=points.shape)
    normals = mesh.face_normals[face] if with_normals else None
    return PointCloud(np.ascontiguousarray(points), None if normals is None else np.ascontiguousarray(normals))
