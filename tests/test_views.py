"""`twin estimate VIEW [VIEW ...]`: several views of one object, the support plane, depth images, coverage and
the volume interval, rigid-motion invariance, and bad input as one-line errors. The views are a real
two-camera ray-cast scan (scenes/cameras.py, Kinect noise) of an L-bracket on a table."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from cli.main import main
from estimation import CloudError, estimate, load_cloud, make_cloud, save_cloud
from estimation.views import View, estimate_views, plane_from_abcd

TOP = 0.75  # table top, metres
# An L-bracket: a 10 x 6 x 1.5 cm foot and a 1.5 x 6 x 7 cm upright, standing on the table.
FOOT, UPRIGHT = (0.10, 0.06, 0.015), (0.015, 0.06, 0.07)
VOLUME = float(np.prod(FOOT) + np.prod(UPRIGHT))
CAMERAS = ((0.5, -0.3, TOP + 0.45), (-0.4, 0.4, TOP + 0.5))


def _cameras():  # type: ignore[no-untyped-def]
    from scenes.cameras import Camera

    return [Camera(f"c{k}", pos, (0.0, 0.0, TOP), width=320, height=240) for k, pos in enumerate(CAMERAS)]


def bracket_model():  # type: ignore[no-untyped-def]
    """The bracket on a table: a real MuJoCo model and its data, positions computed."""
    import mujoco

    spec = mujoco.MjSpec()
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.4, 0.3, 0.02], pos=[0, 0, TOP - 0.02])
    body = spec.worldbody.add_body(name="bracket", pos=[0.01, 0.02, TOP])
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[s / 2 for s in FOOT], pos=[0, 0, FOOT[2] / 2])
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[s / 2 for s in UPRIGHT],
                  pos=[(UPRIGHT[0] - FOOT[0]) / 2, 0, FOOT[2] + UPRIGHT[2] / 2])
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return model, data


@pytest.fixture(scope="module")
def frames():  # type: ignore[no-untyped-def]
    """Two noisy depth frames of the bracket (ray cast)."""
    from scenes.cameras import KINECT_V1, render

    model, data = bracket_model()
    rng = np.random.default_rng(0)
    return [render(model, data, cam, noise=KINECT_V1, rng=rng) for cam in _cameras()]


@pytest.fixture(scope="module")
def views(frames):  # type: ignore[no-untyped-def]
    """Each frame's points near the bracket (some table kept) and its camera centre, world frame."""
    out = []
    for frame in frames:
        points, _ = frame.points()
        near = (np.abs(points[:, 0]) < 0.12) & (np.abs(points[:, 1]) < 0.12)
        out.append((points[near], np.asarray(frame.camera.position, float)))
    return out


@pytest.fixture
def pcds(tmp_path, views):  # type: ignore[no-untyped-def]
    paths = []
    for k, (points, origin) in enumerate(views):
        save_cloud(make_cloud(points, sensor_origins=origin), tmp_path / f"view{k}.pcd")
        paths.append(str(tmp_path / f"view{k}.pcd"))
    return paths


def _run(capsys, argv):  # type: ignore[no-untyped-def]
    code = main(["estimate", *argv, "--density", "1000", "--json"])
    out = capsys.readouterr()
    assert code == 0, out.err
    return json.loads(out.out)


def test_two_views_with_the_support_plane_found_hold_the_truth(capsys, pcds, views):
    record = _run(capsys, [*pcds, "--support-plane", "auto"])
    low, high = record["volume_bounds_m3"]
    assert low <= VOLUME <= high
    assert record["volume_m3"] == pytest.approx(VOLUME, rel=0.15)
    assert 0.5 < record["coverage"] < 1.0  # the base and the far faces were not seen
    assert record["views"] == {"count": 2, "points": [len(p) for p, _ in views]}
    assert record["points_in"] == sum(len(p) for p, _ in views)  # read, not what fusion thinned them to
    assert record["support_plane"] == pytest.approx([0, 0, 1, -TOP], abs=2e-3)
    assert any("closed on the support plane" in w for w in record["warnings"])
    assert any("rests on completion" in w for w in record["warnings"])


def test_a_given_plane_in_file_units_gives_the_same_answer(capsys, tmp_path, views):
    paths = []
    for k, (points, origin) in enumerate(views):
        save_cloud(make_cloud(points * 1000, sensor_origins=origin * 1000), tmp_path / f"mm{k}.pcd")
        paths.append(str(tmp_path / f"mm{k}.pcd"))
    # A tilted normal of any length: normalised; D in millimetres like the file.
    record = _run(capsys, [*paths, "--units", "mm", "--support-plane", "0", "0", "2", str(-2 * TOP * 1000)])
    assert record["support_plane"] == pytest.approx([0, 0, 1, -TOP])
    assert record["volume_m3"] == pytest.approx(VOLUME, rel=0.15)
    low, high = record["volume_bounds_m3"]
    assert low <= VOLUME <= high


def test_without_the_plane_the_unseen_base_is_not_closed_and_coverage_says_so(capsys, tmp_path, views):
    # The table cut away by hand: what a segmenter hands over. No plane given: nothing closes the base.
    paths = []
    for k, (points, origin) in enumerate(views):
        keep = points[:, 2] > TOP + 0.004
        save_cloud(make_cloud(points[keep], sensor_origins=origin), tmp_path / f"obj{k}.pcd")
        paths.append(str(tmp_path / f"obj{k}.pcd"))
    bare = _run(capsys, paths)
    closed = _run(capsys, [*paths, "--support-plane", "0", "0", "1", str(-TOP)])
    # 'auto' does not take the bracket's own top or side for the table (the rest of it lies behind them):
    # no plane in these views, so the one through the lowest point.
    found = _run(capsys, [*paths, "--support-plane", "auto"])
    assert any("no support plane in the data" in w for w in found["warnings"])
    assert found["support_plane"][:3] == [0, 0, 1] and -found["support_plane"][3] == pytest.approx(TOP, abs=0.01)
    assert bare["coverage"] < closed["coverage"] + 0.05
    assert not any("support plane" in w for w in bare["warnings"])
    # Without the plane the base could be anywhere below the seen part: the interval says so. (Which of
    # the two volumes is nearer the truth depends on the noise draw: over four draws the bare one was
    # 1.7 to 7.7 % off and the closed one 1.5 to 4.7 %.)
    # Unbounded (JSON null) where the estimate calls the points one sheet with nothing measured behind it.
    (bare_low, bare_high), (closed_low, closed_high) = bare["volume_bounds_m3"], closed["volume_bounds_m3"]
    assert closed_high is not None
    assert (np.inf if bare_high is None else bare_high) - bare_low > 1.5 * (closed_high - closed_low)


def test_depth_images_read_like_the_clouds(capsys, tmp_path, frames, pcds):
    from PIL import Image
    from scipy.spatial.transform import Rotation

    argv = []
    for k, frame in enumerate(frames):
        mm = np.nan_to_num(np.round(frame.depth * 1000), nan=0).astype(np.uint16)
        Image.fromarray(mm).save(tmp_path / f"depth{k}.png")
        x, y, z, w = Rotation.from_matrix(frame.camera.rotation).as_quat()  # scipy: x y z w
        argv += ["--viewpoint-pose", *map(str, (*frame.camera.position, w, x, y, z))]
    cam = frames[0].camera
    intr = cam.intrinsics  # fusion's pixel centres are at +0.5; OpenCV's cx is half a pixel less
    argv += ["--intrinsics", str(intr.fx), str(intr.fy), str(intr.cx - 0.5), str(intr.cy - 0.5)]
    record = _run(capsys, [str(tmp_path / "depth0.png"), str(tmp_path / "depth1.png"), *argv,
                           "--support-plane", "auto"])
    # The depth images hold the whole table and the edge pixels the clouds dropped: more points, same object.
    assert record["views"]["count"] == 2 and min(record["views"]["points"]) > 10_000
    assert record["volume_m3"] == pytest.approx(VOLUME, rel=0.15)
    low, high = record["volume_bounds_m3"]
    assert low <= VOLUME <= high


def test_a_rigid_motion_of_views_and_plane_keeps_the_volume(views):
    """Within 0.2 % (the issue asks 0.5 %). The Kinect's quantised depth puts points on a lattice, where
    equal distances once let a rigid motion swap a normal's 16th neighbour: 0.45 % then."""
    from scipy.spatial.transform import Rotation

    from estimation.views import View, estimate_views, plane_from_abcd

    def run(rot: np.ndarray, shift: np.ndarray) -> float:
        moved = [View(p @ rot.T + shift, rot @ o + shift) for p, o in views]
        normal = rot @ np.array([0.0, 0.0, 1.0])
        plane = plane_from_abcd([*normal, -normal @ (rot @ np.array([0, 0, TOP]) + shift)])
        return estimate_views(moved, 1000.0, support=plane).estimate.volume

    base = run(np.eye(3), np.zeros(3))
    rng = np.random.default_rng(7)
    for _ in range(3):
        rot = Rotation.random(random_state=rng).as_matrix()
        assert run(rot, rng.uniform(-2, 2, 3)) == pytest.approx(base, rel=0.002)


