"""Closing what no camera saw: an object's bottom on its support plane, its mirror image, its carved hull.

An object at rest on a table hides its base. Where its walls come down to the plane upright (a box, a
can, a cone), the base is the plane itself inside the object's outline: we add points there, marked as
completed, plus a skirt up the wall through the band the plane removal cut away. Where the walls curve
in towards the plane (a ball, a lying capsule, a torus), the base is not flat and it adds nothing: the
mirror image below may, or else the estimator closes that hole itself, and the result rests on less
evidence (reported as less coverage).

The outline is the object's own top-down shadow (its points projected on the plane), so a ring's hole
stays open and a box seen from one side still gets its whole base (its top face casts the full shadow).

Mirror symmetry: many things on a table are their own mirror image in the horizontal plane at half
their height (a ball, a box, a can, a lying cylinder or capsule, a torus). Such an object's underside is
its top turned over: when the visible part of the lower half matches the upper half reflected
(:func:`mirror_image`, ``MIRROR_SHARE`` of its points, and as much of its lowest band), the reflected upper
half fills what no camera saw below. A cone or a mug on its base fails the test and gets no mirror image;
so does a pentagonal prism on a face, whose lowest band misses its ridge.

Half-turn symmetry: seen from one side only (one camera), a box, a can, a bottle or a ball shows its back
as its front turned half a turn about a vertical axis through its middle (any shape whose footprint is
centrally symmetric: a rectangle seen at a corner too). :func:`half_turn_axis` finds that axis from the
silhouette and the space the cameras saw through, and the observed points (and their mirror image) so
turned fill the back. An object that is not so symmetric (a mug's handle, an L-bracket) gets a wrong back
this way; its coverage says how much of it was guessed.

With depth images (:mod:`estimation.carving`), what is still open after the observed points and the
images is filled from the solid the cameras did not carve away (an unseen side face lies on it), and a
mirrored or turned point the cameras saw through is dropped. Without them, the base is closed as above.

An object standing on another (a can on a box, the top box of a stack) is closed on that object's top, not on
the table (:func:`resting_on`): the top shows around its base, facing up, on every side.

An object a camera's frame cuts where no other view looked (:func:`estimation.carving.open_past_frame`) is
closed as seen, without a half turn (the silhouette's sides and the space seen past the object, which place
its axis, may be the frame's), and flagged: its volume has no upper bound.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from estimation.contracts import as_points
from estimation.neighbours import nearest
from estimation.segmentation import Plane

if TYPE_CHECKING:
    from estimation.carving import DepthView

#: Half-turn image (:func:`half_turn_axis`): the views are one-sided when the mean of the unit horizontal
#: directions from the cameras to the points is at least this long (1: all from one direction; two cameras
#: 90 degrees apart give 0.71).
ONE_SIDED = 0.9

#: The silhouette's sides, as percentiles of the points across the view (robust to a stray point).
SILHOUETTE_PERCENTILE = 0.5

#: Largest share of the turned points that may lie in seen-through space at the best axis (noise, and the
#: odd point a neighbour hid).
TURN_FREE_SHARE = 0.1

#: The half turn is tried only when the cameras' depth sigma at the object is at most this share of its
#: width across the view. The axis is placed to about that sigma (the free-space test's resolution), and
#: an axis off by d puts the back 2 d off: about 4 d / width of the volume (10 % at this share).
TURN_NOISE_SHARE = 0.025

#: Slack of the axis search's free-space test, in cells: an exact surface point, interpolated between
#: pixels, must not count as seen through (a whole cell blurs where the test starts to bite).
TURN_SLACK = 0.5

#: Points in the lowest band above the cut whose normal is within this cosine of horizontal are upright
#: wall (|cos| to the plane normal below 0.3: within ~17 degrees of vertical, a box's or can's side; a
#: ball's, a lying capsule's or a torus's underside near the table points ~30-60 degrees down).
WALL_COSINE = 0.45

#: The band above the removal cut where wall evidence is looked for, metres: thin, so that the side of
#: a lying cylinder or torus a centimetre up (upright there) does not count.
WALL_BAND_M = 0.006

#: The base is closed only when at least this share of the band's points are upright wall...
WALL_SHARE = 0.4

#: ...and at least this many.
MIN_WALL_POINTS = 20

#: Shadow raster cells fill gaps of up to this many cells (morphological closing): dropouts and the
#: sparse far side of a one-camera view.
CLOSING_CELLS = 2


#: The lower half's visible points must land within tolerance of an observed point, reflected, in at
#: least this share for the object to count as mirror-symmetric (noise and the odd stray point cost a few
#: %; a cone's or a mug's lower half, reflected, misses the upper half by far more).
MIRROR_SHARE = 0.8

#: The same share is asked of the lowest visible band of the lower half, this fraction of its height: the
#: points there reflect onto the top, and the image's lowest part (the base it adds) is the top turned over.
#: Over the whole lower half the share is carried by the points near the middle, which reflect onto
#: themselves whatever the shape: a pentagonal prism lying on a face passed with 0.82-0.94 (its lower sides
#: narrow towards the table more slowly than its upper ones towards the ridge, which the lowest band shows:
#: 0.52-0.72) and its mirrored ridge made a V of its base (-6.8 % and -7.6 % at 3 cameras,
#: bench/camera_tables.py).
MIRROR_BAND = 0.25

#: Fewer visible lower-half points than this cannot test symmetry (the object is not mirrored). With 30,
#: a share of ``MIRROR_SHARE`` or more from an object whose true share is a half has a binomial chance
#: under 0.1 %; a flat object (a nut, a coin) whose plane removal took most of its lower half still has
#: that many in the band left.
MIRROR_MIN_POINTS = 30

#: The lower half's points must span this share of its height above the cut (their 5th to 95th percentile):
#: a box standing on another of its size, whose top hides, showed its lower half as a noise band 2 mm deep at
#: its rim, which reflected onto itself and mirrored its top onto the table, through the box under it (+94.5 %).
#: A ball seen from cameras 35 degrees above the table shows about 0.8 of its lower half; a flat nut, the
#: plane's removal having taken the rest, the whole band left.
MIRROR_MIN_SPAN = 0.25

#: The mirror test's tolerance: this many noise sigmas plus ``MIRROR_CELLS`` cells.
MIRROR_SIGMAS = 3.0
MIRROR_CELLS = 1.5

#: The mirror plane's height is half the object's top, taken at this percentile of the heights of the
#: points' neighbourhood centroids (``TOP_NEIGHBOURS`` points each) less the noise's share of it
#: (``TOP_NOISE_SIGMAS``, the normal quantile of the same percentile, times the centroids' sigma,
#: noise / sqrt(neighbours)). The points' own heights, less the full noise's share, were right on a flat top
#: (without the correction a 3 cm book's mirrored base sat 2.6 mm high: -6 %) but read low on a curved one,
#: where few points lie near the top: the correction assumes they all do. The centroids have a quarter of
#: the noise, so whatever the top's shape the correction is a quarter as large, and so is its error
#: (tests/test_carving.py's noisy ring; the clutter's hex nut in bench/cameras.py went from +13.6 % to
#: +8.1 % at 3 cameras). A reflected point that would lie below the plane lies on it. A flat top
#: (:func:`flat_top`) is its points' mean height, and its image is the base, on the plane.
TOP_PERCENTILE = 99.5
TOP_NOISE_SIGMAS = 2.58
TOP_NEIGHBOURS = 16

#: A flat top (:func:`flat_top`): at least ``FLAT_MIN_POINTS`` points (their mean then within 0.07 sigma)
#: facing within 18 degrees of up, inside ``FLAT_WINDOW_SIGMAS`` of the top, their mean within ``FLAT_MEAN_SIGMAS``
#: of it. On noisy synthetic tops (sigma 0.75-1 mm, 12 draws each) a 10 x 10 cm slab was flat in 12, its height
#: within 0.01 sigma on average; a 4 cm ball in none; a ring's curved top in 1. Kept for what it did to boxy scenes
#: (bench/cameras.py, bench/stacks.py: every median down 0.1-1.2 points), with the random tabletops level.
FLAT_FACING_COSINE = 0.95
FLAT_WINDOW_SIGMAS = 3.0
FLAT_MIN_POINTS = 200
FLAT_MEAN_SIGMAS = 0.25

#: A completed point is added only this many cells or more from every point already there (observed or
#: completed before it): completion fills holes, it does not thicken surfaces.
NEW_SURFACE_CELLS = 1.5

#: A carved-surface point within this many cells of the surface already there, on its outside, is where the
#: cameras could not carve all the way to a surface that is known (under a ball): it is dropped.
OUTSIDE_CELLS = 4.0

#: "On its outside": within this cosine of the surface's normal (60 degrees).
OUTSIDE_COSINE = 0.5

#: Resting on another object (:func:`resting_on`): other objects' points count as a support within this many
#: cells of the object's shadow (the top of what it stands on shows around its base) ...
SUPPORT_REACH_CELLS = 4.0

#: ... no higher than the object's lowest points (this percentile of their heights: a few of a can's points
#: fell 5 mm into the box under it, flying pixels the segmentation image gave it) by more than this many noise
#: sigmas ...
SUPPORT_LOWEST_PERCENTILE = 1.0
SUPPORT_SIGMAS = 3.0

#: ... where their surface faces up: a normal within about 25 degrees of the plane's (a neighbour's upright
#: side, beside the object, does not) ...
SUPPORT_COSINE = 0.9

#: ... with at least this many of them ...
SUPPORT_MIN_POINTS = 20

#: ... around the object: seen from its shadow's centre, no gap between them wider than this (degrees). A
#: neighbour's low top beside it (a book lying flat against a box) spans one side, under 180 degrees; the
#: top of a larger box under a can shows on every side.
SUPPORT_MAX_GAP_DEG = 150.0


@dataclass(frozen=True)
class Completion:
    """Points added where no sensor saw the object.

    Attributes:
        points: (m, 3) float64 metres, world frame (m may be 0).
        normals: (m, 3) float64 unit, outward (down for the base, out for the skirt).
        base_area: m^2, area of the closed base (0: the walls do not meet the plane upright, or the base
            came from the mirror image or the carved solid).
        mirrored: how many of ``points`` are the upper half's mirror image.
        turned: how many are the observed side turned half a turn (:func:`half_turn_axis`).
        carved: how many lie on the carved solid's surface.
        carved_volume: m^3, the carved solid's volume (an upper bound up to noise), None without depth images.
        open_past_frame: a camera's frame cut the object where no view looked past the cut
            (:func:`estimation.carving.open_past_frame`): the object may run on out of view, so what is closed
            here is the part seen, and nothing bounds the volume above.
    """

    points: np.ndarray
    normals: np.ndarray
    base_area: float
    mirrored: int = 0
    turned: int = 0
    carved: int = 0
    carved_volume: float | None = None
    open_past_frame: bool = False


def close_bottom(points: np.ndarray, normals: np.ndarray, plane: Plane, *, cell: float,
                 cut: float) -> Completion:
    """The base and skirt of an object resting on ``plane`` (see the module docstring).

    Args:
        points: (n, 3) float64 metres, world frame: the object's observed points (all above ``cut``).
        normals: (n, 3) float64 unit outward normals of ``points`` (oriented to their sensors).
        plane: the support plane, normal pointing up into the object's side.
        cell: spacing of the added points and of the shadow raster, metres (about the point spacing).
        cut: height above the plane below which observed points were removed with the plane, metres.
    """
    pts = as_points(points, "points")
    nrm = as_points(normals, "normals")
    empty = Completion(np.zeros((0, 3)), np.zeros((0, 3)), 0.0)
    up = plane.normal
    h = pts @ up + plane.offset
    band = h < cut + WALL_BAND_M
    wall = band & (np.abs(nrm @ up) < WALL_COSINE)
    if wall.sum() < max(MIN_WALL_POINTS, WALL_SHARE * band.sum()):
        return empty
    # A 2D basis of the plane from the shadow's own principal axis, and a raster whose cell edges sit on
    # multiples of ``cell`` from the shadow's centroid: the base moves with the object under any rigid
    # motion (a basis fixed to the world's axes gave another raster, +-1.5 % volume, per rotation). A
    # flipped axis maps that raster onto itself.
    flat = pts - np.outer(pts @ up, up)
    centre = flat.mean(axis=0)
    axis = np.linalg.svd(flat - centre, full_matrices=False)[2][0]
    e1 = axis - (axis @ up) * up
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    uv = np.stack([(flat - centre) @ e1, (flat - centre) @ e2], axis=1)
    k = np.floor(uv / cell).astype(np.int64)
    k0 = k.min(axis=0) - (CLOSING_CELLS + 1)
    ij, lo = k - k0, k0 * cell
    shape = tuple(ij.max(axis=0) + CLOSING_CELLS + 2)
    shadow = np.zeros(shape, dtype=bool)
    shadow[ij[:, 0], ij[:, 1]] = True
    from scipy import ndimage

    shadow = ndimage.binary_closing(shadow, iterations=CLOSING_CELLS)
    ci, cj = np.nonzero(shadow)
    centres = lo + (np.stack([ci, cj], axis=1) + 0.5) * cell
    origin = centre - plane.offset * up  # the shadow's centroid on the plane (``centre`` has no up part)
    base = origin + centres[:, :1] * e1 + centres[:, 1:] * e2
    out_pts, out_nrm = [base], [np.broadcast_to(-up, base.shape)]
    rim = shadow & ~ndimage.binary_erosion(shadow)
    ri, rj = np.nonzero(rim)
    if len(ri) and cut > 0:
        rim_uv = lo + (np.stack([ri, rj], axis=1) + 0.5) * cell
        centre_uv = centres.mean(axis=0)
        out2 = rim_uv - centre_uv
        out2 /= np.maximum(np.linalg.norm(out2, axis=1, keepdims=True), 1e-12)
        outward = out2[:, :1] * e1 + out2[:, 1:] * e2
        rim_base = origin + rim_uv[:, :1] * e1 + rim_uv[:, 1:] * e2
        for z in np.arange(cell, cut, cell):
            out_pts.append(rim_base + z * up)
            out_nrm.append(outward)
    return Completion(np.concatenate(out_pts), np.concatenate(out_nrm), float(shadow.sum() * cell**2))


@dataclass(frozen=True)
class Closed:
    """Observed points and the base :func:`close_bottom` added, as one cloud with per-point sensors.

    Attributes:
        points, origins, normals: (k, 3) float64, world frame, metres (normals unit, outward).
        completed: (k,) bool, True for the added points.
        completion: what was added.
        support: the plane the object was closed on (the support plane, or the top of the object it stands
            on), or None: nothing of the object lies below it (:func:`estimation.views.on_support`).
    """

    points: np.ndarray
    origins: np.ndarray
    normals: np.ndarray
    completed: np.ndarray
    completion: Completion
    support: Plane | None = None


def mirror_image(points: np.ndarray, normals: np.ndarray, plane: Plane, *, noise: float,
                 cell: float, cut: float = 0.0) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The upper half of an object resting on ``plane``, reflected in the plane at half its height, if the
    visible lower half supports it (see the module docstring).

    Args:
        points, normals: (n, 3) float64, world frame: observed points (metres) and unit outward normals.
        plane: the support plane, normal up into the object's side.
        noise: metres, the points' sigma. cell: metres, about the point spacing.
        cut: metres: the height below which observed points went with the plane.

    Returns:
        (points, normals, share): every reflected upper-half point with its reflected normal and the share
        of the lower half's points that matched; None when the object is not mirror-symmetric (or too
        little of its lower half was seen to tell).
    """
    from scipy.spatial import cKDTree

    pts = as_points(points, "points")
    nrm = as_points(normals, "normals")
    up = plane.normal
    h = plane.height(pts)
    tree = cKDTree(pts)
    flat = flat_top(pts, nrm, plane, noise)
    if flat is not None:
        top = float(h[flat].mean())
    else:
        k = min(TOP_NEIGHBOURS, len(pts))
        top = _percentile_top(plane.height(pts[nearest(tree, pts, k)[1]].mean(axis=1)), noise, k)
    middle = 0.5 * max(top, 0.0)
    lower = h < middle  # whatever the plane's removal left of it
    if lower.sum() < MIRROR_MIN_POINTS:
        return None
    reflected = pts[lower] + 2.0 * (middle - h[lower])[:, None] * up
    hit = tree.query(reflected, workers=-1)[0] <= MIRROR_SIGMAS * noise + MIRROR_CELLS * cell
    share = float(hit.mean())
    if share < MIRROR_SHARE:
        return None
    low = h[lower]
    if np.subtract(*np.percentile(low, [95, 5])) < MIRROR_MIN_SPAN * (middle - cut):
        return None
    band = low < low.min() + MIRROR_BAND * (middle - low.min())
    if band.sum() >= MIRROR_MIN_POINTS and hit[band].mean() < MIRROR_SHARE:
        return None
    upper = h >= middle
    # Nothing lies below the plane the object rests on: a reflected point that would (its top's noise, a top read
    # a little low) lies on it. A flat top's image is the base itself, on the plane: reflected, half its noise
    # landed below the plane and, lifted onto it, the base sat ~0.4 sigma high (a 9 mm disc -4.6 % at 3 cameras);
    # left below, the reconstruction averaged it but its lowest bumps stood the collision hull on them (a soup
    # can at rest 1.4 -> 2.2 mm off the reference, bench/camera_fidelity.py).
    drop = np.minimum(2.0 * (h[upper] - middle), h[upper])
    if flat is not None:
        drop = np.where(flat[upper], h[upper], drop)
    out = pts[upper] - drop[:, None] * up
    return out, nrm[upper] - 2.0 * (nrm[upper] @ up)[:, None] * up, share


