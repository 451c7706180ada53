"""Cloud objects carry their frame's pose (quat or rotation matrix) and viewpoints, from file to body."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from estimation import make_cloud, save_cloud
from scenes.build import build_scene, estimates_record
from scenes.sampling import sample_surface
from scenes.scenefile import SceneError, parse_scene
from scenes.sources import scene_cloud
from twin.poses import rotation

#: A turn of 120 degrees about (1, 1, 1): every axis moves, so a frame rotation that is ignored shows.
Q_SCENE = np.array([0.5, 0.5, 0.5, 0.5])


def _turn(axis: tuple[float, float, float], degrees: float) -> np.ndarray:
    a = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    half = np.radians(degrees) / 2
    return rotation(np.array([np.cos(half), *(np.sin(half) * a)]))


#: How the scan is turned inside the second file.
R_FILE = _turn((0.3, -1.0, 0.5), 70.0)


def _scan(folder: Path, name: str, turn: np.ndarray | None = None, *, normals: bool = False,
          origin: np.ndarray | None = None) -> Path:
    """A 12 x 8 x 5 cm box, centred 2 cm off its file's origin, sampled at 20k points (metres)."""
    box = trimesh.creation.box(extents=(0.12, 0.08, 0.05))
    box.apply_translation((0.02, -0.01, 0.03))
    cloud = sample_surface(box, 20_000, seed=3)
    turn = np.eye(3) if turn is None else turn
    pts = cloud.points @ turn.T
    out = make_cloud(pts, cloud.normals @ turn.T if normals else None, sensor_origins=origin)
    save_cloud(out, folder / name)
    return folder / name


def _scene(folder: Path, **obj: object) -> dict:
    return {"name": "posed", "table": {"size": [1.0, 1.0, 0.04], "height": 0.5},
            "objects": [{"id": "scan", "material": "pla", **obj}]}


@pytest.mark.parametrize("position", [[0.1, -0.05, 0.8], [0.1, -0.05]])
def test_a_turned_file_with_the_inverse_turn_in_the_scene_gives_the_same_body(tmp_path, position):
    _scan(tmp_path, "a.ply")
    _scan(tmp_path, "b.ply", R_FILE)
    cache = tmp_path / "coacd"
    # The same scan twice: as scanned with the scene's pose, and turned by R_FILE inside its file with the
    # inverse turn composed into the scene's pose (given as a matrix, to cover both spellings).
    a = parse_scene(_scene(tmp_path, cloud="a.ply", quat=Q_SCENE.tolist(), position=position), base=tmp_path)
    b = parse_scene(_scene(tmp_path, cloud="b.ply", rotation=(rotation(Q_SCENE) @ R_FILE.T).tolist(),
                           position=position), base=tmp_path)
    (body_a,) = build_scene(a, cache_dir=cache, progress=False).objects
    (body_b,) = build_scene(b, cache_dir=cache, progress=False).objects
    va, vb = body_a.estimate.mass.volume, body_b.estimate.mass.volume
    assert abs(va - vb) / va < 0.005
    assert abs(va - 0.12 * 0.08 * 0.05) / va < 0.02  # and it is the box
    np.testing.assert_allclose(body_a.quat, body_b.quat)
    # The estimate's centre of mass moves with the points' sampling on the grid: well under a millimetre.
    assert np.linalg.norm(body_a.position - body_b.position) < 5e-4
    world_a = body_a.visual[0] + body_a.position
    world_b = body_b.visual[0] + body_b.position
    np.testing.assert_allclose(world_a.min(axis=0), world_b.min(axis=0), atol=1e-3)
    np.testing.assert_allclose(world_a.max(axis=0), world_b.max(axis=0), atol=1e-3)
    centre = rotation(Q_SCENE) @ np.array([0.02, -0.01, 0.03])  # the box's centre in world axes
    if len(position) == 3:  # the frame's origin exactly at position: the box where the pose puts it
        np.testing.assert_allclose(body_a.position, np.asarray(position) + centre, atol=1e-3)
    else:  # x and y from the pose, resting on the table
        np.testing.assert_allclose(body_a.position[:2], np.asarray(position) + centre[:2], atol=1e-3)
        assert abs(world_a[:, 2].min() - 0.5) < 3e-3
    record = estimates_record(build_scene(b, cache_dir=cache, progress=False))["objects"][0]
    turn = rotation(np.asarray(record["source_to_body"]["quat_wxyz"]))
    np.testing.assert_allclose(turn, rotation(Q_SCENE) @ R_FILE.T, atol=1e-9)