@pytest.mark.slow  # ~15 s: in CI's slow run, to keep the default run under ten minutes
def test_views_past_the_point_cap_are_thinned_first(monkeypatch):
    """Fused views of more than ``tolerances.VIEW_POINTS`` are thinned to about that many measured points
    before anything fits normals to them (a 4096 x 4096 depth frame took minutes and more memory than the
    machine has). A box seen from above at sigma 0.5 mm, capped at under half its points: the estimate moves
    by a small fraction of its error."""
    import trimesh

    from estimation import tolerances as tol
    from estimation.views import View, estimate_views, plane_from_abcd

    box = trimesh.creation.box(extents=(0.10, 0.08, 0.06))
    box.apply_translation([0.0, 0.0, 0.03])
    points, faces = trimesh.sample.sample_surface_even(box, 100_000, seed=1)
    normals = box.face_normals[faces]
    seen = normals[:, 2] > -0.5  # not its base
    points = points[seen] + np.random.default_rng(2).normal(0.0, 0.0005, (int(seen.sum()), 3))
    toward = normals[seen] + [0.0, 0.0, 1.0]  # each point's camera above it, on its face's side
    origins = points + 0.5 * toward / np.linalg.norm(toward, axis=1, keepdims=True)
    table = plane_from_abcd([0.0, 0.0, 1.0, 0.0])
    full = estimate_views([View(points, origins)], 1000.0, support=table)
    monkeypatch.setattr(tol, "VIEW_POINTS", 35_000)
    thinned = estimate_views([View(points, origins)], 1000.0, support=table)
    assert thinned.view_points == full.view_points == (len(points),)  # what the view brought, as given
    assert thinned.object_points < 35_000 < 0.5 * full.object_points
    assert thinned.estimate.volume == pytest.approx(box.volume, rel=0.006)
    assert thinned.estimate.volume == pytest.approx(full.estimate.volume, rel=0.002)
    # Noise thicker than half the thinning voxel: a seeded random share (one point per voxel would keep the
    # noise's tails as often as its middle), the same share every run.
    noisy = points + np.random.default_rng(3).normal(0.0, 0.002, points.shape)
    runs = [estimate_views([View(noisy, origins)], 1000.0, support=table) for _ in range(2)]
    assert runs[0].object_points <= 35_000 and runs[0].estimate.volume == runs[1].estimate.volume
    assert runs[0].estimate.volume == pytest.approx(box.volume, rel=0.05)


def test_one_sided_views_leave_the_volume_unbounded_above():
    """A ball seen by one camera and nothing else: its back may reach anywhere behind what was seen. The
    interval stopped at 40 % of the true volume (and said the volume lay in it); now its top is unknown."""
    from estimation.views import View, estimate_views

    rng = np.random.default_rng(4)
    centre, camera, radius = np.array([0.0, 0.0, 0.5]), np.zeros(3), 0.05
    d = rng.normal(size=(20_000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    points = centre + radius * d
    seen = np.einsum("ij,ij->i", d, camera - points) > 0  # the half facing the camera
    result = estimate_views([View(points[seen], camera)], 1000.0)
    low, high = result.volume_bounds_m3
    assert high == float("inf") and low <= 4 / 3 * np.pi * radius**3
    assert any("all from one side: nothing bounds what lies behind it" in w for w in result.warnings)
    # Seen from both sides, the interval is finite again.
    other = np.array([0.0, 0.0, 1.0])
    back = np.einsum("ij,ij->i", d, other - points) > 0
    both = estimate_views([View(points[seen], camera), View(points[back], other)], 1000.0)
    assert np.isfinite(both.volume_bounds_m3[1])


def _box_on_table(size, at, *, floor=False):  # type: ignore[no-untyped-def]
    """Each camera's whole frame (points, world frame; its centre) of a box of ``size`` (m) standing at ``at``
    (x, y) on the table, ray cast at sigma 1 mm; the floor too when ``floor``."""
    import mujoco

    from scenes.cameras import SIGMA_1MM, render

    spec = mujoco.MjSpec()
    if floor:
        spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[3, 3, 0.1])
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.4, 0.3, 0.02], pos=[0, 0, TOP - 0.02])
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[s / 2 for s in size],
                            pos=[at[0], at[1], TOP + size[2] / 2])
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    rng = np.random.default_rng(0)
    return [(render(model, data, cam, noise=SIGMA_1MM, rng=rng).points()[0], np.asarray(cam.position, float))
            for cam in _cameras()]


def test_a_tight_crop_around_a_flat_object_still_finds_the_table():
    """Cropped close around a book, its top outweighs the ring of table around it: the largest plane is the
    book's top, refused (the rest of the book and the table lie below it), and the next one is the table.
    (Before, the views fell back to the plane through their lowest point and the estimate lost 65 %.)"""
    from estimation.views import View, estimate_views

    size = (0.24, 0.17, 0.03)
    reach = float(np.linalg.norm(size)) / 2 + 0.01  # half the diagonal and a centimetre
    views = [View(points[np.linalg.norm(points[:, :2], axis=1) < reach], origin)
             for points, origin in _box_on_table(size, (0.0, 0.0))]
    result = estimate_views(views, 1000.0, support="auto")
    assert result.plane is not None
    assert result.plane.normal == pytest.approx([0, 0, 1], abs=0.01)
    assert -result.plane.offset == pytest.approx(TOP, abs=2e-3)
    assert not any("no support plane" in w for w in result.warnings)
    assert result.estimate.volume == pytest.approx(float(np.prod(size)), rel=0.05)


def test_whole_frames_with_the_floor_in_view_take_the_table_not_the_floor():
    """Whole camera frames of a box on a table see the floor around the table: the floor is a plane with
    everything above it, and what stands on it is the table with the box on top. The table, almost all of
    that and carrying the box, becomes the support. (Before, the "object" was the table: +1000 % and more.)"""
    from estimation.views import View, estimate_views

    size = (0.08, 0.06, 0.05)
    views = [View(points, origin) for points, origin in _box_on_table(size, (0.05, 0.0), floor=True)]
    assert min(float(v.points[:, 2].min()) for v in views) < 0.1  # the floor is in view
    result = estimate_views(views, 1000.0, support="auto")
    assert result.plane is not None and -result.plane.offset == pytest.approx(TOP, abs=2e-3)
    assert any("a table on the floor?" in w for w in result.warnings)
    assert result.estimate.volume == pytest.approx(float(np.prod(size)), rel=0.05)


@pytest.mark.parametrize(("extra", "message"), [
    # Facing down, through the table: every sensor lies below it (a table's "z = 0.75" written as 0 0 -1 0.75).
    (["--support-plane", "0", "0", "-1", str(TOP)], r"the sensor of view0\.pcd lies 4\d\d mm below it"),
    (["--support-plane", "0", "0", "0", "1"], r"the normal \(A, B, C\) is zero"),
    (["--support-plane", "0", "0", "1", "nan"], r"four finite numbers"),
    (["--support-plane", "up"], r"'auto' or four numbers"),
    (["--support-plane", "0", "0", "1", "1e308"], r"support plane: it passes 1e\+308 m from the origin, beyond the "
                                                  r"10000 m"),
    # a sensor 1e160 m away went through (numpy warned of a divide by zero and an invalid cast)
    (["--viewpoint", "0", "0", "1e160", "--viewpoint", "1e160", "0", "0"],
     r"view0\.pcd: the sensor is 1e\+160 m from the origin, beyond the 10000 m"),
    (["--viewpoint", "0", "0", "1"], r"--viewpoint given 1 times for 2 views"),
    (["--method", "obb"], r"need --method auto"),
    (["--depth-scale", "0.001"], r"pass --intrinsics"),
])
def test_bad_options_are_one_line_errors(capsys, pcds, extra, message):
    assert main(["estimate", *pcds, "--density", "1000", *extra]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert pytest.importorskip("re").search(message, err), err


def test_two_cameras_facing_each_other_see_one_object_not_two():
    """Rays graze a can at its outline, so two cameras facing each other across it see two halves centimetres
    apart; the half with fewer points was dropped as another object (-55 %, a review's mug -54 %). A view that
    has most of its points in another cluster than the largest sees the object's other side."""
    import mujoco

    from scenes.cameras import EXACT, Camera, render

    radius, height = 0.04, 0.09
    spec = mujoco.MjSpec()
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.4, 0.3, 0.02], pos=[0, 0, TOP - 0.02])
    spec.worldbody.add_body(name="can", pos=[0, 0, TOP]).add_geom(
        type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[radius, height / 2, 0], pos=[0, 0, height / 2])
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    views = []
    for k, azimuth in enumerate(np.radians([30, 210])):
        camera = Camera(f"c{k}", (0.45 * np.cos(azimuth), 0.45 * np.sin(azimuth), TOP + 0.15), (0, 0, TOP + 0.045),
                        width=640, height=480)
        points, _ = render(model, data, camera, noise=EXACT).points()
        views.append(View(points[np.linalg.norm(points[:, :2], axis=1) < 0.12], np.asarray(camera.position), f"c{k}"))
    result = estimate_views(views, 1000.0, support=plane_from_abcd([0.0, 0.0, 1.0, -TOP]))
    assert not any("apart from the object" in w for w in result.warnings), result.warnings
    assert result.estimate.volume == pytest.approx(np.pi * radius**2 * height, rel=0.3)