def flat_top(points: np.ndarray, normals: np.ndarray, plane: Plane, noise: float) -> np.ndarray | None:
    """(n,) bool: the points of a flat top, or None where the top is not flat (or too few points say so).

    ``points`` (n, 3) metres and their outward unit ``normals``, world frame; ``noise`` metres, the points'
    sigma. The top is flat where the points facing up (``FLAT_FACING_COSINE``) within ``FLAT_WINDOW_SIGMAS``
    noise sigmas of the highest neighbourhoods' height (neighbours along the plane, blind to the noise in the
    heights) are ``FLAT_MIN_POINTS`` or more and centred on it (``FLAT_MEAN_SIGMAS``): a plane's noise is
    symmetric, while on a curved top the points in that window lie mostly below it. Their mean height is the
    top's.
    """
    from scipy.spatial import cKDTree

    up = plane.normal
    h = plane.height(points)
    shadow = points - np.outer(h, up)
    k = min(TOP_NEIGHBOURS, len(points))
    top = _percentile_top(h[nearest(cKDTree(shadow), shadow, k)[1]].mean(axis=1), noise, k)
    window = (normals @ up > FLAT_FACING_COSINE) & (np.abs(h - top) < FLAT_WINDOW_SIGMAS * noise)
    if window.sum() < FLAT_MIN_POINTS or abs(float(h[window].mean()) - top) > FLAT_MEAN_SIGMAS * noise:
        return None
    return window