def test_without_a_pose_a_cloud_is_placed_by_its_centre_of_mass_as_before(tmp_path):
    _scan(tmp_path, "a.ply")
    spec = parse_scene(_scene(tmp_path, cloud="a.ply", position=[0.1, -0.05, 0.8]), base=tmp_path)
    (body,) = build_scene(spec, cache_dir=tmp_path / "coacd", progress=False).objects
    np.testing.assert_allclose(body.position, [0.1, -0.05, 0.8])


def test_viewpoints_are_turned_with_the_cloud_and_scaled_to_metres(tmp_path):
    _scan(tmp_path, "a.ply")
    (tmp_path / "mm.xyz").write_text("\n".join(f"{x} {y} {z}" for x, y, z in np.random.default_rng(0).uniform(
        0, 50, (200, 3))))
    spec = parse_scene(_scene(tmp_path, cloud="mm.xyz", units="mm", quat=[0.0, 1.0, 0.0, 0.0],  # 180 about x
                              viewpoints=[[0, 0, 500]]), base=tmp_path).objects[0]
    _, viewpoint = scene_cloud(spec)
    np.testing.assert_allclose(viewpoint, [0.0, 0.0, -0.5], atol=1e-12)


def test_several_viewpoints_orient_each_normal_towards_the_nearest(tmp_path):
    _scan(tmp_path, "a.ply")
    views = [[0.02, -0.01, 1.03], [0.02, -0.01, -0.97]]  # a metre above and below the box's centre
    spec = parse_scene(_scene(tmp_path, cloud="a.ply", viewpoints=views), base=tmp_path).objects[0]
    cloud, viewpoint = scene_cloud(spec)
    assert viewpoint is None and cloud.normals is not None
    p = cloud.points
    inner = (np.abs(p[:, 0] - 0.02) < 0.04) & (np.abs(p[:, 1] + 0.01) < 0.02)  # away from the edges
    top, bottom = inner & (p[:, 2] > 0.0549), inner & (p[:, 2] < 0.0051)  # the two large faces
    assert top.sum() > 1000 and bottom.sum() > 1000
    assert (cloud.normals[top, 2] > 0.9).all() and (cloud.normals[bottom, 2] < -0.9).all()


def test_a_pcd_viewpoint_is_used_when_the_scene_gives_none(tmp_path):
    _scan(tmp_path, "a.pcd", origin=np.array([0.0, 0.0, 0.7]))
    spec = parse_scene(_scene(tmp_path, cloud="a.pcd", quat=[0.0, 1.0, 0.0, 0.0]), base=tmp_path).objects[0]
    _, viewpoint = scene_cloud(spec)
    np.testing.assert_allclose(viewpoint, [0.0, 0.0, -0.7], atol=1e-6)  # turned with the cloud
    given = parse_scene(_scene(tmp_path, cloud="a.pcd", viewpoints=[[1, 2, 3]]), base=tmp_path).objects[0]
    np.testing.assert_allclose(scene_cloud(given)[1], [1, 2, 3])  # the scene's wins


