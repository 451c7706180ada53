"""Strays: points apart from the object are dropped and said; the object's own parts never are."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from estimation import estimate, make_cloud
from estimation.spacing import point_spacing
from estimation.strays import STRAY_SHARE, islands

RADIUS = 0.05
BALL = 4 / 3 * np.pi * RADIUS**3


def _ball(n: int, seed: int, radius: float = RADIUS, center=(0.0, 0.0, 0.0)) -> np.ndarray:  # type: ignore[no-untyped-def]
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return radius * v / np.linalg.norm(v, axis=1, keepdims=True) + np.asarray(center)


def _strays(seed: int) -> np.ndarray:
    """30 single points in a 1 m box, and two clumps of 8 points (a reflection, a speck of background),
    none within 2 cm of the ball."""
    rng = np.random.default_rng(seed)
    single = rng.uniform(-0.5, 0.5, size=(200, 3))
    single = single[np.linalg.norm(single, axis=1) > RADIUS + 0.02][:30]
    clumps = [c + rng.normal(scale=0.002, size=(8, 3)) for c in ([0.0, 0.0, 0.1], [0.15, -0.1, 0.0])]
    return np.vstack([single, *clumps])


@pytest.mark.parametrize("seed", [0, 1])
def test_outliers_around_a_ball_are_dropped_and_the_volume_holds(seed):
    ball, strays = _ball(20_000, seed), _strays(seed)
    kept = estimate(make_cloud(np.r_[ball, strays]), 1000.0, keep_strays=True)
    est = estimate(make_cloud(np.r_[ball, strays]), 1000.0)
    # Kept, the 46 strays cost percents and call the surface open; dropped, the ball is as if they never were.
    assert abs(kept.mass.volume / BALL - 1) > 0.02
    assert abs(est.mass.volume / BALL - 1) < 0.003
    assert est.points_in == 20_000
    assert any(w.startswith(f"dropped {len(strays)} stray point(s) in 32 cluster(s)") for w in est.warnings)
    assert not any("not measured" in w or "open" in w for w in est.warnings), est.warnings


def test_normals_and_sensor_origins_follow_the_points_they_belong_to():
    ball, strays = _ball(5000, 3), _strays(3)
    points = np.r_[ball, strays]
    normals = points / np.linalg.norm(points, axis=1, keepdims=True)
    cloud = make_cloud(points, normals)
    found = islands(points, point_spacing(points))
    assert found.keep[:5000].all() and not found.keep[5000:].any()
    sub = cloud.subset(found.keep)
    assert np.array_equal(sub.points, ball) and np.allclose(sub.normals, normals[:5000], atol=1e-12)
    one = make_cloud(points, sensor_origins=np.array([0.0, 0.0, 1.0])).subset(found.keep)
    assert one.sensor_origins.shape == (5000, 3) and one.sensor_origins.strides[0] == 0  # still one origin
    many = make_cloud(points, sensor_origins=points * 3).subset(found.keep)
    assert np.array_equal(many.sensor_origins, ball * 3)


def test_two_objects_are_kept_and_named_as_separate_parts():
    points = np.r_[_ball(10_000, 4), _ball(10_000, 5, radius=0.03, center=(0.3, 0.0, 0.0))]
    est = estimate(make_cloud(points), 1000.0)
    assert est.points_in == 20_000
    assert est.mass.volume == pytest.approx(BALL + 4 / 3 * np.pi * 0.03**3, rel=0.005)
    assert any(w.startswith("the cloud is 2 separate parts (50 %, 50 % of the points)") for w in est.warnings)
    assert not any("stray" in w for w in est.warnings)


def _surface(mesh: trimesh.Trimesh, n: int, seed: int) -> np.ndarray:
    return trimesh.sample.sample_surface(mesh, n, seed=seed)[0]


@pytest.mark.parametrize(("name", "points"), [
    # uneven density: one half of a box sampled 16 times as densely as the other (4x the spacing)
    ("uneven box", lambda: (lambda p: np.r_[p[p[:, 0] < 0], p[p[:, 0] >= 0][::16]])(
        _surface(trimesh.creation.box([0.1, 0.06, 0.04]), 60_000, 6))),
    ("sparse ball", lambda: _ball(150, 7)),
    ("thin torus", lambda: _surface(trimesh.creation.torus(0.05, 0.002), 20_000, 8)),
    ("noisy ball", lambda: _ball(20_000, 9) + np.random.default_rng(9).normal(scale=0.001, size=(20_000, 3))),
    ("mostly scatter", lambda: np.random.default_rng(10).uniform(-0.05, 0.05, size=(3000, 3))),
])
def test_an_objects_own_points_are_never_strays(name, points):
    p = points()
    found = islands(p, point_spacing(p))
    assert found.strays == 0 and found.keep.all(), (name, found.strays, found.part_shares)
    assert found.parts <= 1, (name, found.part_shares)  # scatter is all small islands: 0


def test_an_object_seen_in_two_pieces_is_two_parts_not_strays():
    # A box seen past an occluder: two pieces of its surface 3 cm apart, each far more than STRAY_SHARE.
    p = _surface(trimesh.creation.box([0.2, 0.05, 0.05]), 20_000, 11)
    p = p[np.abs(p[:, 0]) > 0.015]
    found = islands(p, point_spacing(p))
    assert found.strays == 0 and found.parts == 2 and min(found.part_shares) > STRAY_SHARE


def test_parts_far_apart_that_make_a_line_are_named_in_the_error():
    # Two balls 100 m apart are a line to the shape check: "line-like, it encloses no volume" said nothing of the
    # two parts (50 m apart they were a warning, and the estimate went on).
    from estimation.errors import CloudError

    rng = np.random.default_rng(0)
    ball = rng.normal(size=(1500, 3))
    ball = 0.05 * ball / np.linalg.norm(ball, axis=1, keepdims=True)
    with pytest.raises(CloudError, match=r"line-like, it encloses no volume \(100 x \S+ x \S+ m along its principal axes\): the cloud is 2 separate parts "
                                         r"\(50 %, 50 % of the points\).*split the cloud"):
        estimate(make_cloud(np.vstack([ball, ball[::-1] + np.array([100.0, 0.0, 0.0])])), 1000.0)
