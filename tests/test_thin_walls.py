"""Thin parts: the noise is read on a wall's own face, a hollow ball whose wall the noise hides says so, and a
noisy wire thinner than the flood fill's cells keeps its normals pointing out."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from estimation import estimate, make_cloud
from estimation.spacing import surface_noise
from scenes.sampling import sample_surface
from scenes.shapes import bottle, closed_box, coil, hollow_ball, open_pipe


@pytest.mark.parametrize("sigma", [0.0001, 0.0005, 0.001])
def test_noise_of_a_solid_is_read(sigma):
    mesh = trimesh.creation.box(extents=(0.08, 0.06, 0.05))
    cloud = sample_surface(mesh, 100_000, seed=1, noise_sigma=sigma, with_normals=False)
    assert surface_noise(cloud.points) == pytest.approx(sigma, rel=0.1)


@pytest.mark.parametrize("sigma", [0.0001, 0.0005])
def test_a_walls_other_face_is_not_read_as_noise(sigma):
    # A 3 mm wall, about three point spacings: the patches that measure the noise reach the other face.
    # Before they were cut down to their own face this read 1.5 mm at both sigmas.
    cloud = sample_surface(hollow_ball(0.06, 0.003, 0.012), 100_000, seed=1, noise_sigma=sigma, with_normals=False)
    assert surface_noise(cloud.points) == pytest.approx(sigma, rel=0.15)


@pytest.mark.parametrize("extents", [(0.3, 0.03, 0.002), (0.1, 0.1, 0.002)])
def test_a_clean_plate_two_spacings_thick_reads_no_noise_and_keeps_its_thickness(extents):
    # 20,000 points, about 1 mm apart, on a 2 mm plate: the sheet cut measured its own face exactly (0), took 0
    # for "no spread yet" and kept the other face in its next pass: 0.98 mm of noise, cells of 2 mm and a
    # 300 x 30 x 2 mm ruler 3.3x its volume (interval 0 to unbounded).
    mesh = trimesh.creation.box(extents=extents)
    mesh.apply_transform(trimesh.transformations.random_rotation_matrix(np.random.default_rng(0).random(3)))
    cloud = sample_surface(mesh, 20_000, seed=0, with_normals=False)
    assert surface_noise(cloud.points, own_sheet=True) < 1e-6
    result = estimate(make_cloud(cloud.points), 1000.0)
    assert result.volume == pytest.approx(mesh.volume, rel=0.05)
    assert result.volume_bounds_m3[0] <= mesh.volume <= result.volume_bounds_m3[1]


def test_a_thin_walled_ball_with_a_little_noise_is_not_filled_solid():
    # With the wall read as 1.5 mm of noise the cell was the wall's thickness and the ball came out solid:
    # +558 %, no warning.
    mesh = hollow_ball(0.06, 0.003, 0.012)
    cloud = sample_surface(mesh, 100_000, seed=1, noise_sigma=0.0001, with_normals=False)
    result = estimate(make_cloud(cloud.points), 1000.0)
    assert result.volume == pytest.approx(mesh.volume, rel=0.01)
    assert np.isfinite(result.mass.mass)


@pytest.mark.slow
def test_a_hollow_ball_whose_wall_is_six_sigmas_thick_is_not_filled():
    # Sigma 0.5 mm on a 3 mm wall, no normals: the faces' noisy shells touch, no inside between them is found,
    # and only the widest closing shell encloses anything, by sealing the ball's mouth. That was taken as the
    # inside (+560 %, said in a warning); the points' density between the faces shows it is air (hollows.py).
    mesh = hollow_ball(0.06, 0.003, 0.012)
    cloud = sample_surface(mesh, 100_000, seed=1, noise_sigma=0.0005, with_normals=False)
    result = estimate(make_cloud(cloud.points), 1000.0)
    assert result.volume == pytest.approx(mesh.volume, rel=0.02)
    low, high = result.volume_bounds_m3
    assert low <= mesh.volume <= high


@pytest.mark.parametrize("seed", [1, 2])
def test_a_noisy_wire_thinner_than_the_flood_cells_is_not_filled(seed):
    # A 4 mm wire under 0.5 mm noise, no normals: the coarse cells are 2.3 mm and the shell encloses nothing.
    # The orientation probe looked two cells along each normal, across the wire to the outside beyond it,
    # and flipped ~9 % of the normals: the coil's gaps filled, +38 % and +45 % at these seeds.
    mesh = coil(wire=0.004, radius=0.015, turns=4, pitch=0.01)
    cloud = sample_surface(mesh, 30_000, seed=seed, noise_sigma=0.0005, with_normals=False)
    result = estimate(make_cloud(cloud.points), 1000.0)
    # 30k points at the noise limit leave it about 10 % short whichever way the normals point, and the last digit
    # of the noise reading moves that (seed 2: -9.7 %, -9.1 % and -10.2 % at three noise readings 0.74-0.75 mm).
    assert result.volume == pytest.approx(mesh.volume, rel=0.15)
    # The normals the estimate used point out of the wire: away from the helix's centre line.
    points, normals = np.asarray(result.points, float), np.asarray(result.normals, float)
    t = np.linspace(0.0, 2 * np.pi * 4, 20_000)
    line = np.c_[0.015 * np.cos(t), 0.015 * np.sin(t), 0.01 * t / (2 * np.pi)]
    from scipy.spatial import cKDTree

    _, nearest = cKDTree(line).query(points)
    outward = np.einsum("ij,ij->i", normals, points - line[nearest]) > 0
    assert outward.mean() > 0.97  # 0.91 and 0.89 before


@pytest.mark.parametrize("seed", [1, pytest.param(2, marks=pytest.mark.slow)])  # 4-5 s each: one in the default run
def test_a_noisy_3mm_plate_keeps_its_thickness(seed):
    # Six sigmas thick: a point the noise moved into the plate has the other face nearly as close as its own,
    # its wide normal patch spanned both and turned sideways, and only the points moved outward kept planes
    # facing out: +1.8 % (0.03 mm on each face). Each patch is now fitted again on its own sheet.
    mesh = trimesh.creation.box(extents=(0.06, 0.05, 0.003))
    cloud = sample_surface(mesh, 60_000, seed=seed, noise_sigma=0.0005, with_normals=False)
    result = estimate(make_cloud(cloud.points), 1000.0)
    assert result.volume == pytest.approx(mesh.volume, rel=0.01)


@pytest.mark.parametrize("seed", [1, pytest.param(2, marks=pytest.mark.slow)])  # 8 s each: one in the default run
def test_a_dense_noisy_wire_ring_fits_its_normals_wider_than_the_noise(seed):
    # A 3.2 mm wire at sigma 0.5 mm, sampled densely: the 96 nearest neighbours (the cap on the normal fit) lie
    # within ~0.55 mm, inside the noise slab, and their planes follow the noise. Most cells were then taken for
    # creases, their vertices put on the tangent planes outside the wire: +4 to +6 % on bench/thin_parts.py's
    # rings. The fit now draws its neighbours from a thinned share of the points (estimate._spread_neighbours).
    mesh = trimesh.creation.torus(0.015, 0.0016, major_sections=96, minor_sections=24)
    cloud = sample_surface(mesh, 100_000, seed=seed, noise_sigma=0.0005, with_normals=False)
    result = estimate(make_cloud(cloud.points), 1000.0)
    assert result.volume == pytest.approx(mesh.volume, rel=0.02)


def test_a_bottle_whose_mouth_the_closing_shell_seals_is_not_filled_with_given_normals():
    # 3 mm walls, a 20 mm mouth on a 70 mm body: the flood fill's closing shell seals the mouth, and the body's
    # air was taken as inside (+250 %). The inner wall's normals say the air is outside.
    mesh = bottle()
    cloud = sample_surface(mesh, 100_000, seed=1, with_normals=True)
    result = estimate(make_cloud(cloud.points, cloud.normals), 1000.0)
    assert result.volume == pytest.approx(mesh.volume, rel=0.01)
    low, high = result.volume_bounds_m3
    assert low <= mesh.volume <= high


@pytest.mark.parametrize("sigma", [0.0, 0.0005])
def test_a_long_pipes_wall_is_not_read_as_noise(sigma):
    # 100k points, 1.4 mm apart on a 3 mm wall: the first noise patch reached the other face and its plane,
    # tilted by it, read the gap as noise: 1.5 mm clean, 1.57 mm at sigma 0.5 mm.
    cloud = sample_surface(open_pipe(), 100_000, seed=1, noise_sigma=sigma, with_normals=False)
    if sigma:
        assert surface_noise(cloud.points, own_sheet=True) == pytest.approx(sigma, rel=0.2)
    else:
        assert surface_noise(cloud.points, own_sheet=True) < 0.0002


def test_a_long_open_pipe_without_normals_is_not_filled():
    # The noise read as 1.5 mm set 3 mm cells, and the coarse grid's 128 cells along 600 mm were 5.5 mm:
    # neither saw into the wall, and the pipe came out solid (+180 %).
    mesh = open_pipe()
    cloud = sample_surface(mesh, 100_000, seed=1, with_normals=False)
    result = estimate(make_cloud(cloud.points), 1000.0)
    assert result.volume == pytest.approx(mesh.volume, rel=0.01)


@pytest.mark.parametrize("shape", ["closed box", "closed ball", "bottle"])
def test_air_that_the_flood_fill_encloses_is_not_filled_without_normals(shape):
    # A closed box or ball with 2-3 mm walls, and a bottle whose mouth the closing shell seals: the shell
    # encloses the air, and without normals nothing said it was not the inside: +264 %, +553 %, +385 %.
    mesh = {"closed box": lambda: closed_box(0.003), "closed ball": lambda: hollow_ball(0.04, 0.002, 0.0),
            "bottle": bottle}[shape]()
    cloud = sample_surface(mesh, 100_000, seed=1, with_normals=False)
    result = estimate(make_cloud(cloud.points), 1000.0)
    assert result.volume == pytest.approx(mesh.volume, rel=0.01)
    low, high = result.volume_bounds_m3
    assert low <= mesh.volume <= high


def test_a_closed_boxs_noise_is_read_where_it_is_most_of_a_spacing():
    # 3 mm walls at sigma 0.5 mm, 0.8 mm apart: the plane of a sample's nearest few points follows the noise;
    # started from it alone, the sheet cut read 1.56 mm (the walls' gap).
    cloud = sample_surface(closed_box(0.003), 100_000, seed=1, noise_sigma=0.0005, with_normals=False)
    assert surface_noise(cloud.points, own_sheet=True) == pytest.approx(0.0005, rel=0.1)
    assert surface_noise(cloud.points) == pytest.approx(0.0005, rel=0.1)


def test_a_closed_box_with_walls_six_sigmas_thick_is_not_filled():
    # Sigma 0.5 mm on 3 mm walls: the nearest-point test's reach (2.5 sigma) merges the two faces, and the box
    # came out filled (+269 %); the points' density between the faces tells them apart.
    mesh = closed_box(0.003)
    cloud = sample_surface(mesh, 100_000, seed=0, noise_sigma=0.0005, with_normals=False)
    result = estimate(make_cloud(cloud.points), 1000.0)
    assert result.volume == pytest.approx(mesh.volume, rel=0.02)
    low, high = result.volume_bounds_m3
    assert low <= mesh.volume <= high


def test_points_in_two_sheets_about_a_surface_are_told_from_one():
    from estimation.sheets import spread_about

    rng = np.random.default_rng(0)
    n = 20_000
    xy = rng.uniform(-0.05, 0.05, (n, 2))
    surface = np.column_stack([rng.uniform(-0.05, 0.05, (2000, 2)), np.zeros(2000)])
    up = np.tile([0.0, 0.0, 1.0], (len(surface), 1))
    one = np.column_stack([xy, rng.normal(0, 0.0005, n)])
    two = np.column_stack([xy, rng.normal(0, 0.0005, n) + np.where(rng.random(n) < 0.5, -0.001, 0.001)])
    single, double = spread_about(one, surface, up), spread_about(two, surface, up)
    assert not single.two_sheets and single.kurtosis == pytest.approx(3.0, abs=0.25)
    assert single.spread == pytest.approx(0.0005, rel=0.05)
    assert double.two_sheets
    assert double.separation == pytest.approx(0.002, rel=0.1)


@pytest.mark.parametrize("wall", [0.002, 0.0025])
def test_a_hollow_ball_whose_wall_the_noise_merged_says_so(wall):
    # Walls of four and five sigmas: the faces' points merge into one sheet, the flood fill sees one surface
    # and the ball comes out solid (+552 %, +418 %). That was said nowhere, and the interval held only the solid.
    mesh = hollow_ball(0.04, wall)
    cloud = sample_surface(mesh, 100_000, seed=0, noise_sigma=0.0005, with_normals=False)
    result = estimate(make_cloud(cloud.points), 1000.0)
    assert any("two sheets" in w and "hollow" in w for w in result.warnings), result.warnings
    low, high = result.volume_bounds_m3
    assert low <= mesh.volume <= high


@pytest.mark.parametrize("mesh", [  # 5-7 s each: the thin wall in the default run, the solid ones in the slow one
    pytest.param(hollow_ball(0.04, 0.004), id="4mm-wall"),
    pytest.param(trimesh.creation.icosphere(4, 0.03), id="ball", marks=pytest.mark.slow),
    pytest.param(trimesh.creation.box(extents=(0.05, 0.03, 0.02)), id="box", marks=pytest.mark.slow)])
def test_one_noisy_face_is_not_taken_for_two(mesh):
    cloud = sample_surface(mesh, 100_000, seed=2, noise_sigma=0.0005, with_normals=False)
    result = estimate(make_cloud(cloud.points), 1000.0)
    assert not any("two sheets" in w for w in result.warnings), result.warnings


def _holed_ball() -> trimesh.Trimesh:
    """A 40 mm ball with a 2.5 mm wall and three 8 mm holes through it along the axes."""
    ball = trimesh.boolean.difference([trimesh.creation.icosphere(5, 0.04), trimesh.creation.icosphere(5, 0.0375)],
                                      engine="manifold")
    for axis in ([1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]):
        bore = trimesh.creation.cylinder(radius=0.004, height=0.12)
        bore.apply_transform(trimesh.geometry.align_vectors([0, 0, 1.0], axis))
        ball = trimesh.boolean.difference([ball, bore], engine="manifold")
    return ball


def test_a_holed_ball_whose_wall_is_two_spacings_thick_is_not_filled_in_silence():
    # 20k clean points, 1.34 mm apart: the two faces of the 2.5 mm wall were one sheet to the parity rays, the
    # closing shell sealed the holes, and the ball came out filled, +432 %, its interval (+400..+463 %) nowhere
    # near the truth. The finer reach opens its air; the wall is then too thin for the cells, and says so.
    mesh = _holed_ball()
    points, _ = trimesh.sample.sample_surface(mesh, 20_000, seed=0)
    result = estimate(make_cloud(points), 1000.0)
    low, high = result.volume_bounds_m3
    assert low <= mesh.volume <= high
    assert result.volume < 2 * mesh.volume


def _i_beam(length: float, height: float, width: float, flange: float, web: float) -> trimesh.Trimesh:
    import manifold3d

    h, w, tf, tw = height / 2, width / 2, flange, web / 2
    section = np.array([(-w, -h), (w, -h), (w, -h + tf), (tw, -h + tf), (tw, h - tf), (w, h - tf), (w, h), (-w, h),
                        (-w, h - tf), (-tw, h - tf), (-tw, -h + tf), (-w, -h + tf)])
    solid = manifold3d.Manifold.extrude(manifold3d.CrossSection([section]), length).to_mesh()
    return trimesh.Trimesh(np.asarray(solid.vert_properties)[:, :3], np.asarray(solid.tri_verts))


def test_a_web_the_point_cap_would_merge_is_estimated_on_every_point(monkeypatch):
    # The refining pass's cap thinned a 1 m I-beam's 4 mm web from 2.3 spacings (200,000 points) to 1.8 (120,000):
    # its faces merged, +7 to +24 %, the interval unbounded. Here the same proportions, scaled down to run fast:
    # a 2.3 mm web, 50,000 points, a 30,000-point cap.
    from estimation import tolerances as tol

    mesh = _i_beam(0.3, 0.04, 0.02, 0.003, 0.0023)
    mesh.apply_transform(trimesh.transformations.random_rotation_matrix(np.random.default_rng(0).random(3)))
    cloud = make_cloud(sample_surface(mesh, 50_000, seed=0, with_normals=False).points)
    monkeypatch.setattr(tol, "POINT_BUDGET", 8_000)
    monkeypatch.setattr(tol, "REFINE_POINTS", 30_000)

    result = estimate(cloud, 1000.0)
    assert result.volume == pytest.approx(mesh.volume, rel=0.01)
    assert result.volume_bounds_m3[0] <= mesh.volume <= result.volume_bounds_m3[1]
    assert result.volume_bounds_m3[1] - result.volume_bounds_m3[0] < 0.05 * mesh.volume

    monkeypatch.setattr(tol, "FULL_POINTS", 30_000)  # no pass past the cap: what the beam got
    capped = estimate(cloud, 1000.0)
    assert capped.volume > 1.2 * mesh.volume and capped.volume_bounds_m3[1] == float("inf")


def test_a_scan_of_one_side_does_not_take_more_points_past_the_cap(monkeypatch):
    # Its doubt is the unseen half, which no number of points measures: a 300,000-point scan of three faces of a
    # box took 23 s in passes past the cap instead of 5 s, for the same answer.
    import importlib

    from estimation import tolerances as tol

    mesh = trimesh.creation.box(extents=(0.2, 0.15, 0.1))
    points = sample_surface(mesh, 120_000, seed=0, with_normals=False).points
    facing = np.abs(points) / np.array([0.1, 0.075, 0.05])
    axis = np.argmax(facing, axis=1)
    outward = np.zeros_like(points)
    outward[np.arange(len(points)), axis] = np.sign(points[np.arange(len(points)), axis])
    seen = np.einsum("ij,ij->i", np.array([0.5, 0.4, 0.6]) - points, outward) > 0
    cloud = make_cloud(points[seen])
    monkeypatch.setattr(tol, "POINT_BUDGET", 8_000)
    monkeypatch.setattr(tol, "REFINE_POINTS", 20_000)
    module = importlib.import_module("estimation.estimate")  # the module: ``estimation.estimate`` is the function
    budgets: list[int] = []
    one_pass = module._auto_pass

    def counted(*args, **kwargs):  # type: ignore[no-untyped-def]
        budgets.append(args[5])  # (cloud, box, local, spacing, noise, budget, ...)
        return one_pass(*args, **kwargs)

    monkeypatch.setattr(module, "_auto_pass", counted)
    result = estimate(cloud, 1000.0)
    assert result.volume_bounds_m3[1] == float("inf")  # said: one sheet, nothing behind it
    assert budgets == [8_000, 20_000] and result.points_used <= 20_000

    monkeypatch.setattr(tol, "MEASURED_GAIN", 2.0)  # the gate open: a pass past the cap runs
    budgets.clear()
    estimate(cloud, 1000.0)
    assert budgets == [8_000, 20_000, len(cloud)]