def test_the_views_together_are_held_to_the_point_cap(capsys, pcds, monkeypatch):
    """The cap was per file: forty copies of a 1M-point file passed 5 GB."""
    from estimation import cloudfile

    sizes = [len(load_cloud(p).points) for p in pcds]
    monkeypatch.setattr(cloudfile, "MAX_POINTS", sum(sizes) - 1)
    assert main(["estimate", *pcds, "--density", "1000"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"the views together hold more than {sum(sizes) - 1:,} points" in err, err
    monkeypatch.setattr(cloudfile, "MAX_POINTS", sizes[0])  # the first view fills it: the second is refused
    assert main(["estimate", *pcds, "--density", "1000"]) == 2
    assert "the views together hold more than" in capsys.readouterr().err
    monkeypatch.setattr(cloudfile, "MAX_POINTS", sum(sizes))
    assert main(["estimate", *pcds, "--density", "1000", "--json"]) == 0


def test_a_support_plane_of_huge_coefficients_is_normalised():
    from estimation.views import plane_from_abcd

    # 0 0 1e308 D overflowed the normal's length to inf: a zero normal, "only 0 points lie above" the plane
    plane = plane_from_abcd([0.0, 0.0, 1e308, -TOP * 1e308])
    assert plane.normal.tolist() == [0.0, 0.0, 1.0] and plane.offset == pytest.approx(-TOP)


def test_a_pcd_viewpoint_far_away_is_refused(capsys, tmp_path, views):
    save_cloud(make_cloud(views[0][0], sensor_origins=np.array([0.0, 0.0, 1e300])), tmp_path / "far.pcd")
    assert main(["estimate", str(tmp_path / "far.pcd"), "--density", "1000"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "far.pcd: the sensor is 1e+300 m from the origin, beyond the 10000 m" in err, err


def test_a_view_without_viewpoint_is_refused(capsys, tmp_path, views, pcds):
    save_cloud(make_cloud(views[1][0]), tmp_path / "bare.ply")
    assert main(["estimate", pcds[0], str(tmp_path / "bare.ply"), "--density", "1000"]) == 2
    err = capsys.readouterr().err
    assert ("bare.ply: no sensor origin (no VIEWPOINT header or vp_x vp_y vp_z fields; a VIEWPOINT of 0 0 0 1 0 0 0, "
            "the PCD default, is read as unknown; pass --viewpoint X Y Z)") in err
    # --viewpoint once per view supplies it (and replaces the header of the other)
    o0, o1 = (map(str, o) for _, o in views)
    assert main(["estimate", pcds[0], str(tmp_path / "bare.ply"), "--density", "1000", "--json",
                 "--viewpoint", *o0, "--viewpoint", *o1]) == 0


def _ball_view():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(3000, 3))
    return 0.05 * points / np.linalg.norm(points, axis=1, keepdims=True) + [0.0, 0.0, 0.06], np.array([0.3, 0, 0.3])


@pytest.mark.parametrize(("build", "error", "said"), [
    (lambda p, o: View(np.vstack([p, [np.nan, 0, 0]]), o, "cam"), CloudError, "cam: points: contains NaN"),
    (lambda p, o: View(p[:, :2], o), CloudError, r"a view: points: expected shape \(n, 3\)"),
    (lambda p, o: View(p, o[:2]), CloudError, r"origin: expected the sensor's position, \(3,\) or one per point"),
    (lambda p, o: View(p, "here"), CloudError, "origin: expected the sensor's position"),
    (lambda p, o: [View(p, [np.nan, 0, 0])], CloudError, "the sensor's position is not finite"),
    (lambda p, o: [p], TypeError, "a list of View records"),
    (lambda p, o: View(p, o), TypeError, "a list of View records"),
])
def test_views_built_by_hand_are_checked(build, error, said):
    with pytest.raises(error, match=said):
        estimate_views(build(*_ball_view()), 1000.0, support="auto")


def test_a_view_from_lists_or_with_an_origin_per_point_is_the_same_view():
    points, origin = _ball_view()
    volume = estimate_views([View(points, origin)], 1000.0, support="auto").estimate.volume
    assert estimate_views([View(points.tolist(), origin.tolist())], 1000.0, support="auto").estimate.volume == volume
    per_point = np.tile(origin, (len(points), 1))
    assert estimate_views([View(points, per_point)], 1000.0, support="auto").estimate.volume == volume


def test_estimate_names_the_record_it_takes():
    with pytest.raises(TypeError, match=r"takes a PointCloud \(make_cloud\(points\) builds one"):
        estimate(_ball_view()[0], 1000.0)


def test_a_view_with_no_points_is_refused(capsys, tmp_path, pcds):
    empty = tmp_path / "empty.xyz"
    empty.write_text("# nothing seen\n")
    assert main(["estimate", pcds[0], str(empty), "--density", "1000"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("twin estimate: error: ") and "empty.xyz" in err and err.count("\n") == 1


@pytest.mark.parametrize(("name", "write", "message"), [
    ("zeros.png", lambda p: _png(p, np.zeros((30, 40), np.uint16)), r"no pixel holds a depth \(all 1200"),
    ("nan.npy", lambda p: np.save(p, np.full((30, 40), np.nan)), r"no pixel holds a depth"),
    ("negative.npy", lambda p: np.save(p, np.full((30, 40), -1.0)), r"all 1200 are zero, negative or NaN"),
    ("empty.npy", lambda p: np.save(p, np.zeros((0, 40))), r"the depth image is empty"),
    ("eight.png", lambda p: _png(p, np.full((30, 40), 200, np.uint8)), r"8-bit PNG cannot hold depth"),
    ("one.png", lambda p: _png(p, np.ones((30, 40), bool)), r"a 1-bit PNG cannot hold depth"),
    # PIL reads a 16-bit RGB PNG as 8-bit RGB: the header says which it is.
    ("rgb16.png", lambda p: _png_header(p, 40, 30, colour=2), r"a 16-bit RGB PNG; a depth image is a 16-bit single"),
    ("rgba.png", lambda p: _png(p, np.full((30, 40, 4), 200, np.uint8)), r"an 8-bit RGBA PNG; a depth image is"),
    ("rgb.npy", lambda p: np.save(p, np.ones((30, 40, 3))), r"numeric \(h, w\) array"),
    # one pixel with a depth, and depths of 1e300 m: IndexErrors in the spacing and the noise of the views
    ("one.npy", lambda p: np.save(p, np.pad([[1.0]], ((15, 14), (20, 19)))), r"too few points: 1 \(need at least 100\)"),
    ("far.npy", lambda p: np.save(p, np.full((30, 40), 1e300)), r"coordinates reach 1e\+300 m from the origin"),
    ("complex.npy", lambda p: np.save(p, np.ones((30, 40), complex)), r"real numbers, got complex128"),
    # A small file whose header claims 90000 x 90000 was a 60 GiB allocation; refused from the header.
    ("lie.npy", lambda p: _npy_claiming(p, (90000, 90000)), r"truncated: the header claims shape \(90000, 90000\)"),
    ("huge.npy", lambda p: _npy_claiming(p, (8000, 8000), sparse=True), r"8000x8000 depth image is more than the 16,777,216"),
    # A 16-bit PNG header claiming 20000 x 20000 was PIL's DecompressionBombError; refused before decoding.
    ("bomb.png", lambda p: _png_header(p, 20000, 20000), r"20000x20000 depth image is more than the 16,777,216"),
    # A TIFF named .png: PIL opened it past the PNG header's size check (8000 x 8000 in 192 KB took 6.8 GB).
    ("tiff.png", lambda p: _tiff(p), r"not a PNG \(no PNG signature"),
    # Corrupt chunks PIL answers with ValueError or SyntaxError, not OSError: they ended in tracebacks.
    ("phys.png", lambda p: _png_with_chunk(p, b"pHYs", b"\0"), r"not a readable PNG \(Truncated pHYs chunk\)"),
    ("ztxt.png", lambda p: _png_with_chunk(p, b"zTXt", b"k\0\0" + __import__("zlib").compress(bytes(5_000_000))),
     r"not a readable PNG \(Decompressed data too large"),
    ("idat.png", lambda p: _png_short_idat(p), r"not a readable PNG \(broken PNG file"),
])
def test_bad_depth_frames_are_one_line_errors(capsys, tmp_path, name, write, message):
    import re

    write(tmp_path / name)
    assert main(["estimate", str(tmp_path / name), "--intrinsics", "50", "50", "19.5", "14.5"]) == 2
    err = capsys.readouterr().err
    assert re.search(message, err) and err.count("\n") == 1, err
    assert err.count(name) <= 1, err  # the readers' own errors were wrapped again: "cannot read X: X: not a PNG"


@pytest.mark.parametrize(("extra", "message"), [
    (["--intrinsics", "50", "50", "319.5", "14.5"], r"principal point \(319.5, 14.5\) lies outside the 40x30"),
    (["--intrinsics", "0", "50", "19.5", "14.5"], r"focal lengths must be 1 to 1e\+06 pixels"),
    (["--intrinsics", "1e-300", "1e-300", "19.5", "14.5"], r"focal lengths must be 1 to 1e\+06 pixels"),
    (["--intrinsics", "1e300", "50", "19.5", "14.5"], r"focal lengths must be 1 to 1e\+06 pixels"),
    # fx / fy = 105: a typo (a digit too many); no camera's pixels are 105 times as tall as wide. Was accepted.
    (["--intrinsics", "5250", "50", "19.5", "14.5"],
     r"focal lengths fx 5250 and fy 50 differ 105-fold: pixels that far from square are no camera's"),
    (["--intrinsics", "50", "501", "19.5", "14.5"], r"fx 50 and fy 501 differ 10\.02-fold"),
    (["--intrinsics", "50", "50", "19.5", "14.5", "--depth-scale", "1000"], r"inverse"),
    # was ignored: the image read in millimetres, as if --units mm applied to it or did nothing
    (["--intrinsics", "50", "50", "19.5", "14.5", "--units", "mm"], r"--units is for point files"),
    (["--intrinsics", "50", "50", "19.5", "14.5", "--depth-scale", "1e-300"], r"depth scale must be .* in \[1e-06, 10\]"),
    (["--intrinsics", "50", "50", "19.5", "14.5", "--viewpoint-pose", "0", "0", "0", "2", "0", "0", "0"],
     r"norm 1 \(within 0.001\), got 2"),
    (["--intrinsics", "50", "50", "19.5", "14.5", "--viewpoint-pose", "1e300", "0", "0", "1", "0", "0", "0"],
     r"pose: the camera is 1e\+300 m from the origin, beyond the 10000 m"),
])
def test_bad_intrinsics_and_poses_are_one_line_errors(capsys, tmp_path, extra, message):
    import re

    _png(tmp_path / "d.png", np.full((30, 40), 800, np.uint16))
    assert main(["estimate", str(tmp_path / "d.png"), *extra]) == 2
    err = capsys.readouterr().err
    assert re.search(message, err) and err.count("\n") == 1, err


@pytest.mark.parametrize(("suffix", "extra", "size"), [
    (".npy", [], r"624 m across, more than"),  # millimetres saved as float: read as metres
    (".png", ["--depth-scale", "1"], r"624 m across, more than"),
    (".png", ["--depth-scale", "1e-6"], r"0\.624 mm across, less than"),
])
def test_a_depth_image_in_other_units_is_refused_as_a_point_file_is(capsys, tmp_path, suffix, extra, size):
    """The units check ran only without --intrinsics: a disc in millimetres read as metres came out an 848 m object
    with exit 0 (the hint only in the JSON's warnings). It is refused as a point file's is, naming --depth-scale."""
    rows, cols = np.mgrid[:30, :40]
    depth = np.full((30, 40), 800, np.uint16)
    depth[(cols - 20) ** 2 + (rows - 15) ** 2 < 64] = 700
    image = tmp_path / f"d{suffix}"
    if suffix == ".npy":
        np.save(image, depth.astype(np.float32))
    else:
        _png(image, depth)
    mesh = tmp_path / "m.stl"
    assert main(["estimate", str(image), "--intrinsics", "50", "50", "19.5", "14.5", *extra,
                 "--mesh-out", str(mesh)]) == 2
    err = capsys.readouterr().err
    assert re.fullmatch(rf"twin estimate: error: object is {size} the 2 mm to 5 m an object here is: the depth "
                        r"images are probably in other units \(check --depth-scale, .*\)\n", err), err
    assert not mesh.exists()


def _npy_claiming(path, shape, *, sparse=False):  # type: ignore[no-untyped-def]
    """An .npy header for ``shape`` float64, then 1 KB of data, or (sparse) a file of its full size with no
    blocks written."""
    with open(path, "wb") as fh:
        np.lib.format.write_array_header_1_0(fh, {"descr": "<f8", "fortran_order": False, "shape": shape})
        if sparse:
            fh.truncate(fh.tell() + 8 * int(np.prod(shape)))
        else:
            fh.write(bytes(1024))


def _tiff(path):  # type: ignore[no-untyped-def]
    from PIL import Image

    Image.fromarray(np.full((30, 40), 700, np.uint16)).save(path, format="TIFF")


def _png_header(path, width, height, colour=0):  # type: ignore[no-untyped-def]
    """A PNG signature and IHDR chunk (16-bit, greyscale unless ``colour`` says) for ``width`` x ``height``, and
    nothing after."""
    import struct
    import zlib

    ihdr = b"IHDR" + struct.pack(">IIBBBBB", width, height, 16, colour, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + ihdr + struct.pack(">I", zlib.crc32(ihdr)))


def _png(path, array):  # type: ignore[no-untyped-def]
    from PIL import Image

    Image.fromarray(array).save(path)


def _png_with_chunk(path, kind, data):  # type: ignore[no-untyped-def]
    """A valid 16-bit depth PNG with one more chunk (``kind``, ``data``) right after the IHDR."""
    import struct
    import zlib

    _png(path, np.full((30, 40), 800, np.uint16))
    raw = path.read_bytes()
    chunk = struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    path.write_bytes(raw[:33] + chunk + raw[33:])  # the signature (8) and IHDR (25) first


def _png_short_idat(path):  # type: ignore[no-untyped-def]
    """A valid 16-bit depth PNG whose image data chunk claims 14 bytes fewer than it holds: the reader takes
    the rest for the next chunk's header."""
    _png(path, np.full((30, 40), 800, np.uint16))
    raw = bytearray(path.read_bytes())
    at = raw.index(b"IDAT") - 4
    raw[at:at + 4] = (int.from_bytes(raw[at:at + 4], "big") - 14).to_bytes(4, "big")
    path.write_bytes(bytes(raw))


@pytest.mark.parametrize(("quat", "norm"), [("0 0 0 0", "0"), ("5 5 5 5", "10")])
def test_a_pcd_viewpoint_with_a_non_unit_quaternion_is_refused(capsys, tmp_path, quat, norm):
    # The same rule as --viewpoint-pose (contracts.unit_quaternion): 5 5 5 5 used to pass silently.
    path = tmp_path / "z.pcd"
    path.write_text("VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\n"
                    f"VIEWPOINT 1 2 3 {quat}\nPOINTS 1\nDATA ascii\n1 2 3\n")
    assert main(["estimate", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"z.pcd: VIEWPOINT's quaternion qw qx qy qz must have norm 1 (within 0.001), got {norm}\n" in err
    assert err.count("\n") == 1


def _solid_on_table(kind: str):  # type: ignore[no-untyped-def]
    """A real MuJoCo model of one solid standing on the table (a 6 x 4 x 5 cm box, a 3 cm ball or a 6.6 x 12 cm
    can) and its true volume, m^3."""
    import mujoco

    spec = mujoco.MjSpec()
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.4, 0.3, 0.02], pos=[0, 0, TOP - 0.02])
    geom, size, volume = {"box": (mujoco.mjtGeom.mjGEOM_BOX, [0.03, 0.02, 0.025], 0.06 * 0.04 * 0.05),
                          "ball": (mujoco.mjtGeom.mjGEOM_SPHERE, [0.03, 0, 0], 4 / 3 * np.pi * 0.03**3),
                          "can": (mujoco.mjtGeom.mjGEOM_CYLINDER, [0.033, 0.06, 0], np.pi * 0.033**2 * 0.12)}[kind]
    height = size[2] if kind == "box" else size[0] if kind == "ball" else size[1]
    spec.worldbody.add_geom(type=geom, size=size, pos=[0.0, 0.0, TOP + height])
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return model, data, volume


@pytest.mark.parametrize("kind", ["box", "ball", "can"])
def test_views_given_as_points_carve_as_their_depth_frames(kind):
    """A view that comes as points and its sensor origin (a PCD with a VIEWPOINT) carves the space its points'
    rays passed through, as its depth frame would: one or two cameras, the table cropped close or cut away.
    Without it the unseen far side was closed by a thin shell: one camera gave a box -58 %, a can -81 %,
    two cameras a box -57 %. Within the issue's targets (1 camera: 15 % at worst, 2: 10 %) with room to spare:
    at 1 camera the frames' own carving is 5-9 % off on the ball and the can."""
    from estimation.views import View, estimate_views, plane_from_abcd
    from scenes.cameras import SIGMA_1MM, render

    model, data, volume = _solid_on_table(kind)
    rng = np.random.default_rng(1)
    frames = [render(model, data, cam, noise=SIGMA_1MM, rng=rng) for cam in _cameras()]
    table = plane_from_abcd([0.0, 0.0, 1.0, -TOP])
    for count, within in ((1, 0.12), (2, 0.05)):
        for crop, support, cut_table in [(0.3, "auto", False), (0.08, table, False), (0.3, table, True)]:
            views = []
            for frame in frames[:count]:
                points, _ = frame.points()
                keep = (np.abs(points[:, 0]) < crop) & (np.abs(points[:, 1]) < crop)
                if cut_table:
                    keep &= points[:, 2] > TOP + 0.004
                views.append(View(points[keep], np.asarray(frame.camera.position, float)))
            result = estimate_views(views, 1000.0, support=support)
            case = f"{kind}, {count} camera(s), crop {crop} m, table {'cut' if cut_table else 'kept'}"
            assert result.estimate.volume == pytest.approx(volume, rel=within), case
            low, high = result.volume_bounds_m3
            assert low <= volume <= high, case


def test_a_frame_pictured_from_its_points_says_what_the_frame_says(monkeypatch):
    """`carving.depth_of_points` on a depth frame's own points (edge pixels dropped, as `points()` gives them):
    its pixel is the frame's, it proves free 95 % of what the frame does round a can (97.5-98 % over three
    noise draws), and under 1 % of the can itself (0.3-0.5 %: the frame's dropouts, filled)."""
    from estimation.carving import carving_views, depth_of_points, free_space
    from estimation.views import plane_from_abcd
    from scenes.cameras import SIGMA_1MM, render

    model, data, _ = _solid_on_table("can")
    frame = render(model, data, _cameras()[0], noise=SIGMA_1MM, rng=np.random.default_rng(2))
    points, _ = frame.points()
    table = plane_from_abcd([0.0, 0.0, 1.0, -TOP])
    probes = np.random.default_rng(3).uniform([-0.1, -0.1, TOP + 0.001], [0.1, 0.1, TOP + 0.15], (50_000, 3))
    inside = (np.hypot(probes[:, 0], probes[:, 1]) < 0.033) & (probes[:, 2] < TOP + 0.12)
    real = free_space(probes, carving_views([frame.view()], table, 0.003), slack=0.001)
    for crop in (0.3, 0.08):
        near = (np.abs(points[:, 0]) < crop) & (np.abs(points[:, 1]) < crop)
        (pictured,) = depth_of_points(points[near], np.asarray(frame.camera.position, float), table)
        assert pictured.intrinsics.fx == pytest.approx(frame.view().intrinsics.fx, rel=0.05)
        free = free_space(probes, carving_views([pictured], table, 0.003), slack=0.001)
        assert (free & real).sum() >= 0.95 * real.sum()
        assert free[inside].mean() < 0.01
    # The spacing measured at a sample of a big frame's points is still the frame's pixel: measured among the
    # sample itself, a whole 1280 x 720 frame was pictured at twice the camera's pitch.
    import estimation.carving

    monkeypatch.setattr(estimation.carving, "POINT_IMAGE_SAMPLE", len(points) // 10)
    (sampled,) = depth_of_points(points, np.asarray(frame.camera.position, float), table)
    assert sampled.intrinsics.fx == pytest.approx(frame.view().intrinsics.fx, rel=0.05)
    # Past the point cap, a random quarter is pictured at the pitch a quarter has: about twice the frame's.
    monkeypatch.setattr(estimation.carving, "POINT_IMAGE_MAX_POINTS", len(points) // 4)
    (quarter,) = depth_of_points(points, np.asarray(frame.camera.position, float), table)
    assert 0.3 < quarter.intrinsics.fx / frame.view().intrinsics.fx < 0.6
    # Cut close, the background is the table: the plane's depth on each ray.
    cut = points[np.hypot(points[:, 0], points[:, 1]) < 0.05]
    (known,) = depth_of_points(cut, np.asarray(frame.camera.position, float), table)
    assert np.isfinite(known.depth).all()  # the plane lies ahead of every ray of this camera's image
    rim = np.zeros(known.depth.shape, dtype=bool)
    rim[[0, -1], :] = rim[:, [0, -1]] = True
    from estimation.fusion import depth_to_points

    on_plane, index = depth_to_points(np.where(rim, known.depth, np.nan), known.intrinsics, known.rotation, known.position)
    assert np.abs(table.height(on_plane)).max() < 1e-9 and len(index) == rim.sum()
    # A cloud whose every point has its own origin is no camera's: nothing is pictured.
    cloud = points[:500]
    assert depth_of_points(cloud, cloud + np.array([0.0, 0.0, 0.5]), table) is None


def test_one_pcd_of_a_box_estimates_its_volume_from_the_cli(capsys, tmp_path):
    """The issue's contract end to end: one camera's cloud of a box on the table, as a PCD whose VIEWPOINT is
    the camera, `twin estimate FILE --support-plane auto`. It was -58 % (the far side a thin shell)."""
    from scenes.cameras import SIGMA_1MM, render

    model, data, volume = _solid_on_table("box")
    frame = render(model, data, _cameras()[0], noise=SIGMA_1MM, rng=np.random.default_rng(4))
    points, _ = frame.points()
    near = (np.abs(points[:, 0]) < 0.2) & (np.abs(points[:, 1]) < 0.2)
    save_cloud(make_cloud(points[near], sensor_origins=np.asarray(frame.camera.position, float)), tmp_path / "v.pcd")
    record = _run(capsys, [str(tmp_path / "v.pcd"), "--support-plane", "auto"])
    assert record["volume_m3"] == pytest.approx(volume, rel=0.08)
    low, high = record["volume_bounds_m3"]
    assert low <= volume and (high is None or volume <= high)


@pytest.mark.parametrize("kind", ["can", "ball"])
def test_one_camera_of_a_round_object_keeps_its_volume_under_rigid_motion(kind):
    """Within 0.2 % (the issue asks 0.5 %), plane found in the data. The can moved 1.2 % and the ball 1.0 %:
    the segment's voxels lay on the world's axes (another stray point joined the object per rotation), and the
    carving grid's axis took the SVD's arbitrary sign and its size from the world-axis extent."""
    from scipy.spatial.transform import Rotation

    from estimation.views import View, estimate_views
    from scenes.cameras import SIGMA_1MM, render

    model, data, _ = _solid_on_table(kind)
    frame = render(model, data, _cameras()[0], noise=SIGMA_1MM, rng=np.random.default_rng(1))
    points, _ = frame.points()
    points = points[(np.abs(points[:, 0]) < 0.2) & (np.abs(points[:, 1]) < 0.2)]
    origin = np.asarray(frame.camera.position, float)
    base = estimate_views([View(points, origin)], 1000.0, support="auto").estimate.volume
    rng = np.random.default_rng(7)
    for _ in range(3):
        rot, shift = Rotation.random(random_state=rng).as_matrix(), rng.uniform(-2, 2, 3)
        moved = estimate_views([View(points @ rot.T + shift, rot @ origin + shift)], 1000.0, support="auto")
        assert moved.estimate.volume == pytest.approx(base, rel=0.002)


def test_a_support_plane_far_below_the_object_is_warned_about():
    """A plane given in another frame (the floor for the table, 0.3 m below): the base was closed down to it
    without a word (a 6 x 4 x 5 cm box seen by one camera: +46 %). The plane it rests on gets no such warning."""
    from estimation.views import View, estimate_views, plane_from_abcd
    from scenes.cameras import SIGMA_1MM, render

    model, data, _ = _solid_on_table("box")
    frame = render(model, data, _cameras()[0], noise=SIGMA_1MM, rng=np.random.default_rng(5))
    points, _ = frame.points()
    view = View(points[points[:, 2] > TOP + 0.004], np.asarray(frame.camera.position, float))
    for below, warned in ((0.0, False), (0.3, True)):
        result = estimate_views([view], 1000.0, support=plane_from_abcd([0.0, 0.0, 1.0, -(TOP - below)]))
        said = [w for w in result.warnings if "above the support plane, more than the object is wide" in w]
        assert bool(said) == warned, result.warnings
    assert said[0].startswith("the object's lowest points lie 30")


@pytest.mark.parametrize("below", [10.0, 10_000.0])
def test_a_support_plane_many_widths_below_the_object_is_refused_at_once(capsys, tmp_path, below):
    # Closing the base down to it grew a grid with the gap: a 5 cm dome over a plane 100 m below took 9 GB and
    # 84 s, 10 km below the kernel killed it at 24 GB; 10 m below gave 0.9 m^3 after 16 s. Now one line, exit 2.
    rng = np.random.default_rng(0)
    dome = rng.normal(size=(3000, 3))
    dome = 0.05 * dome / np.linalg.norm(dome, axis=1, keepdims=True)
    np.save(tmp_path / "dome.npy", dome[dome[:, 2] > 0])
    code = main(["estimate", str(tmp_path / "dome.npy"), "--support-plane", "0", "0", "1", str(below),
                 "--viewpoint", "0", "0", "1", "--json"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "support plane: the object's lowest points lie" in err and "times" in err, err


def test_a_small_objects_base_is_not_counted_seen_from_its_side_walls():
    # A 15 mm cube on a table: every point of its base lies within the coverage radius (two 4 mm cells) of its
    # side walls' lowest points, so a 14 mm nut reported coverage 1.00. Points seen only count for faces that
    # face their way.
    import trimesh

    from estimation.coverage import coverage

    cube = trimesh.creation.box(extents=(0.015, 0.015, 0.015))
    points, faces = trimesh.sample.sample_surface_even(cube, 4000, seed=0)
    normals = cube.face_normals[faces]
    seen = normals[:, 2] > -0.5  # the top and the sides, not the base
    blind, total = coverage(cube.vertices, cube.faces, points[seen], radius=0.008)
    facing, _ = coverage(cube.vertices, cube.faces, points[seen], radius=0.008, normals=normals[seen])
    assert blind == pytest.approx(total)
    assert facing == pytest.approx(total * 5 / 6, rel=1e-6)
    unknown, _ = coverage(cube.vertices, cube.faces, points[seen], radius=0.008,
                          normals=np.full_like(normals[seen], np.nan))
    assert unknown == pytest.approx(total)  # a normal that could not be fitted faces any way


def _one_side(mesh, sigma: float, seed: int = 0) -> np.ndarray:
    """The part of ``mesh``'s surface a camera up and to one side sees (no occlusion test: convex shapes), with
    noise of ``sigma`` metres."""
    import trimesh

    points, faces = trimesh.sample.sample_surface_even(mesh, 40_000, seed=seed)
    camera = mesh.centroid + np.array([0.4, -0.3, 0.5])
    seen = np.einsum("ij,ij->i", mesh.face_normals[faces], camera - points) > 0
    return points[seen] + np.random.default_rng(seed).normal(0.0, sigma, (int(seen.sum()), 3))


@pytest.mark.parametrize("sigma", [0.0, 0.001])
@pytest.mark.parametrize("shape", ["box", "can"])
def test_one_view_without_its_origin_is_not_a_confident_wrong_number(capsys, tmp_path, shape, sigma):
    # One camera's points and nothing else: the reconstruction closes a slab around the sheet. A box came out -75 %
    # and a can -87 % with intervals that stopped at a third of the truth, and coverage 0.89 and 0.93.
    import trimesh

    mesh = {"box": trimesh.creation.box(extents=(0.06, 0.04, 0.05)),
            "can": trimesh.creation.cylinder(0.033, 0.12, sections=64)}[shape]
    save_cloud(make_cloud(_one_side(mesh, sigma)), tmp_path / "view.ply")
    out = _run(capsys, [str(tmp_path / "view.ply")])
    assert any("points face only" in w and "one side" in w for w in out["warnings"]), out["warnings"]
    low, high = out["volume_bounds_m3"]
    assert low <= mesh.volume and high is None  # unbounded above: strict JSON says null
    assert out["coverage"] < 0.8


@pytest.mark.parametrize("sigma", [0.0, 0.0005])
@pytest.mark.parametrize("shape", ["box", "ball", "mug"])
def test_a_whole_objects_points_face_all_of_its_surface(shape, sigma):
    import trimesh

    from estimation import estimate
    from scenes.sampling import sample_surface
    from scenes.shapes import make_shapes

    mesh = {"box": trimesh.creation.box(extents=(0.06, 0.04, 0.05)), "ball": trimesh.creation.icosphere(4, 0.03),
            "mug": make_shapes(12, 0)[11].mesh}[shape]
    cloud = sample_surface(mesh, 50_000, seed=3, noise_sigma=sigma, with_normals=False)
    result = estimate(cloud, 1000.0)
    assert not any("points face only" in w for w in result.warnings), result.warnings
    assert np.isfinite(result.volume_bounds_m3[1])


def test_a_depth_image_past_the_pixel_cap_is_thinned_to_the_same_points(caplog):
    # A 4096 x 4096 frame took 2.8 GB as points; past MAX_VIEW_PIXELS every stride-th row and column is read,
    # and each of those pixels lands where it would have in the whole image.
    from estimation.depthimage import MAX_VIEW_PIXELS, coarsened, intrinsics
    from estimation.fusion import depth_to_points

    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 1.5, size=(301, 403))
    depth[rng.random(depth.shape) < 0.1] = np.nan
    camera = intrinsics(350.0, 340.0, 201.3, 149.8, width=403, height=301)
    assert coarsened(depth, camera) == (depth, camera, 1)  # under the cap: untouched
    assert MAX_VIEW_PIXELS >= 1920 * 1080
    thin, grid, stride = coarsened(depth, camera, max_pixels=20_000)
    assert stride == 3 and thin.shape == (101, 135) and "read every 3rd pixel of the 403x301 depth image" in caplog.text
    rot, pos = np.eye(3), np.array([0.1, -0.2, 0.3])
    whole, index = depth_to_points(depth, camera, rot, pos)
    kept = {int(i): p for i, p in zip(index, whole, strict=True)}
    points, thin_index = depth_to_points(thin, grid, rot, pos)
    rows, cols = np.divmod(thin_index, thin.shape[1])
    expected = np.array([kept[int(r * stride * depth.shape[1] + c * stride)] for r, c in zip(rows, cols, strict=True)])
    assert np.allclose(points, expected, rtol=0, atol=1e-12)
    # A narrow image thins by less than stride^2: the stride grows until the cap holds (1 x 16 M came out 5.3 M).
    row = np.ones((1, 40_000))
    thin, _, stride = coarsened(row, intrinsics(100.0, 100.0, 20_000.0, 0.5, width=40_000, height=1),
                                max_pixels=5_000)
    assert stride == 8 and thin.size == 5_000


def test_non_square_pixels_back_project_where_the_square_ones_they_came_from_do():
    # Every 2nd column (or row) of a frame is the frame of a camera whose pixels are twice as wide (tall):
    # fx (fy) halves, the principal point with it. Each kept pixel must land where it did in the whole frame,
    # up to the bound on fx / fy, which still takes a 2x anamorphic lens on 2x binning (4:1) and no more.
    from estimation.depthimage import MAX_PIXEL_ASPECT, intrinsics
    from estimation.fusion import depth_to_points

    rng = np.random.default_rng(1)
    depth = rng.uniform(0.5, 1.5, size=(120, 160))
    camera = intrinsics(300.0, 300.0, 79.3, 60.2, width=160, height=120)  # OpenCV's cx, cy
    rot, pos = np.eye(3), np.array([0.1, -0.2, 0.3])
    whole, _ = depth_to_points(depth, camera, rot, pos)
    whole = whole.reshape(120, 160, 3)
    for stride_x, stride_y in ((2, 1), (1, 2), (4, 1), (1, 4)):
        thin = depth[::stride_y, ::stride_x]
        grid = intrinsics(300.0 / stride_x, 300.0 / stride_y, 79.3 / stride_x, 60.2 / stride_y,
                          width=thin.shape[1], height=thin.shape[0])
        points, _ = depth_to_points(thin, grid, rot, pos)
        expected = whole[::stride_y, ::stride_x].reshape(-1, 3)
        np.testing.assert_allclose(points, expected, rtol=0, atol=1e-12)
    assert MAX_PIXEL_ASPECT == 4.0
    with pytest.raises(CloudError, match=r"^focal lengths fx 75 and fy 300.1 differ 4\.001-fold"):
        intrinsics(75.0, 300.1, 79.3, 60.2, width=160, height=120)


@pytest.mark.parametrize("sigma", [0.0005, 0.0002, 0.0])
def test_two_frames_from_one_camera_are_one_object(sigma):
    # Each point lay a noise away from its twin in the other frame (on it, at sigma 0): the clustering cell,
    # counted in the union's spacing, shrank to the noise and the box fell apart: -84 % at 0.5 mm, "no object
    # above the support plane" at 0.2 mm.
    import trimesh

    from estimation.views import View, estimate_views, plane_from_abcd

    box = trimesh.creation.box(extents=[0.10, 0.06, 0.04])
    pts, idx = trimesh.sample.sample_surface(box, 4000, seed=0)
    pts, normals = pts + np.array([0, 0, 0.02]), box.face_normals[idx]
    cam = np.array([0.3, 0.1, 0.3])
    seen = pts[((cam - pts) * normals).sum(1) > 0]
    rays = (seen - cam) / np.linalg.norm(seen - cam, axis=1)[:, None]
    rng = np.random.default_rng(1)
    frames = [seen + rays * rng.normal(0, sigma, (len(seen), 1)) for _ in range(2)]
    plane = plane_from_abcd([0, 0, 1, 0])
    one = estimate_views([View(frames[0], cam, "f1")], 1000.0, support=plane)
    two = estimate_views([View(f, cam, f"f{k}") for k, f in enumerate(frames)], 1000.0, support=plane)
    assert two.estimate.volume == pytest.approx(one.estimate.volume, rel=0.03)
    assert not any("lie apart from the object" in w for w in two.warnings), two.warnings


def test_a_support_plane_given_to_the_api_is_made_unit_or_refused():
    from estimation.segmentation import Plane

    points = np.random.default_rng(0).uniform([-0.05, -0.03, 0.0], [0.05, 0.03, 0.04], (4000, 3))
    view = View(points, np.array([0.0, 0.0, 1.0]))
    unit = estimate_views([view], 1000.0, support=Plane(np.array([0.0, 0.0, 1.0]), 0.0, 0.0, 0)).estimate.volume
    for scale in (2.0, 1000.0):  # a normal of length 2 doubled the volume; of 1000, asked for 1 TiB
        plane = Plane(np.array([0.0, 0.0, scale]), 0.0, 0.0, 0)
        assert estimate_views([view], 1000.0, support=plane).estimate.volume == pytest.approx(unit, rel=1e-9)
    assert estimate_views([view], 1000.0, support=[0, 0, 1, 0]).estimate.volume == pytest.approx(unit, rel=1e-9)
    for bad, said in ((Plane(np.array([np.nan, 0.0, 1.0]), 0.0, 0.0, 0), "four finite numbers"),
                      (Plane(np.array([0.0, 0.0, 1.0]), 0.0, -1.0, 0), "its rms must be"),
                      ([0, 0, 0, 0], "normal .* is zero"), (7, "four finite numbers")):
        with pytest.raises(CloudError, match=f"support plane: .*{said}"):
            estimate_views([view], 1000.0, support=bad)


def test_a_sparse_table_does_not_cut_away_the_object_standing_on_it():
    """A table sampled every 11 mm under a 2 cm cube sampled every 0.6 mm: the table's spacing set a 15 mm
    band cut above the plane, and three quarters of the cube went with it."""
    from estimation.views import plane_from_abcd

    rng = np.random.default_rng(0)
    table = np.c_[rng.uniform(-0.5, 0.5, (8000, 2)), rng.normal(0, 0.0005, 8000)]
    cube = rng.uniform(-0.01, 0.01, (3000, 3))
    face = rng.integers(0, 5, 3000)
    cube[face == 0, 2] = 0.01
    for k, (axis, side) in enumerate([(0, 1), (0, -1), (1, 1), (1, -1)], start=1):
        cube[face == k, axis] = 0.01 * side
    cube += [0.0, 0.0, 0.01]
    result = estimate_views([View(np.vstack([table, cube]), np.array([0.0, 0.0, 1.0]))], 1000.0,
                            support=plane_from_abcd([0, 0, 1, 0]))
    seen = int((cube[:, 2] > 0.003).sum())  # the cube's points above any noise band of the table
    assert result.object_points >= seen


def test_views_may_come_from_a_generator_or_a_tuple():
    """A generator was used up by the type check: "no view saw any point of the object"."""
    points, origin = _ball_view()
    volume = estimate_views([View(points, origin)], 1000.0, support="auto").estimate.volume
    assert estimate_views((View(p, o) for p, o in [(points, origin)]), 1000.0, support="auto").estimate.volume == volume
    assert estimate_views((View(points, origin),), 1000.0, support="auto").estimate.volume == volume
    with pytest.raises(TypeError, match=r"^estimate_views takes a list of View records"):
        estimate_views(5, 1000.0)  # not iterable at all


@pytest.mark.parametrize(("seed", "shown"), [
    (-1, "-1"),  # numpy: "expected non-negative integer"
    (1.5, "1.5"),  # numpy: a SeedSequence TypeError
    ("x", "'x'"),
    (True, "True"),
    pytest.param(-(2**5000), "an integer of 5001 bits", id="huge"),  # its repr is past Python's 4300 digits
])
def test_a_seed_numpy_cannot_take_is_one_line_naming_it(seed, shown):
    from estimation import SettingsError

    with pytest.raises(SettingsError, match=rf"^seed must be a whole number >= 0, got {re.escape(shown)}$"):
        estimate_views([View(*_ball_view())], 1000.0, support="auto", seed=seed)


def test_any_whole_seed_numpy_takes_is_taken():
    points, origin = _ball_view()
    for seed in (0, np.int64(7), 2**70):
        assert estimate_views([View(points, origin)], 1000.0, support="auto", seed=seed).estimate.volume > 0


def test_depth_frames_that_cut_the_object_leave_its_volume_unbounded_above(capsys, tmp_path):
    """`twin estimate A.npy B.npy --intrinsics ...` of two frames that both end before a box's far end: the
    interval stopped at 0.89 of the true volume. Past the frames nobody looked, so it has no top, and says why."""
    from scipy.spatial.transform import Rotation

    from tests.test_carving import CUT_BOX, CUT_TOP, NARROW, box_frame

    truth = float(np.prod(CUT_BOX))
    files, argv = [], []
    for k, camera in enumerate(NARROW):
        _, view = box_frame(*camera, seed=k)
        np.save(tmp_path / f"d{k}.npy", view.depth)
        x, y, z, w = Rotation.from_matrix(view.rotation).as_quat()  # scipy: x y z w
        files.append(str(tmp_path / f"d{k}.npy"))
        argv += ["--viewpoint-pose", *map(str, (*view.position, w, x, y, z))]
    intr = view.intrinsics  # fusion's pixel centres are at +0.5; OpenCV's cx is half a pixel less
    argv += ["--intrinsics", str(intr.fx), str(intr.fy), str(intr.cx - 0.5), str(intr.cy - 0.5),
             "--support-plane", "0", "0", "1", str(-CUT_TOP)]
    record = _run(capsys, [*files, *argv])
    low, high = record["volume_bounds_m3"]
    assert low <= truth and high is None  # JSON has no infinity: null
    assert any("runs out of a depth image's frame" in w for w in record["warnings"])


def test_a_clouds_completed_points_widen_its_interval_to_what_was_observed():
    # What the twin does with a camera cloud's completed flags (sync.messages.Cloud.completed): the interval
    # rests on the observed points, as estimate_views' does, not on the completed ones counted as measured.
    import trimesh

    from estimation.views import assess, with_completion

    box = trimesh.creation.box((0.10, 0.06, 0.085))
    box.apply_translation((0.0, 0.0, 0.0425))
    points, faces = trimesh.sample.sample_surface(box, 40_000, seed=1)
    normals = box.face_normals[faces]
    est = estimate(make_cloud(points, normals), 1000.0)
    base = points[:, 2] < 1e-6  # the base, closed on the support plane
    low, high = est.volume_bounds_m3
    got = with_completion(est, points, base, normals=normals)
    share, (a, b) = assess(est, points[~base], 0.0, normals=normals[~base])
    assert 0.8 < share < 0.9  # the base is 0.0060 of 0.0373 m^2
    assert got.volume_bounds_m3[0] <= min(a, low) + 1e-12 and got.volume_bounds_m3[1] >= max(b, high) - 1e-12
    assert got.volume_bounds_m3[0] < low - 0.02 * est.volume and got.volume_bounds_m3[1] > high + 0.02 * est.volume
    assert got.volume_bounds_m3[0] < box.volume < got.volume_bounds_m3[1]
    assert "completed by the sender" in got.warnings[-1] and got.volume == est.volume and got.mass == est.mass
    # Nothing completed: the estimate as it was. Almost everything completed: nothing bounds it.
    assert with_completion(est, points, np.zeros(len(points), bool)) is est
    almost = np.ones(len(points), bool)
    almost[:50] = False
    assert with_completion(est, points, almost).volume_bounds_m3 == (0.0, float("inf"))
    with pytest.raises(ValueError, match="flags"):
        with_completion(est, points, base[:-1])


def _bracket_views(views):  # type: ignore[no-untyped-def]
    return [View(points, origin, name=f"v{k}") for k, (points, origin) in enumerate(views)]


def test_a_stray_point_or_a_view_of_a_few_points_does_not_stop_the_others_carving(views):
    """A view that cannot be pictured as a depth image carves nothing; the others still carve. Until session 41
    one such view (a stray point behind its sensor, a third view of 5 points) stopped every view carving, in
    silence: a box seen by two cameras came out -67 %."""
    plane = (0.0, 0.0, 1.0, -TOP)
    clean = _bracket_views(views)
    base = estimate_views(clean, 1000.0, support=plane).estimate.volume
    points, origin = views[1]
    away = (origin - points.mean(axis=0)) / np.linalg.norm(origin - points.mean(axis=0))
    stray = [clean[0], View(np.vstack([points, origin + 0.3 * away]), origin, name="v1")]
    few = [*clean, View(views[0][0][:5] + np.array([0.0, 0.0, 0.01]), views[0][1], name="few")]
    for label, case in (("stray", stray), ("few", few)):
        got = estimate_views(case, 1000.0, support=plane)
        assert got.estimate.volume == pytest.approx(base, rel=0.01), label
    assert any(w.startswith("few could not be pictured") for w in got.warnings)


def test_a_given_plane_cutting_into_the_object_is_refused(views):
    """The bracket's foot is 15 mm tall: a plane 10 mm up it, given for the views cropped above the table, had
    8-10 % of the points under it, within the share the below-test allows, and took a quarter off in silence."""
    cropped = [View(p[p[:, 2] > TOP + 0.003], o) for p, o in views]
    assert estimate_views(cropped, 1000.0, support=(0.0, 0.0, 1.0, -TOP)).estimate.volume > 0
    with pytest.raises(CloudError, match=r"support plane: \d+ points lie up to .* mm below it, under the object .* "
                                         r"cuts into the object"):
        estimate_views(cropped, 1000.0, support=(0.0, 0.0, 1.0, -(TOP + 0.01)))


def test_a_sensor_below_the_support_plane_is_refused(views):
    """A camera sees what rests on a plane from above: a sensor below a given plane (a VIEWPOINT mirrored, a
    plane in another frame) is refused. The horizontal plane ``auto`` falls back to is a guess, not the user's
    word: one a sensor lies below is dropped, said, and the views are closed as with no plane (it was refused
    as a given plane is, and a cereal box's views cropped at the table's edge, turned into another frame,
    could not be estimated with ``auto`` at all: bench/rigid_motion.py)."""
    (p0, o0), (p1, o1) = views
    below = [View(p0, o0), View(p1, o1 * [1.0, 1.0, -1.0], name="mirrored")]
    with pytest.raises(CloudError, match=r"support plane: the sensor of mirrored lies \d+ mm below it"):
        estimate_views(below, 1000.0, support=(0.0, 0.0, 1.0, -TOP))
    above_table = [View(v.points[v.points[:, 2] > TOP + 0.003], v.origin, name=v.name) for v in below]
    guessed = estimate_views(above_table, 1000.0, support="auto")
    unsupported = estimate_views(above_table, 1000.0, support=None)
    assert guessed.plane is None
    assert any(re.search(r"no support plane in the data, and the horizontal plane through the lowest point will not "
                         r"do \(the sensor of mirrored lies \d+ mm below it\): closed without a support plane", w)
               for w in guessed.warnings), guessed.warnings
    assert guessed.estimate.volume == unsupported.estimate.volume


def test_a_view_that_shows_none_of_the_object_is_named(views):
    """A view with nothing of the object in it (only the table; or in other units or another frame, cut away
    with the table) is named in a warning; before, it went into the table in silence."""
    (p0, o0), (p1, o1) = views
    table = p1[(p1[:, 2] < TOP + 0.002) & (np.abs(p1[:, 0]) > 0.09)]
    got = estimate_views([View(p0, o0), View(p1, o1), View(table, o1, name="table only")], 1000.0,
                         support=(0.0, 0.0, 1.0, -TOP))
    assert any(w.startswith("none of the points of table only lie on the object") for w in got.warnings)


def test_a_view_reaching_too_far_is_named(views):
    """Coordinates beyond range are refused naming the view they came from (a PCD of doubles under a SIZE 4
    header read as 3.4e38 m, and the error did not say which of the files it was)."""
    (p0, o0), (p1, o1) = views
    wild = np.vstack([p1, [[3.4e38, 0.0, 0.0]]])
    with pytest.raises(CloudError, match=r"^wild\.pcd: coordinates reach 3\.4e\+38 m from the origin"):
        estimate_views([View(p0, o0, name="good.pcd"), View(wild, o1, name="wild.pcd")], 1000.0, support="auto")


def test_a_depth_image_at_the_wrong_scale_says_so():
    """Millimetres read as metres (--depth-scale 1) step a metre or more from pixel to pixel: every pixel is on a
    depth edge. That was refused as "the view has no points"; the error now names the depths and the scale."""
    from estimation.depthimage import depth_view, intrinsics

    rows, cols = np.mgrid[0:48, 0:64]
    depth = 400.0 + 3.0 * rows + 2.0 * cols  # a tilted plane about half a metre away, in millimetres
    camera = intrinsics(60.0, 60.0, 32.0, 24.0, width=64, height=48)
    with pytest.raises(CloudError, match=r"the depths run 400\.\.667 m; is the depth scale right"):
        depth_view(depth, camera, np.eye(3), np.zeros(3))
    points, _ = depth_view(depth / 1000.0, camera, np.eye(3), np.zeros(3))
    assert len(points) > 0.8 * depth.size


def test_what_lies_below_the_support_plane_is_cut_away_and_the_mass_follows():
    from dataclasses import replace

    import trimesh

    from estimation.estimate import from_mesh
    from estimation.views import on_support, plane_from_abcd

    box = trimesh.creation.box((0.1, 0.1, 0.1))  # z from -0.05 to 0.05
    whole = from_mesh(np.asarray(box.vertices), np.asarray(box.faces), 1000.0)
    cut = on_support(whole, plane_from_abcd((0.0, 0.0, 1.0, 0.045)))  # z = -0.045, up into the box
    assert cut.volume == pytest.approx(0.1 * 0.1 * 0.095, rel=1e-9)
    assert cut.mass.mass == pytest.approx(cut.volume * 1000.0, rel=1e-12)
    assert cut.mass.center_of_mass[2] == pytest.approx(0.0025, abs=1e-9)  # the middle of -0.045 .. 0.05
    assert cut.vertices[:, 2].min() == pytest.approx(-0.045, abs=1e-12) and cut.warnings == whole.warnings
    # A plane the surface does not reach below leaves the estimate as it is (the same record).
    assert on_support(whole, plane_from_abcd((0.0, 0.0, 1.0, 0.05))) is whole
    assert on_support(whole, None) is whole
    # A plane with most of the cloud below it is not what the object rests on: nothing cut, and said.
    points = np.random.default_rng(0).uniform(-0.05, 0.05, (1000, 3))
    high = on_support(replace(whole, cell=0.001), plane_from_abcd((0.0, 0.0, 1.0, -0.02)), points=points)
    assert high.volume == whole.volume and "so it is not the object's: nothing cut" in high.warnings[-1]
    above = on_support(whole, plane_from_abcd((0.0, 0.0, 1.0, -0.06)))  # z = 0.06, over the whole box
    assert above.volume == whole.volume and "the whole surface lies below" in above.warnings[-1]
    # A surface manifold3d cannot take as closed (a face missing) is kept whole, and said.
    opened = from_mesh(np.asarray(box.vertices), np.asarray(box.faces)[1:], 1000.0)
    kept = on_support(opened, plane_from_abcd((0.0, 0.0, 1.0, 0.045)))
    assert np.array_equal(kept.vertices, opened.vertices) and "not a closed manifold" in kept.warnings[-1]


def test_a_cut_at_the_support_plane_keeps_the_inertia_and_curvature_of_what_is_left():
    from dataclasses import replace

    import trimesh

    from estimation.estimate import from_mesh
    from estimation.views import on_support, plane_from_abcd

    box = trimesh.creation.box((0.1, 0.06, 0.1))
    cut = on_support(from_mesh(np.asarray(box.vertices), np.asarray(box.faces), 1000.0),
                     plane_from_abcd((0.0, 0.0, 1.0, 0.03)))  # z = -0.03: a 0.1 x 0.06 x 0.08 box is left
    mass = 1000.0 * 0.1 * 0.06 * 0.08
    expected = mass / 12 * np.array([0.06**2 + 0.08**2, 0.1**2 + 0.08**2, 0.1**2 + 0.06**2])
    assert np.allclose(np.diag(cut.mass.inertia), expected, rtol=1e-9) and abs(cut.mass.inertia[0, 1]) < 1e-12
    assert cut.mass.center_of_mass == pytest.approx([0.0, 0.0, 0.01], abs=1e-12)
    # What an estimate holds beyond its flat mesh (curved slivers, estimation.curvature) is not cut with the
    # piece below: a ball's estimate cut a hair under its lowest vertex keeps its volume, and its interval moves
    # down by what was cut.
    rng = np.random.default_rng(5)
    d = rng.normal(size=(20_000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ball = estimate(make_cloud(0.03 * d, d), 1000.0)
    assert ball.volume != pytest.approx(float(trimesh.Trimesh(ball.vertices, ball.faces).volume), rel=1e-4)
    lowest = float(ball.vertices[:, 2].min())
    hair = on_support(ball, plane_from_abcd((0.0, 0.0, 1.0, -(lowest + 1e-7))))
    assert len(hair.faces) != len(ball.faces) and hair.volume == pytest.approx(ball.volume, rel=1e-6)
    sliced = on_support(replace(ball, volume_bounds_m3=(1e-4, 1.2e-4)), plane_from_abcd((0.0, 0.0, 1.0, 0.029)))
    cut_away = ball.volume - sliced.volume
    assert cut_away > 0 and sliced.volume_bounds_m3 == pytest.approx((1e-4 - cut_away, 1.2e-4 - cut_away))
