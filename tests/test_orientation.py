"""Normals the outside probe cannot read take their sign along one sheet, not across a noisy wall
(``estimation.normals.on_one_sheet``)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from estimation import estimate
from estimation.normals import on_one_sheet
from scenes.sampling import sample_surface
from scenes.shapes import inside_out, make_parts


def _slab(thickness: float, sigma: float, n: int = 20_000, seed: int = 0):
    """Both faces of a 30 x 30 mm wall ``thickness`` thick, ``sigma`` of noise along z; every normal +z (unoriented,
    as fitted). Returns the points, the normals, each point's face (0 or 1), and each point's 32 nearest."""
    rng = np.random.default_rng(seed)
    face = rng.integers(0, 2, n)
    points = np.c_[rng.uniform(0, 0.03, (n, 2)), face * thickness + rng.normal(0, sigma, n)]
    normals = np.tile([0.0, 0.0, 1.0], (n, 1))
    neighbours = cKDTree(points).query(points, 32)[1]
    return points, normals, face, neighbours


@pytest.mark.parametrize("thickness, kept_across", [(0.003, 0.3), (0.004, 0.0)])
def test_edges_through_the_noise_inside_a_wall_are_dropped_and_those_along_a_face_kept(thickness, kept_across):
    """At 6 sigmas (issue 12's 3 mm walls at 0.5 mm) a quarter of the edges between the noise's tails survive (both
    ends' centroids mid-wall; measured 0.23), at 8 sigmas none (0 of 58)."""
    sigma = 0.0005
    points, normals, face, neighbours = _slab(thickness, sigma)
    r, c = np.repeat(np.arange(len(points)), 16), neighbours[:, :16].ravel()
    across = face[r] != face[c]
    assert across.sum() > 30  # the noise's tails do meet inside the wall: something to drop
    along = on_one_sheet(points, normals, r, c, sigma, neighbours)
    assert along[~across].mean() > 0.995
    assert along[across].mean() <= kept_across


def test_where_the_noise_is_under_the_spacing_every_edge_is_kept():
    points, normals, _, neighbours = _slab(0.003, 1e-6, n=2_000)  # ~0.5 mm apart, no noise to speak of
    r, c = np.repeat(np.arange(len(points)), 16), neighbours[:, :16].ravel()
    assert on_one_sheet(points, normals, r, c, 1e-6, neighbours).all()


@pytest.mark.slow  # ~25 s: in CI's slow run
@pytest.mark.parametrize("index, name, flipped, volume", [
    (9, "part-comb-09", 0.01, 0.03),  # 5.2 % of the normals inside out and +8.4 % before
    (2, "part-heatsink-02", 0.1, 0.06),  # 32 % and +11.4 % before; what is left: docs/estimation.md
])
def test_a_noisy_combs_and_heatsinks_fins_come_out_right_side_out(index, name, flipped, volume):
    """bench/thin_parts.py's parts with 3.1-3.4 mm teeth and fins under 0.5 mm of noise, no normals: most points are
    ones the outside probe cannot read, whose signs were carried along the most parallel edges, which hopped between
    a fin's two (parallel) faces through the noise inside it."""
    part = make_parts(16, 0)[index]
    assert part.name == name
    cloud = sample_surface(part.mesh, 100_000, seed=[0, index], noise_sigma=0.0005, with_normals=False)
    est = estimate(cloud, 1000.0)
    assert inside_out(part.mesh, est.points, est.normals) < flipped
    assert abs(est.volume / part.volume - 1) < volume
