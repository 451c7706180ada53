"""scenes.association and scenes.restfilter: the camera tracker's pure parts, on hand-made segments."""

from __future__ import annotations

import numpy as np
import pytest

from scenes.association import (
    ASSOCIATION_RADIUS,
    MAX_SPEED,
    MIN_OVERLAP,
    gate,
    nearest,
    outsiders,
    overlap,
    reach,
    search,
    sharing,
)
from scenes.cameras import Segment
from scenes.restfilter import RestFilter, partial_motion


def _segment(centre: tuple[float, float, float], half: float = 0.02, n: int = 200, seed: int = 0) -> Segment:
    points = np.asarray(centre) + np.random.default_rng(seed).uniform(-half, half, (n, 3))
    return Segment(points=points, origins=np.zeros_like(points), geom=np.zeros(n, int))


def test_gate_takes_the_nearest_segment_whose_grown_box_holds_the_prediction():
    segs = [_segment((0.0, 0.0, 0.8)), _segment((0.3, 0.0, 0.8))]
    got = gate(segs, {"a": np.array([0.01, 0.0, 0.8]), "b": np.array([0.29, 0.01, 0.8]),
                      "far": np.array([0.0, 0.5, 0.8])})
    assert got == {"a": 0, "b": 1}  # "far" is beyond ASSOCIATION_RADIUS of both boxes
    assert gate([], {"a": np.zeros(3)}) == {}


def test_gate_leaves_out_an_object_standing_clear_of_a_segment_another_stands_over():
    seg = _segment((0.0, 0.0, 0.8), half=0.02)
    over, beside = np.array([0.0, 0.0, 0.8]), np.array([0.06, 0.0, 0.8])  # 4 cm outside its footprint
    assert gate([seg], {"over": over, "beside": beside}) == {"over": 0}
    assert outsiders(seg, {"over": over, "beside": beside}) == {"beside"}
    # None over it: nothing tells them apart, both stay.
    assert outsiders(seg, {"x": beside, "y": beside + np.array([0.0, 0.01, 0.0])}) == set()


def test_gate_goes_by_where_an_objects_model_lies_then_by_the_nearest_point_never_the_nearest_centroid():
    # The paper's table: one long segment of two large objects; its centroid, between them, is further from the
    # left object than a small segment beside it is, so the centroid rule gives the left object that speck.
    left, right = _segment((-0.5, 0, 0.8), half=0.1, n=400), _segment((0.5, 0, 0.8), half=0.1, n=400, seed=1)
    long = Segment(points=np.concatenate([left.points, right.points]), origins=np.zeros((800, 3)),
                   geom=np.zeros(800, int))
    speck = _segment((-0.5, 0.17, 0.8), half=0.01, n=30, seed=2)
    here = {"left": np.array([-0.5, 0.05, 0.8])}
    # Not observed yet: the segment of the scan point nearest it (the speck's centroid is the nearest centroid).
    assert gate([long, speck], here) == {"left": 0} == nearest([long, speck], here)
    model = left.points[::2]  # what was seen of it, where it is predicted
    assert gate([long, speck], here, {"left": model}) == {"left": 0}
    assert overlap([long, speck], {"left": model}) == {"left": 0}
    # Its model decides over the nearest point: predicted beside the speck, it is still where its model lies.
    by_speck = {"left": np.array([-0.5, 0.17, 0.8])}
    assert gate([long, speck], by_speck) == {"left": 1}
    assert gate([long, speck], by_speck, {"left": model}) == {"left": 0}
    # Placed where nothing is, or half on the segment, it falls back to the nearest point.
    away = model + np.array([0.0, 1.0, 0.0])
    assert overlap([long, speck], {"left": away}) == {}
    assert gate([long, speck], by_speck, {"left": away}) == {"left": 1}
    half_on = np.concatenate([model[: int(len(model) * (MIN_OVERLAP - 0.1))], away[: len(model)]])
    assert overlap([long, speck], {"left": half_on}) == {}
    assert overlap([], {"left": model}) == {} and overlap([long], {"left": np.zeros((0, 3))}) == {}


def test_overlap_counts_each_model_point_for_the_segment_of_its_nearest_scan_point():
    a, b = _segment((0.0, 0, 0.8), half=0.03), _segment((0.07, 0, 0.8), half=0.03, seed=1)  # 1 cm apart
    # A model over a and 2 cm into b's side: most of its points are nearest a's.
    model = np.random.default_rng(3).uniform([-0.03, -0.03, 0.77], [0.05, 0.03, 0.83], (300, 3))
    assert overlap([a, b], {"x": model}) == {"x": 0}
    assert overlap([b, a], {"x": model}) == {"x": 1}


def test_sharing_goes_by_the_nearest_point_not_the_centroid():
    # One long segment of two objects, its centroid between them, nearer a small third segment than its ends.
    long = Segment(points=np.concatenate([_segment((-0.1, 0, 0.8), n=100).points, _segment((0.1, 0, 0.8), n=100).points]),
                   origins=np.zeros((200, 3)), geom=np.zeros(200, int))
    small = _segment((0.0, 0.07, 0.8), half=0.01, seed=1)
    predicted = {"left": np.array([-0.1, 0.0, 0.8]), "right": np.array([0.1, 0.0, 0.8])}
    assert sharing([long, small], predicted) == {0: ["left", "right"]}


