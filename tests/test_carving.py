"""Closing what no camera saw: space carving from depth images and the mirror image.

Carving runs on real ray-cast depth images of a MuJoCo table with a box (tests/test_cameras.py's scene);
the mirror test on exact synthetic clouds of shapes that are and are not their own horizontal mirror image.
"""

from __future__ import annotations

import numpy as np
import pytest

from estimation.carving import (
    SILHOUETTE_PIXELS,
    carve,
    carved_surface,
    carving_views,
    free_space,
    silhouette_reach,
)
from estimation.completion import (
    MIRROR_MIN_POINTS,
    flat_top,
    mirror_image,
    resting_on,
)
from estimation.segmentation import Plane
from scenes.cameras import EXACT, CameraFeed
from tests.test_cameras import BOX, TABLE_TOP, VOLUME, WORKSPACE, _model, _rig

FLOOR = Plane(np.array([0.0, 0.0, 1.0]), 0.0, 0.0, 0)


def _scan(count: int, noise=EXACT):  # type: ignore[no-untyped-def]
    model, data = _model({"a": (0.02, 0.01)})
    return CameraFeed(_rig(count), WORKSPACE, noise=noise).scan(model, data)


def _inside_box(points: np.ndarray) -> np.ndarray:
    lo = np.array([0.02 - BOX[0] / 2, 0.01 - BOX[1] / 2, TABLE_TOP])
    return ((points >= lo) & (points <= lo + BOX)).all(axis=1)


def test_free_space_is_empty_space_and_never_the_object():
    scan = _scan(3)
    rng = np.random.default_rng(0)
    lo = np.array([-0.1, -0.1, TABLE_TOP + 0.003])
    probe = lo + rng.random((20000, 3)) * [0.24, 0.22, 0.1]
    free = free_space(probe, scan.views, slack=0.002)  # about a pixel's footprint
    inside = _inside_box(probe)
    assert not free[inside].any()  # nothing inside the box is carved (exact depth)
    # Around the box at 3 cameras, most of the empty space is seen through.
    assert free[~inside].mean() > 0.8


def test_a_point_reaches_past_itself_what_its_camera_pixel_spans_on_its_own_surface():
    # A camera 1 m away, 30 degrees above the level: on a level top a pixel spans pitch / sin(30 deg) along
    # the view, away from the camera; on an upright face facing it, pitch / cos(30 deg) down it, not back;
    # past a ball's limb (incidence 90 degrees) no further than on the level surface along the same ray.
    from estimation.carving import DepthView
    from estimation.fusion import Intrinsics

    elevation = np.radians(30.0)
    camera = np.array([-np.cos(elevation), 0.0, np.sin(elevation)])
    view = DepthView(np.zeros((2, 2)), 0.0, Intrinsics(500.0, 500.0, 1.0, 1.0, 2, 2), np.eye(3), camera)
    pitch = SILHOUETTE_PIXELS * 1.0 / 500.0
    at = np.zeros((3, 3))
    level, upright = np.array([0.0, 0.0, 1.0]), np.array([-1.0, 0.0, 0.0])
    limb = np.cross(camera, [0.0, 1.0, 0.0])
    limb /= np.linalg.norm(limb)  # perpendicular to the ray, in the vertical plane of the view
    reach = silhouette_reach(at, np.tile(camera, (3, 1)), np.stack([level, upright, limb]), [view], level)
    away = np.array([1.0, 0.0, 0.0])
    np.testing.assert_allclose(reach[0, 0], away * pitch / np.sin(elevation), rtol=1e-9)
    np.testing.assert_allclose(np.abs(reach[0, 1]), [0.0, pitch, 0.0], atol=1e-12)
    np.testing.assert_allclose(reach[1, 0], [0.0, 0.0, -pitch / np.cos(elevation)], atol=1e-12)
    assert np.linalg.norm(reach[2, 0]) == pytest.approx(pitch / np.sin(elevation))
    # An origin that is no camera's: not known.
    assert np.isnan(silhouette_reach(at[:1], camera[None] + 0.01, level[None], [view], level)).all()