def _percentile_top(heights: np.ndarray, noise: float, k: int) -> float:
    """The top's height, metres, from the heights of neighbourhood centroids of ``k`` points each: their
    ``TOP_PERCENTILE``, less what that percentile adds to the centroids' noise (``noise`` / sqrt(k))."""
    return float(np.percentile(heights, TOP_PERCENTILE)) - TOP_NOISE_SIGMAS * noise / np.sqrt(k)


def half_turn_axis(points: np.ndarray, origins: np.ndarray, plane: Plane, views: Sequence[DepthView], *,
                   cut: float, cell: float, normals: np.ndarray | None = None) -> np.ndarray | None:
    """A point (3,) on the vertical axis about which an object seen from one side, turned half a turn,
    shows its back (a box, a can, a bottle, a ball are their own image so turned: see the module
    docstring); None when that cannot be told.

    The axis is found in the horizontal plane: across the view, midway between the silhouette's two sides;
    along it, where the fewest turned points fall into space some camera saw through (the object's own
    top bounds it from the front, the table seen beyond it from behind), to a fraction of a cell by a
    parabola through the least and its neighbours. None when the views surround the object
    (``ONE_SIDED``), when the cameras' sigma there is more than ``TURN_NOISE_SHARE`` of the width, or when
    even the best axis puts more than ``TURN_FREE_SHARE`` of the turned points in seen-through space.

    Args:
        points, origins: (n, 3) float64, world frame: observed points and each one's sensor origin (metres).
        plane: the support plane. views: as :func:`estimation.carving.carving_views` returns them.
        cut: metres: points below this height were removed with the plane. cell: metres, about the spacing.
    """
    from estimation.carving import free_space, silhouette_reach, view_sigma

    pts, org = as_points(points, "points"), as_points(origins, "origins")
    up = plane.normal
    above = plane.height(pts) > cut
    pts, org = pts[above], org[above]
    if len(pts) < MIRROR_MIN_POINTS:
        return None
    test = pts
    if normals is not None:
        # The outline lies a pixel past the last kept points (the edge pixel is dropped as a likely
        # flying pixel): without that strip, the top's turned far edge stops short of the near one and
        # the least share sat 1-3 mm short of the middle on the clutter's boxes and cans.
        tips = pts + silhouette_reach(pts, org, np.asarray(normals, dtype=np.float64)[above], views, up)[:, 0]
        test = np.concatenate([pts, tips[np.isfinite(tips).all(axis=1)]])
    mean = mean_view_direction(pts, org, up)
    if float(np.linalg.norm(mean)) < ONE_SIDED:
        return None
    along = mean / np.linalg.norm(mean)  # horizontal, away from the cameras
    across = np.cross(up, along)
    a, b = pts @ across, pts @ along
    lo, hi = np.percentile(a, [SILHOUETTE_PERCENTILE, 100 - SILHOUETTE_PERCENTILE])
    if not view_sigma(pts, views) <= TURN_NOISE_SHARE * (hi - lo):  # NaN too
        return None
    band = 2.0 * cell
    middle_b = 0.5 * (float(np.median(b[a <= lo + band])) + float(np.median(b[a >= hi - band])))
    centre = 0.5 * (lo + hi) * across + middle_b * along
    reach = 0.5 * float(np.ptp(b)) + cell
    shifts = np.arange(-reach, reach + 1e-12, cell)
    shares = np.array([free_space(half_turn(test, centre + shift * along, up), views, slack=TURN_SLACK * cell).mean()
                       for shift in shifts])
    if shares.min() > TURN_FREE_SHARE:
        return None
    best = int(np.argmin(shares))
    shift = shifts[best]
    if 0 < best < len(shifts) - 1:  # the parabola through the least and its neighbours: finer than a cell
        left, mid, right = shares[best - 1:best + 2]
        curve = left - 2 * mid + right
        if curve > 0:
            shift += 0.5 * cell * (left - right) / curve
    return centre + shift * along