def test_search_finds_the_nearest_free_segment_within_reach():
    segs = [_segment((0.0, 0.0, 0.8)), _segment((0.2, 0.0, 0.8)), _segment((0.5, 0.0, 0.8))]
    last = np.array([0.25, 0.0, 0.8])
    assert search(segs, last, 0.1, taken=set()) == 1
    assert search(segs, last, 0.1, taken={1}) is None  # the others are beyond 10 cm
    assert search(segs, last, 0.3, taken={1}) == 0
    assert reach(0.0) == ASSOCIATION_RADIUS and reach(-5.0) == ASSOCIATION_RADIUS
    assert reach(2.0) == pytest.approx(ASSOCIATION_RADIUS + 2 * MAX_SPEED)


def _turn_z(angle: float, shift: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    out = np.eye(4)
    out[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    out[:3, 3] = shift
    return out


def test_partial_motion_takes_a_share_of_the_turn_about_the_centre_and_of_its_shift():
    centre = np.array([1.0, 2.0, 0.5])
    step = _turn_z(0.4, (0.02, 0.0, 0.0))
    half = partial_motion(step, centre, 0.5)
    moved = step[:3, :3] @ centre + step[:3, 3]
    assert np.allclose(half[:3, :3] @ centre + half[:3, 3], centre + 0.5 * (moved - centre))
    assert np.allclose(half[:3, :3], _turn_z(0.2)[:3, :3])
    assert np.allclose(partial_motion(step, centre, 1.0), step)


def test_rest_filter_averages_small_steps_and_takes_a_large_one_whole():
    model = np.random.default_rng(0).uniform(-0.02, 0.02, (300, 3))
    rest = RestFilter(window=4)
    small = _turn_z(0.0, (0.0004, 0.0, 0.0))
    got, shrink = rest.step("a", model, small, rmse=0.001)  # 0.4 mm against a 3 mm gate: noise
    # The pose first seen counts as window - 1 fits (the model is that view): the first fit moves it a quarter.
    assert np.allclose(got[:3, 3], small[:3, 3] / 4) and shrink == pytest.approx(1 / 2)
    assert rest.resting("a")
    for n in (4, 4):  # the window caps the mean
        got, shrink = rest.step("a", model, small, rmse=0.001)
        assert np.allclose(got[:3, 3], small[:3, 3] / n) and shrink == pytest.approx(1 / np.sqrt(n))
    push = _turn_z(0.0, (0.02, 0.0, 0.0))
    got, shrink = rest.step("a", model, push, rmse=0.001)  # 2 cm: motion, whole
    assert np.allclose(got, push) and shrink == 1.0 and not rest.resting("a")
    got, _ = rest.step("a", model, small, rmse=0.001)  # the first fit at rest after a motion: whole too
    assert np.allclose(got[:3, 3], small[:3, 3])
    rest.restart("a")  # a new model: its pose counts as one fit
    got, _ = rest.step("a", model, small, rmse=0.001)
    assert np.allclose(got[:3, 3], small[:3, 3] / 2)
    assert np.allclose(RestFilter(window=1).step("b", model, small, rmse=0.001)[0], small)  # 1: each fit whole


def test_rest_filter_holds_one_step_past_the_scatter_but_within_the_residual():
    """The fits' reach has a long tail: one step past the scatter's gate is held (the track stays) and the next
    decides: back within it, noise; past it again, motion, taken whole from the track."""
    model = np.random.default_rng(0).uniform(-0.02, 0.02, (300, 3))
    rest = RestFilter(window=4)
    small = _turn_z(0.0, (0.0004, 0.0, 0.0))
    for _ in range(3):
        rest.step("a", model, small, rmse=0.001)  # scatter 0.4 mm: gate 1.2 mm; the residual's 3 mm
    odd = _turn_z(0.0, (0.002, 0.0, 0.0))
    got, shrink = rest.step("a", model, odd, rmse=0.001)
    assert np.allclose(got, np.eye(4)) and shrink == pytest.approx(1 / 2)
    assert not rest.resting("a") and not rest.moved("a")
    got, _ = rest.step("a", model, small, rmse=0.001)  # back: it was noise
    assert np.allclose(got[:3, 3], small[:3, 3] / 4) and rest.resting("a")
    rest.step("a", model, odd, rmse=0.001)
    got, shrink = rest.step("a", model, odd, rmse=0.001)  # twice in a row: motion
    assert np.allclose(got, odd) and shrink == 1.0 and rest.moved("a")
    rest.step("a", model, small, rmse=0.001)  # the first fit at rest after it, whole
    for _ in range(2):
        rest.step("a", model, small, rmse=0.001)
    far = _turn_z(0.0, (0.004, 0.0, 0.0))  # past the residual's gate: motion at once
    got, _ = rest.step("a", model, far, rmse=0.001)
    assert np.allclose(got, far) and rest.moved("a")
    got, _ = rest.step("a", model, odd, rmse=0.001)  # moving, nothing is held
    assert np.allclose(got, odd)
    for _ in range(3):
        rest.step("a", model, small, rmse=0.001)
    rest.step("a", model, odd, rmse=0.001)  # held ...
    rest.forget("a")  # ... and seen anew: nothing of it counts, the new first pose is window - 1 fits
    assert rest.resting("a") and not rest.moved("a")
    got, _ = rest.step("a", model, odd, rmse=0.001)  # 2 mm within the residual's 3 mm: noise, a quarter
    assert np.allclose(got[:3, 3], odd[:3, 3] / 4)
