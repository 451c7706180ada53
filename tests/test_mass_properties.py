"""Closed-form checks of the one volume/inertia function, and of the paper's formula against it."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from estimation.inertia import mass_properties


def test_box_matches_closed_form():
    a, b, c, rho = 0.3, 0.2, 0.1, 700.0
    box = trimesh.creation.box(extents=(a, b, c))
    box.apply_translation([1.0, -2.0, 0.5])
    p = mass_properties(box.vertices, box.faces, rho)
    m = a * b * c * rho
    assert p.volume == pytest.approx(a * b * c, rel=1e-12)
    assert p.mass == pytest.approx(m, rel=1e-12)
    np.testing.assert_allclose(p.center_of_mass, [1.0, -2.0, 0.5], atol=1e-12)
    expected = m / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    np.testing.assert_allclose(p.inertia, expected, rtol=1e-10, atol=1e-15)
    np.testing.assert_allclose(p.principal_moments, np.sort(np.diag(expected)), rtol=1e-10)
    assert np.linalg.det(p.principal_axes) == pytest.approx(1.0)


def test_rotated_box_inertia_is_rotated():
    box = trimesh.creation.box(extents=(0.3, 0.2, 0.1))
    r = trimesh.transformations.random_rotation_matrix(rand=np.array([0.1, 0.7, 0.3]))
    p0 = mass_properties(box.vertices, box.faces, 1000.0)
    box.apply_transform(r)
    p1 = mass_properties(box.vertices, box.faces, 1000.0)
    np.testing.assert_allclose(p1.inertia, r[:3, :3] @ p0.inertia @ r[:3, :3].T, atol=1e-12)


def test_apex_does_not_matter_for_closed_mesh():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    a = mass_properties(sphere.vertices, sphere.faces, 1.0)
    b = mass_properties(sphere.vertices, sphere.faces, 1.0, apex=np.array([5.0, 5.0, 5.0]))
    assert a.volume == pytest.approx(b.volume, rel=1e-9)
    # The far apex costs ~1e-14 of absolute rounding on moments of ~1e-6.
    np.testing.assert_allclose(a.inertia, b.inertia, rtol=1e-6, atol=1e-12)


def _paper_signed_tetra_volume(vertices, faces, face_normals, apex):
    """The paper's formula, literally: |det| / 6 per face, signed by n . (v1 - apex)."""
    total = 0.0
    for f, n in zip(faces, face_normals, strict=True):
        v1, v2, v3 = vertices[f]
        vol = abs(np.linalg.det(np.stack([v1 - apex, v2 - apex, v3 - apex]))) / 6
        total += vol if np.dot(v1 - apex, n) >= 0 else -vol
    return total


def test_paper_sign_rule_equals_oriented_faces_about_the_apex():
    # An open mesh (a hemisphere shell) so the apex matters, as in the paper.
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    keep = sphere.triangles_center[:, 2] > 0
    verts, faces = sphere.vertices, sphere.faces[keep]
    normals = sphere.face_normals[keep]
    apex = np.array([0.01, -0.02, 0.03])
    slow = _paper_signed_tetra_volume(verts, faces, normals, apex)
    fast = mass_properties(verts, faces, 1.0, apex=apex).volume
    assert fast == pytest.approx(slow, rel=1e-9)


def test_matches_trimesh_on_closed_meshes(torus_mesh):
    mesh = torus_mesh.copy()
    mesh.apply_translation([0.3, -0.1, 0.2])
    ours = mass_properties(mesh.vertices, mesh.faces, 800.0)
    mesh.density = 800.0
    assert ours.volume == pytest.approx(mesh.volume, rel=1e-10)
    np.testing.assert_allclose(ours.center_of_mass, mesh.center_mass, atol=1e-12)
    np.testing.assert_allclose(ours.inertia, mesh.moment_inertia, rtol=1e-8, atol=1e-14)


def test_inside_out_mesh_is_an_error():
    from estimation.errors import ReconstructionError

    box = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    with pytest.raises(ReconstructionError, match="no positive volume"):
        mass_properties(box.vertices, box.faces[:, ::-1], 1000.0)