def mean_view_direction(points: np.ndarray, origins: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """(3,) the mean of the unit directions from each point's sensor to it ((n, 3) each, metres), with ``up``
    (unit) their horizontal parts: length 1 when every view looks one way, ``ONE_SIDED`` and more from one side,
    0 when no direction is left."""
    rays = points - origins
    if up is not None:
        rays -= (rays @ up)[:, None] * up
    lengths = np.linalg.norm(rays, axis=1)
    ok = lengths > 0
    return (rays[ok] / lengths[ok, None]).mean(axis=0) if ok.any() else np.zeros(3)


def half_turn(vectors: np.ndarray, axis: np.ndarray | None, up: np.ndarray) -> np.ndarray:
    """(n, 3) ``vectors`` turned half a turn about the vertical (``up``) line through ``axis``: points
    (metres, world frame); with ``axis`` None, directions (normals)."""
    flat = np.eye(3) - np.outer(up, up)
    if axis is None:
        return vectors - 2.0 * vectors @ flat
    return vectors + 2.0 * (axis - vectors) @ flat


def close_on_plane(points: np.ndarray, origins: np.ndarray, normals: np.ndarray, plane: Plane | None, *,
                   cell: float, cut: float, noise: float = 0.0, views: Sequence[DepthView] | None = None,
                   others: np.ndarray | None = None) -> Closed:
    """The object's observed points (with their sensors and outward normals) and what closes them.

    Added, in order, each only where nothing is yet (``NEW_SURFACE_CELLS``): the mirror image of the upper
    half (:func:`mirror_image`); then, with ``views``, the half-turned image of one-sided views
    (:func:`half_turn_axis`; not into ``others``) and the carved solid's surface
    (:func:`estimation.carving.carve`, ``others`` as there), else the base on the plane
    (:func:`close_bottom`). All of it on the top of another object when it stands on one (:func:`resting_on`),
    on ``plane`` otherwise. With ``views``, mirrored points some camera saw through are dropped, and an object
    a frame cuts where no view looked past it gets no half turn (``Completion.open_past_frame``).

    Args:
        points, origins, normals: (n, 3) float64 world frame: observed points (metres), their sensors,
            their unit outward normals.
        plane: the support plane (None: nothing is added).
        cell: metres, about the point spacing (the spacing of added points).
        cut: metres: the height below which observed points went with the plane.
        noise: metres, the observed points' sigma (the mirror test's tolerance).
        views: every camera's depth image of the scene, for carving, as
            :func:`estimation.carving.carving_views` prepares them (None: no carving).
        others: (m, 3) other objects' observed points (carving splits unseen space with them).

    A completed point's "sensor" is a virtual one a metre outside the object along its outward normal, so
    that whatever orients normals towards sensors keeps the completion's own orientation.
    """
    pts = as_points(points, "points")
    completion = Completion(np.zeros((0, 3)), np.zeros((0, 3)), 0.0)
    if plane is not None and len(pts) and others is not None and len(others):
        plane = resting_on(pts, others, plane, cell=cell, noise=noise) or plane
    if plane is not None and len(pts):
        completion = _complete(pts, np.asarray(normals, dtype=np.float64), np.asarray(origins, dtype=np.float64),
                               plane, cell=cell, cut=cut, noise=noise, views=views, others=others)
    observed = len(pts)
    return Closed(points=np.concatenate([pts, completion.points]),
                  origins=np.concatenate([origins, completion.points + completion.normals]),
                  normals=np.concatenate([normals, completion.normals]),
                  completed=np.concatenate([np.zeros(observed, bool), np.ones(len(completion.points), bool)]),
                  completion=completion, support=plane if len(pts) else None)


def resting_on(points: np.ndarray, others: np.ndarray, plane: Plane, *, cell: float, noise: float) -> Plane | None:
    """The plane through the top of another object this one stands on, or None (it stands on ``plane``).

    Completion closes an object down to the plane it rests on: a can on a box closed down to the table
    took the box's inside under it as its own (+32 %; the mirror image, at half the height above the table,
    put the can's top inside the box). The box's top shows around the can's base, facing up, just below its
    lowest points, on every side (``SUPPORT_*``); a neighbour's side or a low top beside the object does not.

    Args:
        points: (n, 3) metres, world frame: the object's observed points.
        others: (m, 3) metres: other objects' observed points.
        plane: the support plane the scene stands on (normal up).
        cell: metres, about the point spacing. noise: metres, the points' sigma.

    Returns:
        ``plane`` raised to the support's median height (parallel to it), or None.
    """
    from scipy.spatial import cKDTree

    from estimation.carving import plane_frame

    pts = as_points(points, "points")
    other = as_points(others, "others")
    centre, axes, local = plane_frame(pts, plane)  # local[:, :2]: the shadow, about its centroid
    reach = SUPPORT_REACH_CELLS * cell
    other_flat = (other - centre) @ axes[:2].T
    low, high = local[:, :2].min(axis=0) - 2 * reach, local[:, :2].max(axis=0) + 2 * reach
    near = (other_flat >= low).all(axis=1) & (other_flat <= high).all(axis=1)
    around, around_flat = other[near], other_flat[near]
    if len(around) < SUPPORT_MIN_POINTS:
        return None
    # Within reach of the object's shadow, and not above its lowest points.
    lowest = float(np.percentile(local[:, 2], SUPPORT_LOWEST_PERCENTILE))
    candidate = ((cKDTree(local[:, :2]).query(around_flat, workers=-1)[0] <= reach)
                 & (plane.height(around) <= lowest + SUPPORT_SIGMAS * noise))
    if candidate.sum() < SUPPORT_MIN_POINTS:
        return None
    candidates, offset = around[candidate], around_flat[candidate]
    # Facing up: each candidate's plane, from its neighbours among the other points around.
    patches = around[cKDTree(around).query(candidates, k=min(TOP_NEIGHBOURS, len(around)), workers=-1)[1]]
    patches = patches - patches.mean(axis=1, keepdims=True)
    normal = np.linalg.eigh(patches.transpose(0, 2, 1) @ patches)[1][:, :, 0]
    facing = np.abs(normal @ axes[2]) >= SUPPORT_COSINE
    support, offset = candidates[facing], offset[facing]
    if len(support) < SUPPORT_MIN_POINTS:
        return None
    # On every side of it.
    angles = np.sort(np.arctan2(offset[:, 1], offset[:, 0]))
    if np.degrees(np.diff(np.concatenate([angles, angles[:1] + 2 * np.pi])).max()) > SUPPORT_MAX_GAP_DEG:
        return None
    height = float(np.median(plane.height(support)))
    if height <= 0.0:
        return None
    return Plane(axes[2], float(plane.offset) - height, plane.rms, plane.inliers)


def _complete(points: np.ndarray, normals: np.ndarray, origins: np.ndarray, plane: Plane, *, cell: float, cut: float,
              noise: float, views: Sequence[DepthView] | None, others: np.ndarray | None) -> Completion:
    """What :func:`close_on_plane` adds (arguments as there)."""
    from scipy.spatial import cKDTree

    oriented = bool(np.isfinite(normals).all())
    toward = mean_view_direction(points, origins, plane.normal)
    # Seen from one side, what closes the back (a half turn placed by the same free-space test, or the carving
    # alone) lies short of it, and the carving's margins, wider than the noise asks, made up for it: such an
    # object keeps them (1 camera, 8 random tabletops x 2 draws: 7.57 % median |error| kept, 7.95 % with the
    # margin taken back, 7.91 % with both changes). Seen around, the carving is as measured.
    measured = float(np.linalg.norm(toward)) < ONE_SIDED
    mirrored = turned = np.zeros((0, 3)), np.zeros((0, 3))
    if oriented:
        image = mirror_image(points, normals, plane, noise=noise, cell=cell, cut=cut)
        if image is not None:
            mirrored = _not_seen_through(_new(image[0], image[1], points, NEW_SURFACE_CELLS * cell), views, cell,
                                         measured)
    open_past = False
    if views is not None:
        from estimation.carving import open_past_frame

        open_past = open_past_frame(points, origins, views)
    # Cut by a frame, the silhouette's sides across the view and the space seen beyond the object, which place
    # the half turn's axis, may be the frame's: no half turn.
    axis = None if views is None or not oriented or open_past else half_turn_axis(
        points, origins, plane, views, cut=cut, cell=cell, normals=normals)
    if axis is not None:
        # The mirror image turned too: the back's underside.
        both, both_n = np.concatenate([points, mirrored[0]]), np.concatenate([normals, mirrored[1]])
        above = plane.height(both) > cut
        turned = _not_seen_through(_new(half_turn(both[above], axis, plane.normal),
                                        half_turn(both_n[above], None, plane.normal), both, NEW_SURFACE_CELLS * cell),
                                   views, cell, measured)
        if others is not None and len(others) and len(turned[0]):
            # Not into a neighbour: its seen surface is in the way.
            clear = cKDTree(others).query(turned[0], workers=-1)[0] > NEW_SURFACE_CELLS * cell
            turned = turned[0][clear], turned[1][clear]
    have_p, have_n = [points, mirrored[0], turned[0]], [normals, mirrored[1], turned[1]]
    if views is None:
        bottom = close_bottom(points, normals, plane, cell=cell, cut=cut)
        base = _new(bottom.points, bottom.normals, np.concatenate(have_p), NEW_SURFACE_CELLS * cell)
        pts, nrm = np.concatenate([mirrored[0], base[0]]), np.concatenate([mirrored[1], base[1]])
        return Completion(pts, nrm, bottom.base_area if len(base[0]) else 0.0, mirrored=len(mirrored[0]))
    # Voxels fine enough to put two layers in the band the plane removal cut from the walls (the carved wall
    # there meets the base), within the cost bound of ``carving.MAX_CELLS_PER_EXTENT``.
    from estimation.carving import (
        CELLS_PER_EXTENT,
        MAX_CELLS_PER_EXTENT,
        SUBSAMPLE,
        carve,
        carved_surface,
        plane_frame,
    )

    extent = float(np.ptp(plane_frame(points, plane, toward)[2], axis=0).max())  # in world axes: not invariant
    voxel = min(extent / CELLS_PER_EXTENT, max(0.5 * cut, extent / MAX_CELLS_PER_EXTENT))
    unknown = np.full_like(turned[0], np.nan)
    carving = carve(np.concatenate([points, turned[0]]), views, plane, others=others, cell=voxel, toward=toward,
                    origins=np.concatenate([origins, unknown]), normals=np.concatenate([normals, unknown]),
                    blend_sigma=measured)
    surface, surface_n = carved_surface(carving, views if measured else ())
    have = np.concatenate(have_p)
    have_normals = np.concatenate(have_n)
    if len(surface):
        dist, nearest = cKDTree(have).query(surface, workers=-1)
        along = np.einsum("ij,ij->i", surface - have[nearest], have_normals[nearest])
        outside = along > OUTSIDE_COSINE * dist
        keep = (dist > NEW_SURFACE_CELLS * cell) & ~((dist < OUTSIDE_CELLS * carving.cell) & outside)
        surface, surface_n = surface[keep], surface_n[keep]
    if len(surface) and carving.cell / SUBSAMPLE < cell:
        # No denser than the observed points: the reconstruction takes its cell from the spacing and its
        # noise, and a dense noise-free completion read as both (two noisy views of a bracket: 0.8 mm cells
        # under 1.1 mm noise, walls "thinner than the spacing" everywhere, -64 %).
        from estimation.downsample import voxel_subsample

        # In the carving grid's frame: voxels on the world's axes keep another subset per rotation.
        kept = voxel_subsample((surface - carving.origin) @ carving.axes.T, cell)
        surface, surface_n = surface[kept], surface_n[kept]
    return Completion(np.concatenate([mirrored[0], turned[0], surface]),
                      np.concatenate([mirrored[1], turned[1], surface_n]), 0.0, mirrored=len(mirrored[0]),
                      turned=len(turned[0]), carved=len(surface), carved_volume=carving.volume,
                      open_past_frame=open_past)


def _not_seen_through(image: tuple[np.ndarray, np.ndarray], views: Sequence[DepthView] | None,
                      cell: float, blend_sigma: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``image`` (points, normals) less the points some camera saw through, a cell's slack (all: no views;
    ``blend_sigma`` as :func:`estimation.carving.free_space` takes it)."""
    if views is None or not len(image[0]):
        return image
    from estimation.carving import free_space

    keep = ~free_space(image[0], views, slack=cell, blend_sigma=blend_sigma)
    return image[0][keep], image[1][keep]


def _new(points: np.ndarray, normals: np.ndarray, have: np.ndarray, distance: float) -> tuple[np.ndarray, np.ndarray]:
    """The ``points`` (and their ``normals``) farther than ``distance`` from every point of ``have``."""
    from scipy.spatial import cKDTree

    if len(points) == 0 or len(have) == 0:
        return points, normals
    far = cKDTree(have).query(points, workers=-1, distance_upper_bound=distance)[0] > distance
    return points[far], normals[far]


#: Observed surface may lie this many noise sigmas from the reconstructed one on average (bias on curved
#: or small objects, flying pixels that survived). With ``BOUND_UNSEEN_FRACTION`` calibrated on the
#: clutter20 scene at 1-3 cameras (bench/cameras.py: the estimate's own bounds held the truth in 75 % of
#: 59 cases, these in 95 %, median width 1.6x the volume); checked on the paper's objects, not tuned there.
BOUND_NOISE_SIGMAS = 0.5

#: Surface nobody observed may lie this fraction of the object's smallest extent from where completion
#: or hole closing put it (an unseen side may be a hollow, a recess, a bulge): calibrated as above.
BOUND_UNSEEN_FRACTION = 0.1


def honest_bounds(volume: float, estimate_bounds: tuple[float, float] | None, unobserved_area: float,
                  area: float, *, noise: float, extent: float) -> tuple[float, float]:
    """A volume interval for an estimate that rests partly on completion, m^3.

    The estimate's own bounds (what its cloud left open, counting completed points as measured) are
    widened by the observed surface's noise (``BOUND_NOISE_SIGMAS`` x sigma over the whole area) and by
    the unobserved surface (``BOUND_UNSEEN_FRACTION`` x the smallest extent over its area).

    Args:
        volume: m^3, the estimate. estimate_bounds: (low, high) m^3 or None (= volume).
        unobserved_area, area: m^2 (:func:`estimation.coverage.coverage`). noise: metres, sensor sigma of the observed points.
        extent: metres, the object's smallest extent (the OBB's).
    """
    low, high = estimate_bounds if estimate_bounds is not None else (volume, volume)
    slack = area * BOUND_NOISE_SIGMAS * noise + unobserved_area * BOUND_UNSEEN_FRACTION * extent
    return max(0.0, min(low, volume) - slack), max(high, volume) + slack
