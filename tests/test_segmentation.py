"""Support plane and clustering on synthetic scenes with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from estimation.errors import CloudError
from estimation.segmentation import (
    CLUSTER_SPACINGS,
    check_segments,
    cluster,
    fit_plane,
    median_spacing,
    segment,
    split_cluster,
)


def _box_surface(centre, size, n, rng):  # type: ignore[no-untyped-def]
    """n points uniformly on the sides and top of an axis-aligned box resting on z = 0."""
    pts = rng.uniform(-0.5, 0.5, (n, 3)) * size
    face = rng.integers(0, 5, n)  # 0..3 sides, 4 top
    axis = np.where(face < 2, 0, np.where(face < 4, 1, 2))
    sign = np.where(face % 2 == 0, 1.0, -1.0)
    sign[face == 4] = 1.0
    pts[np.arange(n), axis] = sign * np.asarray(size)[axis] / 2
    return pts + np.array([centre[0], centre[1], size[2] / 2])


def _scene(rng, gap=0.03):  # type: ignore[no-untyped-def]
    table = np.column_stack([rng.uniform(-0.4, 0.4, 40000), rng.uniform(-0.3, 0.3, 40000), np.zeros(40000)])
    a = _box_surface((-0.05 - gap / 2, 0.0), (0.1, 0.08, 0.06), 6000, rng)
    b = _box_surface((0.04 + gap / 2, 0.0), (0.08, 0.08, 0.1), 6000, rng)
    pts = np.concatenate([table, a, b]) + rng.normal(0, 0.001, (52000, 3))
    truth = np.concatenate([np.zeros(40000, int), np.ones(6000, int), np.full(6000, 2)])
    return pts, truth


def test_plane_is_found_and_faces_the_sensor():
    rng = np.random.default_rng(0)
    pts, _ = _scene(rng)
    plane = fit_plane(pts, threshold=0.004, toward=np.array([0.0, -1.0, 1.0]), rng=rng)
    assert plane.normal @ [0, 0, 1] > 0.9999
    assert abs(plane.offset) < 5e-4
    assert plane.rms == pytest.approx(0.001, rel=0.2)
    flipped = fit_plane(pts, threshold=0.004, toward=np.array([0.0, 0.0, -1.0]), rng=rng)
    assert flipped.normal @ [0, 0, 1] < -0.9999


def test_two_boxes_3_cm_apart_are_two_segments_none_merged():
    rng = np.random.default_rng(1)
    pts, truth = _scene(rng)
    seg = segment(pts, toward=np.array([0.0, 0.0, 1.0]), rng=rng, plane_threshold=0.004)
    assert seg.count == 2
    check = check_segments(seg.labels, truth, [1, 2])
    assert check.found == (1, 2) and check.merged == () and check.split == () and check.missed == ()


def test_touching_boxes_are_reported_merged():
    rng = np.random.default_rng(2)
    pts, truth = _scene(rng, gap=0.0)
    seg = segment(pts, toward=np.array([0.0, 0.0, 1.0]), rng=rng, plane_threshold=0.004)
    check = check_segments(seg.labels, truth, [1, 2])
    assert len(check.merged) == 1




def _two_boxes(gap, seed):  # type: ignore[no-untyped-def]
    """Two boxes' surfaces ``gap`` apart (0.5 mm noise), their true labels (0, 1) and the clustering cell."""
    rng = np.random.default_rng(seed)
    a = _box_surface((-0.05 - gap / 2, 0.0), (0.1, 0.08, 0.06), 6000, rng)
    b = _box_surface((0.04 + gap / 2, 0.0), (0.08, 0.08, 0.1), 6000, rng)
    pts = np.concatenate([a, b]) + rng.normal(0, 0.0005, (12000, 3))
    return pts, np.repeat([0, 1], 6000), CLUSTER_SPACINGS * median_spacing(pts)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_boxes_a_centimetre_apart_are_parted_by_where_they_are_known_to_be(seed):
    # One cluster at the clustering cell; the finer cells part them, each box's points going to the seed at
    # its centre. The third seed, also in the first box (a stale prediction), shares its piece.
    pts, truth, cell = _two_boxes(0.01, seed)
    assert (cluster(pts, cell=cell) == 0).all()
    seeds = np.array([[-0.055, 0.0, 0.03], [0.045, 0.0, 0.05], [-0.06, 0.01, 0.02]])
    parts = split_cluster(pts, seeds, cell)
    assert parts is not None and set(parts.tolist()) == {0, 1}
    assert (parts == truth).mean() > 0.999


def test_boxes_closer_than_the_noise_allows_and_one_box_with_two_seeds_are_left_whole():
    pts, _, cell = _two_boxes(0.003, 0)
    assert split_cluster(pts, np.array([[-0.05, 0.0, 0.03], [0.04, 0.0, 0.05]]), cell) is None
    box = pts[:6000]
    assert split_cluster(box, np.array([[-0.05, 0.0, 0.03], [-0.02, 0.02, 0.02]]), cell) is None


def test_an_objects_lowest_band_is_its_own_and_the_tables_stray_noise_is_not():
    # A 1 mm-noisy table of 400,000 points (0.13 % of them above 3 sigma: ~500 strays) under a box, cut
    # at 6 mm: the box's points between 3 sigma and the cut come back to it, the strays stay plane.
    rng = np.random.default_rng(5)
    n_table, n_box = 400_000, 20_000
    table = np.column_stack([rng.uniform(-0.4, 0.4, n_table), rng.uniform(-0.3, 0.3, n_table), np.zeros(n_table)])
    box = _box_surface((0.0, 0.0), (0.08, 0.06, 0.03), n_box, rng)
    pts = np.concatenate([table, box]) + rng.normal(0, 0.001, (n_table + n_box, 3))
    seg = segment(pts, toward=np.array([0.0, 0.0, 1.0]), rng=rng, plane_threshold=0.006)
    assert seg.count == 1 and seg.cut == 0.006 and seg.margin == pytest.approx(0.003, rel=0.2)
    height = seg.plane.height(pts)
    in_band = (height > seg.margin + 0.0005) & (height < seg.cut)
    on_box = np.arange(len(pts)) >= n_table
    assert in_band[on_box].sum() > 300
    assert (seg.labels[in_band & on_box] == 0).mean() > 0.95  # the box's lowest millimetres are the box's
    strays = ~on_box & (height > seg.margin)
    far = strays & ((np.abs(pts[:, 0]) > 0.05) | (np.abs(pts[:, 1]) > 0.04))  # a centimetre clear of the box
    assert far.sum() > 200
    assert (seg.labels[far] == -1).all()


def test_small_clusters_are_noise():
    pts = np.concatenate([np.zeros((100, 3)), np.full((5, 3), 1.0)])
    labels = cluster(pts, cell=0.01, min_points=10)
    assert (labels[:100] == 0).all() and (labels[100:] == -1).all()


def test_plane_needs_three_points():
    with pytest.raises(CloudError, match="at least 3 points"):
        fit_plane(np.zeros((2, 3)), threshold=0.01, toward=np.zeros(3), rng=np.random.default_rng(0))
