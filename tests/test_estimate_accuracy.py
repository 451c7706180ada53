"""The auto method against closed-form volumes and inertias, and its invariances.

Tolerances: the reconstruction's discretisation error is O(cell^2 * curvature) on smooth parts and a
rounding of about one cell along sharp edges; at the default 128 cells per side that is < 0.3 % of
volume on these shapes (measured: bench/paper_table.py), so 0.5 % volume and 2 % inertia leave room for
sampling noise at the test's 40k points.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from estimation import estimate
from scenes.sampling import sample_surface

RHO = 1000.0


def _closed_form_cases():
    r, h, R, a = 0.05, 0.12, 0.08, 0.03
    box = (0.2, 0.1, 0.06)
    m_box = np.prod(box) * RHO
    m_cyl = np.pi * r * r * h * RHO
    m_sph = 4 / 3 * np.pi * r**3 * RHO
    m_tor = 2 * np.pi**2 * R * a * a * RHO
    return {
        "box": (trimesh.creation.box(extents=box), m_box,
                m_box / 12 * np.array([box[1] ** 2 + box[2] ** 2, box[0] ** 2 + box[2] ** 2, box[0] ** 2 + box[1] ** 2])),
        "cylinder": (trimesh.creation.cylinder(radius=r, height=h, sections=256), m_cyl,
                     np.array([m_cyl * (3 * r * r + h * h) / 12] * 2 + [m_cyl * r * r / 2])),
        "sphere": (trimesh.creation.icosphere(subdivisions=5, radius=r), m_sph, np.array([0.4 * m_sph * r * r] * 3)),
        "torus": (trimesh.creation.torus(major_radius=R, minor_radius=a, major_sections=128, minor_sections=64), m_tor,
                  np.array([m_tor * (5 * a * a + 4 * R * R) / 8] * 2 + [m_tor * (3 * a * a + 4 * R * R) / 4])),
    }


@pytest.mark.parametrize("name", ["box", "cylinder", "sphere", "torus"])
@pytest.mark.parametrize("normals", ["given", "estimated"])
def test_auto_matches_closed_form(name, normals):
    mesh, mass, diag = _closed_form_cases()[name]
    cloud = sample_surface(mesh, 40_000, seed=1, with_normals=normals == "given")
    result = estimate(cloud, RHO)
    assert result.watertight
    assert result.mass.mass == pytest.approx(mass, rel=5e-3)
    size = float(np.max(mesh.extents))
    assert np.linalg.norm(result.mass.center_of_mass) < 2e-3 * size
    err = np.linalg.norm(result.mass.inertia - np.diag(diag)) / np.linalg.norm(diag)
    assert err < 0.02


@pytest.mark.parametrize("seed", [2, 3])
@pytest.mark.parametrize("shape", ["cube", "prism"])
def test_exact_normals_leave_no_spikes_at_convex_creases(shape, seed):
    # Beyond a convex crease the other face's planes extend past the edge and read the outside as
    # inside; trusted as measured (and spread outward from there), such nodes grew spikes along the
    # edges 3.0 cells out of the faces with exact normals. Now, over 8 draws of the points (the pose does
    # not matter: the box frame takes it out), the cube 0.62-0.80 cells and the 60-degree prism 0.93-1.84
    # (0.63-0.97 and 0.81-1.59 before the thinning's voxels were turned off the box frame's axes): a crease is
    # resolved to about a cell, plus the half cell a vertex may leave its cell by, and which points the
    # thinning keeps moves the largest by half a cell.
    if shape == "cube":
        mesh = trimesh.creation.box(extents=(0.06, 0.06, 0.06))
    else:  # a triangular prism: 60 degree creases
        mesh = trimesh.creation.extrude_triangulation(np.array([(0, 0), (0.06, 0), (0.03, 0.052)]), np.array([[0, 1, 2]]), 0.05)
    rotation = Rotation.random(random_state=7).as_matrix()
    mesh.apply_transform(np.vstack([np.hstack([rotation, [[0.01], [0.02], [0.03]]]), [0, 0, 0, 1]]))
    result = estimate(sample_surface(mesh, 200_000, seed=seed, with_normals=True), RHO)
    # A convex mesh: a vertex's distance outside is its largest height over the face planes.
    heights = (result.vertices @ mesh.face_normals.T) - np.einsum("ij,ij->i", mesh.face_normals, mesh.triangles[:, 0])
    assert heights.max(axis=1).max() < 2.0 * result.cell


def test_estimated_normals_point_outward(torus_mesh, torus_cloud):
    from scipy.spatial import cKDTree

    from estimation.estimate import estimate as run

    result = run(torus_cloud.without_normals(), RHO)
    # Every reconstructed face normal agrees with the true surface normal nearest to it.
    tri = result.vertices[result.faces]
    centres = tri.mean(axis=1)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    _, idx = cKDTree(torus_cloud.points).query(centres)
    agree = np.einsum("ij,ij->i", normals, torus_cloud.normals[idx]) > 0
    assert agree.mean() > 0.99


def test_noise_half_millimetre_without_normals(torus_mesh):
    cloud = sample_surface(torus_mesh, 60_000, seed=3, noise_sigma=0.0005, with_normals=False)
    result = estimate(cloud, RHO)
    assert result.volume == pytest.approx(torus_mesh.volume, rel=0.02)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_noisy_curved_cloud_is_not_inflated_by_the_reconstruction(seed):
    # 100k points: thinned to the point budget. Sigma 0.5 mm on a 15 mm sphere lifts the points' mean by
    # 0.33 % of the volume; thinning one point per voxel, and contouring the noisy faces as creases, each
    # added as much again (+1.0 to +1.4 % before d81f140).
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.015)
    sphere.apply_transform(np.vstack([np.hstack([Rotation.random(random_state=seed).as_matrix(), [[0.1], [0.2], [0.3]]]),
                                      [0, 0, 0, 1]]))
    cloud = sample_surface(sphere, 100_000, seed=seed, noise_sigma=0.0005, with_normals=False)
    result = estimate(cloud, RHO)
    assert result.volume == pytest.approx(sphere.volume, rel=0.004)


@pytest.mark.parametrize("count", [3_000, 10_000])
def test_sparse_clouds_degrade_gracefully(torus_mesh, count):
    cloud = sample_surface(torus_mesh, count, seed=4, with_normals=False)
    result = estimate(cloud, RHO)
    assert result.watertight
    assert result.volume == pytest.approx(torus_mesh.volume, rel=0.02)


def test_viewpoint_orients_visible_side_outward():
    from estimation.normals import estimate_normals, orient_to_viewpoint

    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.1)
    cloud = sample_surface(mesh, 5_000, seed=5, with_normals=False)
    front = cloud.points[cloud.points[:, 2] > 0.02]  # what a sensor above the sphere sees
    normals = orient_to_viewpoint(front, estimate_normals(front), np.array([0.0, 0.0, 2.0]))
    outward = np.einsum("ij,ij->i", normals, front / np.linalg.norm(front, axis=1, keepdims=True))
    assert (outward > 0.9).mean() > 0.99


def _shape(kind: str) -> trimesh.Trimesh:
    if kind == "box":
        return trimesh.creation.box(extents=(1.0, 0.6, 0.35))
    if kind == "capsule":
        return trimesh.creation.capsule(height=0.8, radius=0.3, count=[64, 64])
    return trimesh.creation.torus(major_radius=0.5, minor_radius=0.2, major_sections=96, minor_sections=48)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    kind=st.sampled_from(["box", "capsule", "torus"]),
    size=st.floats(0.01, 1.0),
    quat=st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1),
    shift=st.lists(st.floats(-20, 20), min_size=3, max_size=3),
    normals=st.booleans(),
)
@pytest.mark.slow
def test_error_does_not_depend_on_pose_or_size(kind, size, quat, shift, normals):
    mesh = _shape(kind)
    mesh.apply_scale(size / float(np.max(mesh.extents)))
    transform = np.eye(4)
    transform[:3, :3] = Rotation.from_quat(quat).as_matrix()
    transform[:3, 3] = shift
    mesh.apply_transform(transform)
    cloud = sample_surface(mesh, 30_000, seed=6, with_normals=normals)
    result = estimate(cloud, RHO)
    assert result.volume == pytest.approx(mesh.volume, rel=5e-3)
    assert np.linalg.norm(result.mass.center_of_mass - mesh.center_mass) < 5e-3 * size


@pytest.mark.parametrize("seed", [0, 1])
def test_a_small_ball_with_a_hole_in_its_cloud_is_not_hollow(seed):
    """A 66 mm ball at sigma 0.8 mm with a 20 mm patch no camera saw (as a ring of three cameras left one on
    the tennis ball of clutter20): the coarse flood fill needs a 3-cell shell to close the hole, and the ball
    keeps about a third of its surface's node count inside. Refused as crumbs, it came out a hollow shell
    (-50 %)."""
    from estimation import make_cloud

    rng = np.random.default_rng(seed)
    radius = 0.033
    dirs = rng.normal(size=(9000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hole = np.array([np.cos(0.5), -np.sin(0.5), 0.0])  # on the equator
    dirs = dirs[dirs @ hole < np.cos(0.010 / radius)]  # a cap 20 mm across
    points = radius * dirs + rng.normal(scale=0.0008, size=dirs.shape)
    est = estimate(make_cloud(points, dirs), 1000.0)
    assert est.volume == pytest.approx(4 / 3 * np.pi * radius**3, rel=0.02)


def test_a_box_with_a_whole_face_unseen_says_so_and_its_interval_holds_the_truth():
    """A 28 x 19 x 7 cm box with one 28 x 7 cm face unseen (as a face of clutter20's cereal box near the
    table's edge was): no closing radius closes a hole that size, the flood fill runs inside and the surface
    is a shell round nothing. The estimate cannot know the volume; its interval must reach the truth (up to
    the convex hull) and a warning must say the cloud is open."""
    box = trimesh.creation.box(extents=(0.28, 0.19, 0.07))
    cloud = sample_surface(box, 60_000, seed=0, noise_sigma=0.001, with_normals=True)
    keep = cloud.points[:, 1] > -0.19 / 2 + 0.003  # the -y face (28 x 7 cm) is not seen
    from estimation import make_cloud

    est = estimate(make_cloud(cloud.points[keep], cloud.normals[keep]), 1000.0)
    low, high = est.volume_bounds_m3
    assert low <= box.volume <= high
    # Said as the points facing only part of the surface built round them (the shell's inner face), which
    # leaves the volume unbounded, or, before that check, as the cloud being open (up to the convex hull).
    assert any("points face only" in w and "holes wider than the flood fill closes" in w for w in est.warnings)