@pytest.mark.parametrize(
    ("obj", "message"),
    [
        ({"quat": [1, 0, 0]}, r"^object 'scan' quat: expected 4 numbers, got 3$"),
        ({"quat": [1, 0, 0, 0.1]}, r"^object 'scan' quat: must be a unit quaternion \[w, x, y, z\], got norm 1.00499$"),
        ({"quat": [1, 0, float("nan"), 0]}, r"^object 'scan' quat\[2\]: must be finite, got nan$"),
        ({"rotation": [[1, 0, 0], [0, 1, 0]]}, r"^object 'scan' rotation: expected 3 rows of 3 numbers, got 2$"),
        ({"rotation": [[1, 0, 0], [0, 1, 0], [0, 1]]}, r"^object 'scan' rotation\[2\]: expected 3 numbers, got 2$"),
        ({"rotation": [[1, 0, 0], [0, 1, 0], [0, 0, -1]]}, r"^object 'scan' rotation: must be a rotation matrix .* "
                                                           r"determinant -1$"),
        ({"rotation": [[1, 0, 0], [0, 1.01, 0], [0, 0, 1]]}, r"rotation: must be a rotation matrix .* 0\.0201 off"),
        # Finite, but R^T R overflows (inf, or NaN where inf meets -inf): refused, without numpy's warnings.
        ({"rotation": [[1e200, 1e200, 0], [1e200, -1e200, 0], [0, 0, 1]]}, r"rotation: must be a rotation matrix"),
        ({"rotation": [[1, 0, 0], [0, 1, True], [0, 0, 1]]}, r"^object 'scan' rotation\[1\]\[2\]: expected a number, "
                                                              r"got bool True$"),
        ({"quat": [1, 0, 0, 0], "rotation": np.eye(3).tolist()}, r"^object 'scan': give 'quat' or 'rotation', not both$"),
        ({"rotation_deg": [0, 0, 30]}, r"^object 'scan': rotation_deg does not turn a cloud; give its frame's "
                                       r"orientation as quat"),
        ({"viewpoints": []}, r"^object 'scan' viewpoints: expected a list of 1 to 64 \[x, y, z\] points, got 0$"),
        ({"viewpoints": [[0, 0]]}, r"^object 'scan' viewpoints\[0\]: expected 3 numbers, got 2$"),
        ({"viewpoints": [[0, 0, float("inf")]]}, r"^object 'scan' viewpoints\[0\]\[2\]: must be finite, got inf$"),
        ({"cloud": None, "paper": "mug", "quat": [1, 0, 0, 0]},
         r"^object 'scan': 'quat' is for cloud sources only \(a paper turns by rotation_deg\)$"),
        ({"cloud": None, "primitive": {"type": "box", "size": [1, 1, 1]}, "viewpoints": [[0, 0, 1]]},
         r"^object 'scan': 'viewpoints' is for cloud sources only"),
    ],
)
@pytest.mark.filterwarnings("error")
def test_bad_poses_are_one_scene_error_naming_the_key(tmp_path, obj, message):
    (tmp_path / "a.ply").write_text("")
    full = {"cloud": "a.ply", **obj}
    with pytest.raises(SceneError, match=message) as info:
        parse_scene(_scene(tmp_path, **{k: v for k, v in full.items() if v is not None}), base=tmp_path)
    assert "\n" not in str(info.value)


def test_a_nearly_orthonormal_matrix_is_made_an_exact_rotation(tmp_path):
    (tmp_path / "a.ply").write_text("")
    nearly = (_turn((0, 0, 1), 30) + 2e-4).tolist()  # hand-typed decimals: within the tolerance
    spec = parse_scene(_scene(tmp_path, cloud="a.ply", rotation=nearly), base=tmp_path).objects[0]
    m = np.asarray(spec.frame_rotation)
    np.testing.assert_allclose(m.T @ m, np.eye(3), atol=1e-12)
    assert abs(np.linalg.det(m) - 1) < 1e-12


def test_a_posed_cloud_whose_own_coordinates_leave_the_scene_is_refused(tmp_path):
    # The scene file's position is bounded (and checked against the workspace), but a posed cloud adds its own
    # coordinates to it: a cloud 8.7 km out built a body at (5000, 5000, 5001) m, with no word.
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    far = sample_surface(box, 5000, seed=0).points + 5000.0
    save_cloud(make_cloud(far), tmp_path / "far.ply")
    near = sample_surface(box, 5000, seed=0).points + np.array([2.0, 0.0, 0.0])
    save_cloud(make_cloud(near), tmp_path / "near.ply")
    cache = tmp_path / "coacd"
    scene = parse_scene(_scene(tmp_path, cloud="far.ply", quat=[1, 0, 0, 0], position=[0, 0, 1]), base=tmp_path)
    with pytest.raises(SceneError, match=r"^object 'scan': its cloud's own coordinates place it at \[5000.* beyond "
                                         r"the 1000 m a scene holds"):
        build_scene(scene, cache_dir=cache, progress=False, workers=1)
    doc = _scene(tmp_path, cloud="near.ply", quat=[1, 0, 0, 0], position=[0, 0])
    doc["workspace"] = {"min": [-1.0, -1.0, 0.0], "max": [1.0, 1.0, 2.0]}
    with pytest.raises(SceneError, match=r"^object 'scan': its cloud's own coordinates place it at \[ ?2\..* outside "
                                         r"the workspace"):
        build_scene(parse_scene(doc, base=tmp_path), cache_dir=cache, progress=False, workers=1)