@pytest.mark.parametrize(("fx", "fy"), [(400.0, 100.0), (100.0, 400.0), (250.0, 250.0)])
def test_a_points_reach_spans_one_pixel_in_its_image_whatever_the_pixels_aspect(fx, fy):
    # Non-square pixels (fx != fy) span range / fx across the image's columns and range / fy along its rows:
    # each reach, projected back into the camera that saw the point, is SILHOUETTE_PIXELS long there, in every
    # direction (min(fx, fy) made a reach along the fine axis fx / fy pixels long, 4 of them here).
    from estimation.carving import DepthView
    from estimation.fusion import Intrinsics

    view = DepthView(np.zeros((2, 2)), 0.0, Intrinsics(fx, fy, 1.0, 1.0, 2, 2), np.eye(3), np.zeros(3))
    rng = np.random.default_rng(0)
    at = np.c_[rng.uniform(-0.03, 0.03, (40, 2)), np.ones(40)]  # near the optical axis (+z), 1 m away
    normals = -at / np.linalg.norm(at, axis=1, keepdims=True) + rng.uniform(-0.6, 0.6, (40, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    up = np.array([0.0, -1.0, 0.0])  # the camera's y is down
    ray = at / np.linalg.norm(at, axis=1, keepdims=True)
    cosine = np.abs(np.einsum("ij,ij->i", ray, normals))
    assert (cosine > np.maximum(np.abs(ray @ up), 0.25)).all()  # the reach along is pitch / cosine

    reach = silhouette_reach(at, np.zeros_like(at), normals, [view], up)

    def pixel(p: np.ndarray) -> np.ndarray:
        return np.c_[fx * p[:, 0] / p[:, 2], fy * p[:, 1] / p[:, 2]]

    for k in range(2):  # along the surface away from the camera, and across the ray
        spans = np.linalg.norm(pixel(at + reach[:, k]) - pixel(at), axis=1)
        # Near the axis and a pixel long, the image is its own tangent plane to within 1 %.
        np.testing.assert_allclose(spans, SILHOUETTE_PIXELS, rtol=0.01)


@pytest.mark.parametrize("count", [2, 3])
def test_the_carved_solid_holds_the_object_and_not_much_more(count: int):
    scan = _scan(count)
    seg = scan.segments[0]
    carving = carve(seg.points, scan.views, scan.plane)
    solid = carving.centres(np.argwhere(carving.solid))
    # An upper bound: a voxel centre of the box is solid unless it lies within a voxel of the box's faces.
    assert carving.volume >= 0.9 * VOLUME
    assert carving.volume <= 1.5 * VOLUME
    assert _inside_box(solid).mean() > 0.6
    points, normals = carved_surface(carving)
    assert len(points) and np.allclose(np.linalg.norm(normals, axis=1), 1.0)
    # The base lies on the plane, its normals down.
    base = np.abs(points[:, 2] - TABLE_TOP) < 1e-6
    assert base.any() and (normals[base, 2] < -0.5).mean() > 0.9


def test_the_carved_surface_sits_where_the_camera_measured_not_its_noise_margin_in_front():
    # A camera straight above a 6 cm square block 3 cm tall, on a table: exact depths, but each pixel says its
    # noise is 2 mm. The carving stops FREE_SIGMAS of that in front of the block's top (so noise does not carve
    # into it); the carved surface is taken back to the top the camera measured, within half a voxel.
    from estimation.carving import FREE_SIGMAS, DepthView
    from estimation.fusion import Intrinsics, depth_to_points

    height, half, sigma, cell = 0.03, 0.03, 0.002, 0.0013
    intrinsics = Intrinsics.from_fov(320, 240, 40.0)
    camera = np.array([0.0, 0.0, 0.6])
    rotation = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # looking down, image y = -world y
    rays = intrinsics.rays() @ rotation.T  # world directions with camera-z length 1: depth = distance down
    on_top = camera[:2] + rays[:, :2] * (camera[2] - height)
    block = (np.abs(on_top) <= half).all(axis=1)
    depth = np.where(block, camera[2] - height, camera[2]).reshape(intrinsics.height, intrinsics.width)
    seen = DepthView(depth, np.full(depth.shape, sigma), intrinsics, rotation, camera)
    views = carving_views([seen], FLOOR, 0.001)
    points, _ = depth_to_points(depth, intrinsics, rotation, camera)
    top = points[points[:, 2] > 0.01]
    # A point of something 10 cm up lets the grid rise past the block's top, which would cap the solid
    # one voxel above the highest point.
    carving = carve(top, views, FLOOR, cell=cell, others=np.array([[0.0, 0.0, 0.1]]))

    for given, expected in (((), height + FREE_SIGMAS * sigma), ((views,), height)):
        surface, normals = carved_surface(carving, *given)
        inner = (normals[:, 2] > 0.9) & (np.abs(surface[:, :2]) < half - 5 * cell).all(axis=1)
        assert inner.sum() > 100
        assert np.median(surface[inner, 2]) == pytest.approx(expected, abs=0.5 * cell)
    # The base stands on the plane, where no camera's margin is: it does not move.
    (taken, normals), (left, _) = carved_surface(carving, views), carved_surface(carving)
    down = normals[:, 2] < -0.9
    assert down.sum() > 100 and np.array_equal(taken[down], left[down])


def test_a_blended_noise_margin_frees_rays_passing_beside_an_edge_and_never_the_object():
    # A camera straight above a 6 cm block 3 cm tall whose pixels say 2 mm of noise, on a table whose pixels
    # carving_views puts on the plane with none. Beside the block's walls the four pixels a point falls
    # between mix the two; the largest sigma lends the wall's margin to rays that pass the wall to the table.
    from estimation.carving import DepthView, free_space
    from estimation.fusion import Intrinsics

    height, half, sigma = 0.03, 0.03, 0.002
    intrinsics = Intrinsics.from_fov(320, 240, 40.0)
    camera = np.array([0.0, 0.0, 0.6])
    rotation = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    rays = intrinsics.rays() @ rotation.T
    block = (np.abs(camera[:2] + rays[:, :2] * (camera[2] - height)) <= half).all(axis=1)
    depth = np.where(block, camera[2] - height, camera[2]).reshape(intrinsics.height, intrinsics.width)
    views = carving_views([DepthView(depth, np.full(depth.shape, sigma), intrinsics, rotation, camera)], FLOOR, 0.001)
    x, z = np.meshgrid(np.linspace(half - 0.01, half + 0.01, 201), np.linspace(0.0005, 0.04, 80))
    points = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], axis=1)
    inside = (points[:, 0] <= half) & (points[:, 2] <= height)

    widest, blended = free_space(points, views), free_space(points, views, blend_sigma=True)
    assert not (widest & inside).any() and not (blended & inside).any()
    beside = blended & ~widest
    assert beside.sum() >= 20 and (points[beside, 0] > half).all()
    assert not (widest & ~blended).any()


