"""Clouds sampled the way a laser line scanner samples: slices through the object a few millimetres apart, points a
few tenths of a millimetre apart along each. The spacing was read along the lines, the cell followed it, and the
gaps between the lines were holes the flood fill could not close: an 8 cm ball sliced every 2 mm came out -98 %, its
interval 0..inf m^3, its pole caps dropped as strays (an outside probe). ``spacing.line_gap`` measures
the gap between the lines; ``estimate._along_lines`` estimates from one point per voxel of it, and the stray filter
joins islands across it (``strays.islands``).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from estimation import estimate, make_cloud, spacing
from estimation.strays import islands

SPHERE = trimesh.creation.icosphere(subdivisions=5, radius=0.04)
BOX = trimesh.creation.box((0.1, 0.07, 0.05))
TORUS = trimesh.creation.torus(major_radius=0.04, minor_radius=0.015, major_sections=128, minor_sections=64)
SHAPES = {"sphere": SPHERE, "box": BOX, "torus": TORUS}


def line_scan(mesh: trimesh.Trimesh, gap: float, step: float, *, noise: float = 0.0, seed: int = 0) -> np.ndarray:
    """(n, 3) metres: ``mesh`` in a seeded random pose, cut by parallel planes ``gap`` metres apart along a seeded
    random direction (at a random phase), each cut sampled every ``step`` metres along its outline (from a random
    start), with Gaussian noise of sigma ``noise`` metres on every coordinate."""
    rng = np.random.default_rng(seed)
    posed = mesh.copy()
    pose = np.eye(4)
    pose[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    pose[:3, 3] = rng.uniform(-0.2, 0.2, 3)
    posed.apply_transform(pose)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    height = posed.vertices @ axis
    heights = np.arange(height.min() + rng.uniform(0, gap), height.max(), gap)
    lines = []
    for section in posed.section_multiplane(np.zeros(3), axis, heights):
        if section is None:
            continue
        for outline in section.discrete:
            outline = np.asarray(outline)
            length = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(outline, axis=0), axis=1))]
            t = np.arange(rng.uniform(0, step), length[-1], step)
            flat = np.column_stack([np.interp(t, length, outline[:, 0]), np.interp(t, length, outline[:, 1]),
                                    np.zeros(len(t)), np.ones(len(t))])
            lines.append((flat @ section.metadata["to_3D"].T)[:, :3])
    points = np.vstack(lines)
    return points + rng.normal(scale=noise, size=points.shape) if noise else points


def _even(mesh: trimesh.Trimesh, n: int, noise: float = 0.0, seed: int = 0) -> np.ndarray:
    points = np.asarray(trimesh.sample.sample_surface(mesh, n, seed=seed)[0])
    return points + np.random.default_rng([seed, 1]).normal(scale=noise, size=points.shape) if noise else points


def _grid(step: tuple[float, float], noise: float, seed: int = 0) -> np.ndarray:
    """A 10 x 7 x 5 cm box's faces sampled on a grid ``step`` metres apart (a depth camera's pixels on faces it sees
    obliquely are spaced a few times wider one way than the other)."""
    half, faces = np.array([0.05, 0.035, 0.025]), []
    for axis in range(3):
        u, v = [i for i in range(3) if i != axis]
        a, b = np.meshgrid(np.arange(-half[u], half[u], step[0]), np.arange(-half[v], half[v], step[1]))
        for side in (-1, 1):
            face = np.zeros((a.size, 3))
            face[:, u], face[:, v], face[:, axis] = a.ravel(), b.ravel(), side * half[axis]
            faces.append(face)
    points = np.vstack(faces)
    return points + np.random.default_rng(seed).normal(scale=noise, size=points.shape)


@pytest.mark.parametrize(("gap", "step", "noise"), [(0.002, 0.0002, 0.0), (0.004, 0.0001, 0.0), (0.003, 0.0002, 0.0002)])
def test_the_gap_between_lines_is_measured(gap, step, noise):
    # Slices `gap` apart along the axis meet the surface at lines at least `gap` apart on it, wider where it turns
    # towards the slices (a ball's poles); weighted by area the ball's median is 2 / sqrt(3) = 1.15 times `gap`. The
    # nearest of several noisy points across is nearer than their lines by some of the noise.
    points = line_scan(SPHERE, gap, step, noise=noise, seed=1)
    assert 0.95 * gap <= spacing.line_gap(points) <= 1.25 * gap
    assert spacing.point_spacing(points) < gap / 2  # what the cell followed: the spacing along the lines


@pytest.mark.parametrize("cloud", [
    lambda: _even(SPHERE, 40_000),
    lambda: _even(SPHERE, 40_000, noise=0.0005),  # inside the noise at its spacing: widened past it, still a surface
    lambda: _even(TORUS, 100_000, noise=0.001),
    lambda: _grid((0.001, 0.001), 0.0),
    lambda: _grid((0.001, 0.004), 0.0001),  # four times wider one way, as a depth camera at a grazing angle
    lambda: _grid((0.001, 0.004), 0.0003),
], ids=["even", "even-noisy", "torus-noise-1mm", "grid", "grid-1x4", "grid-1x4-noisy"])
def test_clouds_not_sampled_along_lines_have_no_gap(cloud):
    assert spacing.line_gap(cloud()) == 0.0


def test_the_lines_near_a_balls_poles_are_not_strays():
    # Near the poles the slices meet the surface far apart (7 mm for slices 2 mm apart on a 4 cm ball): at four
    # spacings along the lines (2 mm) the last few lines were islands of their own, and dropped.
    points = line_scan(SPHERE, 0.002, 0.0002, seed=0)
    found = islands(points, spacing.point_spacing(points))
    assert found.strays == 0 and found.parts == 1, (found.strays, found.part_shares)
    # The lines' gap does not hide true strays: 30 points in a 60 cm box around the ball, none within 2 cm of it.
    rng = np.random.default_rng(0)
    far = rng.uniform(-0.3, 0.3, size=(300, 3)) + points.mean(axis=0)
    far = far[np.linalg.norm(far - points.mean(axis=0), axis=1) > 0.06][:30]
    found = islands(np.r_[points, far], spacing.point_spacing(points))
    assert found.strays == 30 and not found.keep[len(points):].any()


#: (shape, gap, step, noise) metres: slices 2-4 mm apart, 0.1-0.3 mm along, clean and at sigma 0.2 mm. The quick ones
#: run by default; each case takes 1-8 s (a first pass and a refining pass at the spacing along the lines, then one
#: from the thinned lines).
SCANS = [
    ("sphere", 0.004, 0.0003, 0.0002),
    ("box", 0.004, 0.0003, 0.0),
    pytest.param("sphere", 0.002, 0.0002, 0.0, marks=pytest.mark.slow),
    pytest.param("box", 0.003, 0.0002, 0.0002, marks=pytest.mark.slow),
    pytest.param("torus", 0.004, 0.0003, 0.0, marks=pytest.mark.slow),
    pytest.param("torus", 0.002, 0.0001, 0.0002, marks=pytest.mark.slow),
]


@pytest.mark.parametrize(("shape", "gap", "step", "noise"), SCANS)
def test_a_line_scanned_cloud_is_estimated_from_its_lines_gap(shape, gap, step, noise):
    mesh = SHAPES[shape]
    est = estimate(make_cloud(line_scan(mesh, gap, step, noise=noise, seed=0)), 1000.0)
    low, high = est.volume_bounds_m3
    # At most 0.7 % off over these and two more seeds (0.3 % at seed 0); the cells are about the lines' gap, 1.8-5 mm.
    assert est.volume == pytest.approx(mesh.volume, rel=0.02)
    # The interval holds the truth and says something: it was 0..inf m^3 (one sheet round nothing).
    assert low <= mesh.volume <= high
    assert 0.9 * mesh.volume < low and high < 1.1 * mesh.volume, (low / mesh.volume, high / mesh.volume)
    assert any("lie along lines" in w for w in est.warnings), est.warnings
    assert not any("stray" in w or "separate parts" in w for w in est.warnings), est.warnings


@pytest.mark.slow
def test_an_evenly_sampled_cloud_says_nothing_of_lines():
    est = estimate(make_cloud(_even(SPHERE, 40_000)), 1000.0)
    assert est.volume == pytest.approx(SPHERE.volume, rel=0.001)
    assert not any("lines" in w for w in est.warnings)