def test_an_empty_view_carves_nothing():
    scan = _scan(1)
    blank = [type(v)(np.full_like(v.depth, np.nan), v.sigma, v.intrinsics, v.rotation, v.position)
             for v in scan.views]
    probe = np.array([[0.0, 0.0, TABLE_TOP + 0.2]])
    assert not free_space(probe, carving_views(blank, FLOOR, 0.0)).any()


def _sphere(n: int, radius: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return radius * d + [0, 0, radius], d


def _cone(n: int, radius: float, height: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    t = rng.random(n)
    h = height * (1 - np.sqrt(t))  # uniform over the lateral surface
    a = rng.random(n) * 2 * np.pi
    r = radius * (1 - h / height)
    points = np.stack([r * np.cos(a), r * np.sin(a), h], axis=1)
    slope = radius / height
    normals = np.stack([np.cos(a), np.sin(a), np.full(n, slope)], axis=1)
    return points, normals / np.linalg.norm(normals, axis=1, keepdims=True)


def test_a_ball_seen_from_above_gets_its_underside_from_the_mirror_image():
    rng = np.random.default_rng(1)
    radius = 0.04
    points, normals = _sphere(20000, radius, rng)
    seen = points[:, 2] > 0.3 * radius  # the lowest 30 % of its height hidden
    image = mirror_image(points[seen], normals[seen], FLOOR, noise=0.0, cell=0.002)
    assert image is not None
    mirrored, mirrored_normals, share = image
    assert share > 0.95
    # The image lies on the sphere, its normals outward, and covers the hidden cap.
    assert np.abs(np.linalg.norm(mirrored - [0, 0, radius], axis=1) - radius).max() < 0.002
    assert (np.einsum("ij,ij->i", mirrored_normals, mirrored - [0, 0, radius]) > 0).all()
    assert mirrored[:, 2].min() < 0.05 * radius


def test_a_flat_ring_under_noise_is_mirrored_about_its_true_middle():
    # A nut-sized torus (14 mm tall) whose lowest 6 mm went with the table, seen through 1 mm of noise:
    # few points are near its curved top, so the points' own heights (less the full noise's quantile) read
    # it low and the reflected underside came out short.
    import trimesh

    rng = np.random.default_rng(3)
    major, minor, sigma = 0.015, 0.007, 0.001
    ring = trimesh.creation.torus(major, minor, major_sections=96, minor_sections=48)
    points, faces = trimesh.sample.sample_surface_even(ring, 4000, seed=3)
    points = points + np.array([0.0, 0.0, minor])
    normals = ring.face_normals[faces]
    seen = (points[:, 2] > 0.006) & (normals[:, 2] > -0.3)
    noisy = points[seen] + rng.normal(0.0, sigma, (int(seen.sum()), 3))
    image = mirror_image(noisy, normals[seen], FLOOR, noise=sigma, cell=0.001)
    assert image is not None
    mirrored = image[0]
    assert mirrored[:, 2].min() >= 0.0  # nothing below the table
    # The image lies on the torus's underside (to the noise), not lifted off it.
    rho = np.linalg.norm(mirrored[:, :2], axis=1)
    distance = np.hypot(rho - major, mirrored[:, 2] - minor) - minor
    low = mirrored[:, 2] < 0.003
    assert low.sum() > 30
    assert abs(float(np.median(distance[low]))) < 0.2 * sigma  # the old estimate: 0.4 sigma out


def _noisy_slab(seed: int, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """A 10 x 10 x 0.9 cm slab on FLOOR, its lowest 3 mm gone with the plane, seen through ``sigma`` of noise."""
    rng = np.random.default_rng(seed)
    slab = _box_surface([-0.05, -0.05, 0.0], [0.05, 0.05, 0.009], 0.001, rng)
    slab = slab[slab[:, 2] > 0.003]
    normals = np.zeros_like(slab)
    for axis, (lo, hi) in enumerate(((-0.05, 0.05), (-0.05, 0.05), (0.0, 0.009))):
        normals[slab[:, axis] == lo, axis] = -1.0
        normals[slab[:, axis] == hi, axis] = 1.0
    return slab + rng.normal(0.0, sigma, slab.shape), normals / np.linalg.norm(normals, axis=1, keepdims=True)


def test_a_flat_top_under_noise_is_mirrored_onto_the_table_without_a_lift():
    """Half a flat top's noise, reflected, lands below the table. Lifted onto it, the mirrored base sat about 0.4
    sigma high (a 9 mm disc -4.6 % at 3 cameras, bench/camera_tables.py); a flat top's image is now the base
    itself, on the table, and the top's height its points' mean."""
    sigma = 0.00075
    slab, normals = _noisy_slab(5, sigma)
    top = flat_top(slab, normals, FLOOR, sigma)
    assert top is not None and float(slab[top, 2].mean()) == pytest.approx(0.009, abs=0.1 * sigma)
    image = mirror_image(slab, normals, FLOOR, noise=sigma, cell=0.001, cut=0.003)
    assert image is not None
    mirrored, mirrored_normals, _ = image
    base = mirrored_normals[:, 2] < -0.9
    assert base.sum() > 5000
    assert abs(float(mirrored[base, 2].mean())) < 0.1 * sigma  # 0.5 sigma up before
    assert mirrored[:, 2].min() >= 0.0  # nothing below the table
    # The sides' image meets the base: the slab's mirrored height is its top's.
    sides = np.abs(mirrored_normals[:, 2]) < 0.1
    assert mirrored[sides, 2].min() == pytest.approx(0.0, abs=4 * sigma)


def test_a_curved_top_is_not_flat():
    """A ball's or a ring's top, noisy, is not taken for flat: its reflected points that land below the table
    still go onto it (a curved top reads low, and its image would sink)."""
    rng = np.random.default_rng(6)
    points, normals = _sphere(20000, 0.02, rng)
    seen = points[:, 2] > 0.006
    noisy = points[seen] + rng.normal(0.0, 0.001, (int(seen.sum()), 3))
    assert flat_top(noisy, normals[seen], FLOOR, 0.001) is None
    slab, slab_normals = _noisy_slab(7, 0.001)  # the control: the same noise on a flat top
    assert flat_top(slab, slab_normals, FLOOR, 0.001) is not None


def test_a_noise_band_at_a_rim_is_not_a_lower_half():
    """A cube on another of its size, the lower one's top all hidden: what lies below its mid-height above the
    table is its rim's noise, a few mm deep, which reflects onto itself. Mirrored, its top went onto the table,
    through the cube under it (+93.1 % at 3 cameras, bench/stacks.py before session 43)."""
    rng = np.random.default_rng(4)
    cube = _box_surface([0.0, 0.0, 0.0805], [0.08, 0.08, 0.1605], 0.0012, rng)
    cube = cube[cube[:, 2] > 0.0806]  # its base hidden (the cube under it)
    normals = np.zeros_like(cube)
    for axis, (lo, hi) in enumerate(((0.0, 0.08), (0.0, 0.08), (0.0805, 0.1605))):
        normals[cube[:, axis] == lo, axis] = -1.0
        normals[cube[:, axis] == hi, axis] = 1.0
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    cube[:, 2] += rng.normal(0.0, 0.001, len(cube))  # sigma 1 mm: some of its rim falls below 8 cm
    assert (cube[:, 2] < 0.08).sum() >= MIRROR_MIN_POINTS  # enough below its mid-height for the test to be asked
    assert mirror_image(cube, normals, FLOOR, noise=0.001, cell=0.0012, cut=0.003) is None
    # The same cube on the table shows its lower half whole, and is its own mirror image.
    on_table = cube - [0.0, 0.0, 0.0805]
    assert mirror_image(on_table[on_table[:, 2] > 0.003], normals[on_table[:, 2] > 0.003], FLOOR, noise=0.001,
                        cell=0.0012, cut=0.003) is not None


def test_a_cone_is_not_its_own_mirror_image():
    rng = np.random.default_rng(2)
    points, normals = _cone(20000, 0.05, 0.08, rng)
    assert mirror_image(points, normals, FLOOR, noise=0.0, cell=0.002) is None


def test_a_pentagonal_prism_on_a_face_is_not_its_own_mirror_image():
    # Its lower sides lean out, its upper ones meet in a ridge: reflected at half its height the two halves
    # come within the tolerance near the middle (0.92 of the lower half's points matched), not at the
    # bottom, and the mirrored ridge made a V of its base (bench/camera_tables.py: -7 % at 3 cameras).
    import trimesh

    rng = np.random.default_rng(4)
    side, length, sigma, cut = 0.08, 0.12, 0.001, 0.006
    angles = -np.pi / 2 - np.pi / 5 + 2 * np.pi * np.arange(5) / 5  # the first edge flat at the bottom
    pentagon = side / (2 * np.sin(np.pi / 5)) * np.c_[np.cos(angles), np.sin(angles)]
    prism = trimesh.convex.convex_hull(np.concatenate([np.c_[pentagon[:, 0], np.full(5, y), pentagon[:, 1]]
                                                        for y in (0.0, length)]))
    prism.apply_translation(-prism.bounds[0] * [0, 0, 1])  # resting on its flat side
    points, faces = trimesh.sample.sample_surface_even(prism, 20000, seed=4)
    normals = prism.face_normals[faces]
    seen = (points[:, 2] > cut) & (normals[:, 2] > -0.3)  # what cameras above the table see
    noisy = points[seen] + rng.normal(0.0, sigma, (int(seen.sum()), 3))
    assert mirror_image(noisy, normals[seen], FLOOR, noise=sigma, cell=0.0015) is None


def _bracket_views(noise=EXACT):  # type: ignore[no-untyped-def]
    """Two depth views of tests/test_views.py's L-bracket on its table, with their depth images."""
    from estimation.views import View
    from scenes.cameras import render
    from tests.test_views import _cameras, bracket_model

    model, data = bracket_model()
    frames = [render(model, data, cam, noise=noise, rng=np.random.default_rng(0)) for cam in _cameras()]
    return [View(f.points()[0], np.asarray(f.camera.position, float), f.camera.name, f.view()) for f in frames]


def test_two_depth_views_of_an_l_bracket_carve_its_concave_corner_away():
    """Silhouette (edge) pixels carve up to their nearest neighbour: left out, the corner stayed (+11 %)."""
    from estimation.views import estimate_views
    from tests.test_views import VOLUME as BRACKET

    result = estimate_views(_bracket_views(), 1000.0, support="auto")
    assert result.estimate.volume == pytest.approx(BRACKET, rel=0.05)
    assert result.volume_bounds_m3[0] <= BRACKET <= result.volume_bounds_m3[1]


@pytest.mark.parametrize("angles", [(23, -41, 67), (10, 20, 30)])
def test_a_rigid_motion_of_depth_views_keeps_the_carved_volume(angles):
    """Points, sensor origins and camera poses moved together: the same completion, point for point, and
    the same volume within 0.1 % (the issue asks 0.5 %). The carved surface's samples and their thinning
    once sat on the world's axes: 1,312 completed points here, 1,502 and 1,606 after these motions, and
    the volume moved 0.3 %."""
    from dataclasses import replace

    from scipy.spatial.transform import Rotation

    from estimation.views import estimate_views
    from scenes.cameras import KINECT_V1

    views = _bracket_views(KINECT_V1)
    base = estimate_views(views, 1000.0, support="auto")
    rot = Rotation.from_euler("xyz", angles, degrees=True).as_matrix()
    shift = np.array([0.4, -1.1, 0.3])
    moved = [replace(v, points=v.points @ rot.T + shift, origin=rot @ v.origin + shift,
                     depth=replace(v.depth, rotation=rot @ v.depth.rotation, position=rot @ v.depth.position + shift))
             for v in views]
    after = estimate_views(moved, 1000.0, support="auto")
    assert after.completed_points == base.completed_points
    assert after.estimate.volume == pytest.approx(base.estimate.volume, rel=0.001)


def _one_object(geom: str, size: list[float], height: float, yaw: float = 0.0):  # type: ignore[no-untyped-def]
    """A table and one free object on it (a visual geom, as twin.model names it), positions computed."""
    import mujoco

    spec = mujoco.MjSpec()
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.4, 0.3, 0.02], pos=[0, 0, TABLE_TOP - 0.02])
    body = spec.worldbody.add_body(name="a", pos=[0.02, 0.01, TABLE_TOP + height / 2],
                                   quat=[np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)])
    body.add_freejoint(name="a/free")
    body.add_geom(name="a/visual", type=getattr(mujoco.mjtGeom, f"mjGEOM_{geom}"), size=size, group=1)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return model, data


ONE_CAMERA_SHAPES = {  # name: (geom, size, height, yaw, volume)
    "ball": ("SPHERE", [0.04, 0, 0], 0.08, 0.0, 4 / 3 * np.pi * 0.04**3),
    "box at 34 degrees": ("BOX", [0.05, 0.03, 0.025], 0.05, 0.6, 0.1 * 0.06 * 0.05),
    "can": ("CYLINDER", [0.035, 0.05, 0], 0.1, 0.0, np.pi * 0.035**2 * 0.1),
}


@pytest.mark.parametrize("shape", list(ONE_CAMERA_SHAPES))
def test_one_camera_sees_the_back_of_a_half_turn_symmetric_object(shape, monkeypatch):
    """One camera (sigma 1 mm, 320 x 240 at ~0.6 m): the front turned half a turn about the axis found
    from the silhouette and the seen-through space closes the back. Without it a ball loses its back."""
    import estimation.completion as completion
    from estimation import estimate, make_cloud
    from scenes.cameras import SIGMA_1MM, ring
    from scenes.sensing import CameraSensor
    from tests.test_cameras import _Truth

    geom, size, height, yaw, volume = ONE_CAMERA_SHAPES[shape]
    model, data = _one_object(geom, size, height, yaw)
    rig = ring((0, 0, TABLE_TOP), count=1, radius=0.45, above=0.45, width=320, height=240)

    def error() -> float:
        seen = CameraSensor(CameraFeed(rig, WORKSPACE, noise=SIGMA_1MM, seed=1)).observe(_Truth(model, data), "a", 0,
                                                                                       shot=1)
        return estimate(make_cloud(seen.points, seen.normals), 1000.0).volume / volume - 1

    turned = error()
    assert abs(turned) < 0.10
    monkeypatch.setattr(completion, "ONE_SIDED", 2.0)  # never one-sided: no half turn
    if shape == "ball":
        assert error() < -0.2
    else:
        assert abs(turned) <= abs(error()) + 0.005


def test_no_half_turn_from_views_around_the_object_or_noise_near_its_size():
    from estimation.completion import half_turn_axis
    from scenes.cameras import DepthNoise

    model, data = _one_object("CYLINDER", [0.035, 0.05, 0], 0.1)
    for count, noise, found in [(1, EXACT, True), (2, EXACT, False), (1, DepthNoise(axial_const=0.004, axial_quad=0.0),
                                                                        False)]:
        scan = CameraFeed(_rig(count), WORKSPACE, noise=noise, seed=2).scan(model, data)
        seg = scan.segments[0]
        axis = half_turn_axis(seg.points, seg.origins, scan.plane, scan.views, cut=scan.margin, cell=scan.cell / 3)
        assert (axis is not None) == found, (count, noise)
        if found:  # on the can's axis, to a few millimetres
            assert np.linalg.norm(axis[:2] - [0.02, 0.01]) < 0.004


# A 16 x 6 x 5 cm box standing centred on the origin of a level plane, and cameras 40 cm above it.
CUT_TOP = 0.75
CUT_BOX = (0.16, 0.06, 0.05)
#: Two 12-degree cameras looking 10 cm short of the box's middle: both frames end before its +x end.
NARROW = (((0.3, -0.45, CUT_TOP + 0.4), (-0.1, 0.0, CUT_TOP), 12.0),
          ((0.3, 0.45, CUT_TOP + 0.4), (-0.1, 0.0, CUT_TOP), 12.0))
#: A Kinect-wide camera from the other end, with the whole box in its frame.
WIDE = ((-0.45, 0.0, CUT_TOP + 0.4), (0.0, 0.0, CUT_TOP), 43.0)


def box_frame(position, target, fov_y_deg: float, *, seed: int = 0):  # type: ignore[no-untyped-def]
    """One 320 x 240 depth frame of ``CUT_BOX`` on the plane z = ``CUT_TOP``, ray cast here (slabs), 1 mm of
    seeded noise: (points (n, 3) with edge pixels dropped, as `twin estimate` takes them; the frame's
    :class:`DepthView`)."""
    from estimation.carving import DepthView
    from estimation.fusion import Intrinsics, depth_to_points, edge_mask

    intr = Intrinsics.from_fov(320, 240, fov_y_deg)
    pos = np.asarray(position, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - pos
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    rotation = np.stack([x, np.cross(z, x), z], axis=1)  # OpenCV axes: x right, y down, z forward
    rays = intr.rays() @ rotation.T  # world directions whose camera z is 1: the ray parameter is the depth
    lo = np.array([-CUT_BOX[0] / 2, -CUT_BOX[1] / 2, CUT_TOP])
    hi = lo + np.array([CUT_BOX[0], CUT_BOX[1], CUT_BOX[2]])
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - pos) / rays, (hi - pos) / rays
        enter, leave = np.nanmax(np.minimum(t1, t2), axis=1), np.nanmin(np.maximum(t1, t2), axis=1)
        table = (CUT_TOP - pos[2]) / rays[:, 2]
    depth = np.where((enter <= leave) & (enter > 0), enter, np.where(table > 0, table, np.nan))
    depth = depth.reshape(intr.height, intr.width) + np.random.default_rng(seed).normal(0.0, 0.001, (intr.height, intr.width))
    points, _ = depth_to_points(np.where(edge_mask(depth, 0.001), np.nan, depth), intr, rotation, pos)
    return points, DepthView(depth, np.full(depth.shape, 0.001), intr, rotation, pos)


def test_the_frames_border_is_not_the_objects_edge():
    """A point on its camera's image border is where the frame stopped, not the object: past it is open unless
    another view had that place in its frame (and so the object's outline there, or empty space)."""
    from estimation.carving import frame_cut, framed, open_past_frame

    table = Plane(np.array([0.0, 0.0, 1.0]), -CUT_TOP, 0.0, 0)
    frames = [box_frame(*camera, seed=k) for k, camera in enumerate((*NARROW, WIDE))]
    views = carving_views([view for _, view in frames], table, 0.003)
    on_box = [points[table.height(points) > 0.003] for points, _ in frames]
    origins = [np.broadcast_to(view.position, p.shape) for p, (_, view) in zip(on_box, frames, strict=True)]
    # The narrow camera's points on its border, and only its own (the wide camera's points project onto the
    # narrow one's border too): one pixel past it lies out of its frame.
    both = np.concatenate([on_box[0], on_box[2]])
    index, past = frame_cut(both, np.concatenate([origins[0], origins[2]]), views)
    assert len(index) > 50 and (index < len(on_box[0])).all()
    assert not framed(past, views[:1]).any()
    assert framed(past, views[2:]).mean() > 0.95
    # One or both narrow cameras: nobody looked past the cut. The wide camera alone saw the whole box, and
    # with it the narrow cameras' cut is bounded.
    assert open_past_frame(on_box[0], origins[0], views[:1])
    assert open_past_frame(np.concatenate(on_box[:2]), np.concatenate(origins[:2]), views[:2])
    assert not open_past_frame(on_box[2], origins[2], views[2:])
    assert not open_past_frame(np.concatenate(on_box), np.concatenate(origins), views)
    # One narrow camera: no half turn, whose axis comes from the silhouette's sides and the space seen past the
    # object, either of which may be the frame's (over 27 frames cutting this box it gave -93 % to +86 %).
    from estimation.completion import close_on_plane
    from estimation.fusion import oriented_normals

    closed = close_on_plane(on_box[0], origins[0], oriented_normals(on_box[0], origins[0]), table, cell=0.002,
                            cut=0.003, noise=0.001, views=views[:1])
    assert closed.completion.open_past_frame and closed.completion.turned == 0


@pytest.mark.slow  # 11 s
def test_a_box_both_frames_cut_has_no_top_to_its_interval():
    """Two narrow cameras see 60 % of a box's length, its far end out of both frames: the estimate is of the
    part seen (-32 %), and the interval stopped at 0.89 of the truth, saying the volume lay in it. Nothing the
    cameras saw bounds the part past their frames: the interval has no top now. A third camera that has the
    whole box in its frame bounds it again."""
    from estimation.views import View, estimate_views

    truth = float(np.prod(CUT_BOX))
    table = Plane(np.array([0.0, 0.0, 1.0]), -CUT_TOP, 0.0, 0)
    frames = [box_frame(*camera, seed=k) for k, camera in enumerate((*NARROW, WIDE))]
    views = [View(points, view.position, f"c{k}", view) for k, (points, view) in enumerate(frames)]
    cut = estimate_views(views[:2], 1000.0, support=table)
    low, high = cut.volume_bounds_m3
    assert cut.estimate.volume < 0.8 * truth  # what was seen
    assert low <= truth <= high and high == float("inf")
    assert any("runs out of a depth image's frame" in w for w in cut.warnings)
    whole = estimate_views(views, 1000.0, support=table)
    low, high = whole.volume_bounds_m3
    assert whole.estimate.volume == pytest.approx(truth, rel=0.05)
    assert low <= truth <= high < float("inf")
    assert not any("frame" in w for w in whole.warnings)


def _box_surface(lo, hi, spacing: float, rng: np.random.Generator, *, top: bool = True) -> np.ndarray:
    """Points on a box's sides (and top) about ``spacing`` apart, world frame, metres."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    faces = []
    for axis in range(3):
        for side in (lo, hi):
            if axis == 2 and (side is lo or not top):
                continue
            area = np.prod(np.delete(hi - lo, axis))
            p = rng.uniform(lo, hi, size=(int(area / spacing**2), 3))
            p[:, axis] = side[axis]
            faces.append(p)
    return np.concatenate(faces)


def _can_surface(centre, radius: float, bottom: float, height: float, spacing: float,
                 rng: np.random.Generator) -> np.ndarray:
    n_side, n_top = int(2 * np.pi * radius * height / spacing**2), int(np.pi * radius**2 / spacing**2)
    a, z = rng.uniform(0, 2 * np.pi, n_side), rng.uniform(bottom, bottom + height, n_side)
    side = np.stack([centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a), z], axis=1)
    r, b = radius * np.sqrt(rng.uniform(0, 1, n_top)), rng.uniform(0, 2 * np.pi, n_top)
    cap = np.stack([centre[0] + r * np.cos(b), centre[1] + r * np.sin(b), np.full(n_top, bottom + height)], axis=1)
    return np.concatenate([side, cap])


def test_a_can_on_a_box_rests_on_the_boxs_top_and_not_on_the_table():
    # Closed down to the table, a can on a box took the box's inside under it as its own: +32 % from three
    # cameras (the mirror image, about half its height above the table, put its top inside the box).
    rng = np.random.default_rng(0)
    box = _box_surface([-0.06, -0.06, 0.0], [0.06, 0.06, 0.04], 0.002, rng)
    can = _can_surface([0.01, -0.005], 0.03, 0.04, 0.08, 0.002, rng)
    box = box[np.hypot(box[:, 0] - 0.01, box[:, 1] + 0.005) > 0.03]  # the can hides the top under it
    support = resting_on(can, box, FLOOR, cell=0.002, noise=0.0005)
    assert support is not None
    np.testing.assert_allclose(support.normal, FLOOR.normal)
    assert support.height(np.array([[0.0, 0.0, 0.04]]))[0] == pytest.approx(0.0, abs=1e-3)
    # Its upper half, mirrored about its own middle, is its underside on the box, not inside the box.
    normals = np.where((can[:, 2] > 0.12 - 1e-9)[:, None], [0.0, 0.0, 1.0], 0.0)
    normals[:, :2] += np.where((can[:, 2] > 0.12 - 1e-9)[:, None], 0.0, (can[:, :2] - [0.01, -0.005]) / 0.03)
    image = mirror_image(can, normals, support, noise=0.0005, cell=0.002)
    assert image is not None
    assert image[0][:, 2].min() == pytest.approx(0.04, abs=0.002)
    assert mirror_image(can, normals, FLOOR, noise=0.0005, cell=0.002)[0][:, 2].min() < 0.005  # on the table


@pytest.mark.parametrize("case", ["beside a box", "beside a flat book", "between four boxes", "alone"])
def test_an_object_on_the_table_rests_on_the_table(case):
    # A neighbour's upright side, or a low top on one side of it (a book lying flat against a box), is not
    # what it stands on.
    rng = np.random.default_rng(1)
    box = _box_surface([0.0, 0.0, 0.0], [0.08, 0.08, 0.08], 0.002, rng)
    box = box[box[:, 2] > 0.004]  # what the plane's removal leaves
    others = {"beside a box": _box_surface([0.081, 0.0, 0.0], [0.16, 0.08, 0.12], 0.002, rng),
              "beside a flat book": _box_surface([0.081, -0.04, 0.0], [0.30, 0.12, 0.008], 0.002, rng),
              "between four boxes": np.concatenate([
                  _box_surface(lo, hi, 0.002, rng) for lo, hi in (([0.081, 0.0, 0.0], [0.16, 0.08, 0.12]),
                                                                  ([-0.081, 0.0, 0.0], [-0.001, 0.08, 0.12]),
                                                                  ([0.0, 0.081, 0.0], [0.08, 0.16, 0.12]),
                                                                  ([0.0, -0.081, 0.0], [0.08, -0.001, 0.12]))]),
              "alone": np.zeros((0, 3))}[case]
    others = others[others[:, 2] > 0.004] if len(others) else others
    # noise 2 mm: the book's top (8 mm) is within the 3 sigmas below the box's lowest points (4 mm) that a support may lie
    assert resting_on(box, others, FLOOR, cell=0.002, noise=0.002) is None
