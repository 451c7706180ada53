"""Several views of one object to one estimate that says how sure it is.

A view is a cloud in a shared world frame plus the sensor origin it was seen from (a PCD's ``VIEWPOINT``
translation, a depth image's camera centre). The views are fused with per-point origins
(:func:`estimation.fusion.fuse_views`), the support plane's points are cut away and the object's base is
closed on the plane (:func:`estimation.completion.close_bottom`), normals are oriented towards each
point's sensor (:func:`estimation.fusion.fused_cloud`) and the result is estimated ('auto'). The record
adds what the estimate alone cannot know: the share of the closed surface some sensor saw (``coverage``)
and a volume interval that widens with what was completed or closed rather than observed
(:func:`estimation.completion.honest_bounds`), and has no top where a depth image's frame cut the object and
no other view looked past the cut (:func:`estimation.carving.open_past_frame`).

Frames: world, metres, with ``+z`` up where a direction is needed (the plane "just below the lowest
points" is horizontal), as in MuJoCo's world.
"""

from __future__ import annotations

import logging
import math
import numbers
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from estimation import tolerances as tol
from estimation.carving import DepthView
from estimation.cloud import check_range, check_sensor_origin, check_spread, distinct_rows
from estimation.completion import ONE_SIDED, close_on_plane, honest_bounds, mean_view_direction
from estimation.contracts import as_points, shown
from estimation.coverage import coverage
from estimation.errors import CloudError, ReconstructionError, SettingsError, refused_number
from estimation.estimate import PhysicalEstimate, estimate
from estimation.fusion import fuse_views, fused_cloud, oriented_normals
from estimation.segmentation import (
    CLUSTER_SPACINGS,
    MIN_CLUSTER_POINTS,
    Plane,
    cluster,
    fit_plane,
    median_spacing,
)

log = logging.getLogger(__name__)

#: RANSAC inlier distance for a plane found in a file, in noise sigmas (``spacing.surface_noise``) and at
#: least ``PLANE_SPACINGS`` point spacings: a table scanned at 1 mm noise is a slab ~6 mm thick.
PLANE_NOISE_SIGMAS = 3.0
PLANE_SPACINGS = 1.5

#: A plane found by RANSAC is the support only if it holds at least this share of the points (a table
#: around an object shows as a good part of a tabletop scan; a stray face of the object does not count)...
MIN_PLANE_SHARE = 0.05

#: ...and at most this share of the other points lie below it (the object's own face fails: the rest of
#: the object is behind it, on the side away from the sensors).
MAX_BELOW_SHARE = 0.05

#: A view with less than this share of its points above the plane in the largest cluster, and more in another,
#: sees that other cluster as its side of the object (:func:`_views_own_sides`).
OWN_SIDE_SHARE = 0.5

#: Points above the plane apart from the object (other clusters of ``segmentation.MIN_CLUSTER_POINTS`` or
#: more) earn a warning beyond this share: a second object, or a plane that is not the support.
OTHER_CLUSTERS_SHARE = 0.05

#: The plane's inliers may add this share of themselves below the margin (its noise tail: 0.13 % beyond 3
#: sigma for Gaussian noise; heavier-tailed real sensors, flying pixels left over).
PLANE_TAIL_SHARE = 0.01

#: Planes tried, largest first, before the data is said to hold no support plane.
PLANE_CANDIDATES = 3

#: A given plane with more than this share of the points more than a cut below it is refused: its normal
#: most likely points into the table, or the numbers are for another frame.
MAX_BELOW_GIVEN = 0.1


@dataclass(frozen=True)
class View:
    """One view of an object.

    Attributes:
        points: (n, 3) float64, metres, world frame (n may be 0: reported, not fused).
        origin: (3,) float64 metres, world frame: the sensor centre, or (n, 3) one per point (a fused
            file's per-point origins); None when unknown.
        name: where it came from (a file name), for messages.
        depth: the depth image the points came from, if any: with one for every view, the space the
            cameras saw through is carved (``estimation.carving``) to close what none of them saw.
    """

    points: np.ndarray
    origin: np.ndarray | None
    name: str = ""
    depth: DepthView | None = None

    def __post_init__(self) -> None:
        label = self.name or "a view"
        object.__setattr__(self, "points", as_points(self.points, f"{label}: points"))
        if self.origin is not None:
            try:
                origin = np.asarray(self.origin, dtype=np.float64)
            except (TypeError, ValueError):
                origin = None
            if origin is None or origin.shape not in ((3,), self.points.shape):
                raise CloudError(f"{label}: origin: expected the sensor's position, (3,) or one per point "
                                 f"{self.points.shape}, got {getattr(origin, 'shape', type(self.origin).__name__)}")
            object.__setattr__(self, "origin", origin)


@dataclass(frozen=True)
class ViewsEstimate:
    """An estimate from views, with how much of it rests on observation.

    Attributes:
        estimate: the physical estimate of the fused, completed cloud.
        coverage: share (0-1) of the closed surface's area within reach of an observed point.
        volume_bounds_m3: (low, high) m^3: where the volume may lie given the noise and what was not
            observed (see :func:`estimation.completion.honest_bounds`).
        view_points: points each view contributed (input order; table points included).
        object_points: observed points of the object after the support plane was cut away.
        completed_points: points added by completion (the base on the support plane).
        plane: the support plane used, or None.
        warnings: the estimate's warnings and those of fusion and completion.
    """

    estimate: PhysicalEstimate
    coverage: float
    volume_bounds_m3: tuple[float, float]
    view_points: tuple[int, ...]
    object_points: int
    completed_points: int
    plane: Plane | None
    warnings: tuple[str, ...]


def _checked_plane(support: object) -> Plane:
    """A support plane given to :func:`estimate_views`: a :class:`Plane` made unit (a normal of length 2
    doubled the volume, of 1000 asked for 1 TiB), or four numbers A B C D as :func:`plane_from_abcd` reads.

    Raises:
        CloudError: as :func:`plane_from_abcd`, or a Plane whose rms is negative or not finite.
    """
    if not isinstance(support, Plane):
        return plane_from_abcd(support)
    if not (math.isfinite(support.rms) and support.rms >= 0):
        raise CloudError(f"support plane: its rms must be a finite number of metres >= 0, got {support.rms!r}")
    return replace(plane_from_abcd(support.as_abcd()), rms=float(support.rms), inliers=support.inliers)


def plane_from_abcd(abcd: object) -> Plane:
    """The plane ``A x + B y + C z + D = 0`` (metres), normal ``(A, B, C)`` normalised.

    Raises:
        CloudError: not four finite numbers, a zero normal, or a plane farther than
            ``tolerances.MAX_COORDINATE_M`` from the origin.
    """
    try:
        values = np.asarray(abcd, dtype=np.float64).ravel()
    except (TypeError, ValueError) as exc:
        raise CloudError(f"support plane: expected four numbers A B C D, got {abcd!r}") from exc
    if values.shape != (4,) or not np.isfinite(values).all():
        raise CloudError(f"support plane: expected four finite numbers A B C D, got {values.tolist()}")
    # Scaled by the largest of A B C before the norm: 0 0 1e308 0 (the plane z = 0) overflowed the norm to
    # inf and became a zero normal ("only 0 points lie above the support plane").
    biggest = float(np.abs(values[:3]).max())
    if biggest == 0:
        raise CloudError("support plane: the normal (A, B, C) is zero")
    values = values / biggest
    length = float(np.linalg.norm(values[:3]))
    distance = float(values[3]) / length
    if abs(distance) > tol.MAX_COORDINATE_M:
        raise CloudError(f"support plane: it passes {refused_number(abs(distance), tol.MAX_COORDINATE_M, digits=3)} m from the "
                         f"origin, beyond the "
                         f"{tol.MAX_COORDINATE_M:g} m an estimate accepts (D is in the file's units)")
    return Plane(values[:3] / length, distance, 0.0, 0)


def plane_below(points: np.ndarray) -> Plane:
    """The horizontal plane (normal +z, world up) through the lowest of ``points`` ((n, 3) metres)."""
    pts = as_points(points, "points")
    return Plane(np.array([0.0, 0.0, 1.0]), -float(pts[:, 2].min()), 0.0, 0)


def find_support_plane(points: np.ndarray, origins: np.ndarray, *, threshold: float,
                       rng: np.random.Generator) -> Plane | None:
    """The support plane in the data (RANSAC), or None when none of the largest planes is one.

    A plane is the support when it holds at least ``MIN_PLANE_SHARE`` of the points, almost all the
    others (``1 - MAX_BELOW_SHARE``, besides the plane's own noise tail) lie on its sensors' side (an
    object's own face has the rest of the object behind it) and so does every sensor. The largest plane is tried first; when it is
    refused, its points are set aside and the next largest is tried, up to ``PLANE_CANDIDATES`` planes: in a
    crop close around a box or a book, the object's top outweighs the ring of table around it.

    Args:
        points: (n, 3) float64 metres, world frame. origins: (n, 3) the sensor of each point.
        threshold: RANSAC inlier distance, metres. rng: for RANSAC's draws.
    """
    rest = np.arange(len(points))
    toward = origins.mean(axis=0)
    for _ in range(PLANE_CANDIDATES):
        if len(rest) < MIN_PLANE_SHARE * len(points) or len(rest) < 3:
            return None
        try:
            plane = fit_plane(points[rest], threshold=threshold, toward=toward, rng=rng)
        except CloudError:
            return None
        h = plane.height(points)
        inliers = int((np.abs(h) < threshold).sum())
        if inliers < MIN_PLANE_SHARE * len(points):
            return None  # the next ones are smaller still
        # Every camera must be above it: a support's top is seen from its upper side only. An object's side
        # face passes the other test where the object's rest is too short behind it to count (the bracket's
        # upright and foot end, read with their true noise), but some camera looks at it from below.
        if _supports(h, plane.clearance(threshold), inliers) and bool((plane.height(origins) > 0).all()):
            return plane
        rest = rest[np.abs(h[rest]) >= threshold]
    return None


def _supports(h: np.ndarray, margin: float, inliers: int) -> bool:
    """Whether a plane with heights ``h`` (m, every point) and ``inliers`` points can be the support."""
    off = np.abs(h) > margin
    # The plane's own noise tail below the margin grows with the plane, not with the object: on a large
    # table next to a small object it alone was 5.0 % of the off-plane points (the bracket's depth images).
    # An object's face has the rest of the object behind it, far more than its own tail.
    return bool(off.any()) and (h < -margin).sum() <= MAX_BELOW_SHARE * off.sum() + PLANE_TAIL_SHARE * inliers


#: Times the support may move up to a plane that what stands on it holds (floor -> table -> tray).
STANDING_ROUNDS = 2

#: What stands on the support is itself a support when one plane in it, parallel to the first (within
#: ``PARALLEL_DEGREES``), holds at least this share of its points and carries at least
#: ``segmentation.MIN_CLUSTER_POINTS`` points standing clear of it (above twice its noise margin) inside its
#: own extent, with almost nothing below it there. A whole table seen from above is almost all top (0.96 of
#: it under a bar of soap); an object's own top face (a book's) carries nothing, the foot of the L-bracket
#: of tests/test_views.py holds 0.44-0.56 of it, and a tray's rim stands at the edge of its extent.
STANDING_PLANE_SHARE = 0.8
PARALLEL_DEGREES = 15.0

#: Points below a plane count against it only this many RANSAC thresholds inside its extent (its edge: a
#: table's side face projects onto the edge, within the sensor's noise and a flying pixel or two).
EXTENT_MARGIN_THRESHOLDS = 2.0


def _cut_threshold(points: np.ndarray, height: np.ndarray, noise: float, threshold: float) -> float:
    """The RANSAC ``threshold`` (metres) with the spacing of what stands on the plane (``height``: (n,) each
    point's, metres) in place of the whole cloud's, where that is finer: the band cut away above the plane.

    A table sampled every 11 mm under a 2 cm cube sampled every 0.6 mm set the spacing, and so a 15 mm cut:
    three quarters of the cube went with the table and it came out 5 times its volume, its interval's low
    end 2.5 times. The plane's own points are not thicker for being sparse; the object's spacing says how
    finely its lowest band can be told from them.
    """
    from estimation.spacing import point_spacing

    above = points[height > PLANE_NOISE_SIGMAS * noise]
    if len(above) < MIN_CLUSTER_POINTS:
        return threshold
    return min(threshold, max(PLANE_NOISE_SIGMAS * noise, PLANE_SPACINGS * point_spacing(above)))


def _largest_above(points: np.ndarray, origins: np.ndarray, plane: Plane, cut: float, view_of: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(object, others): (n,) bool masks of the largest connected cluster more than ``cut`` (metres) above
    ``plane`` and of the other clusters; ``origins`` (n, 3) are the points' sensors, ``view_of`` (n,) int which
    view each came from.

    Raises:
        CloudError: fewer than 3 points above the cut, or no cluster among them.
    """
    from estimation.carving import plane_frame

    keep = np.flatnonzero(plane.height(points) > cut)
    if len(keep) < 3:
        raise CloudError(f"only {len(keep)} points lie above the support plane")
    # What the cut leaves of the plane (its noise tail, edge pixels) is scattered over the whole table;
    # the object is the largest connected cluster above it. Its voxels are laid in axes that move with the
    # scene: on the world's, a rotation of the same views let other stray points join the object.
    above = points[keep]
    local = plane_frame(above, plane, mean_view_direction(above, origins[keep], plane.normal))[2]
    labels = cluster(local, cell=CLUSTER_SPACINGS * _cluster_spacing(above, view_of[keep]))
    if (labels == 0).sum() < 3:
        raise CloudError("no object above the support plane (only scattered points)")
    joined = _views_own_sides(labels, view_of[keep])
    obj, others = np.zeros(len(points), dtype=bool), np.zeros(len(points), dtype=bool)
    obj[keep[np.isin(labels, joined)]] = True
    others[keep[(labels >= 0) & ~np.isin(labels, joined)]] = True
    return obj, others


def _views_own_sides(labels: np.ndarray, view_of: np.ndarray) -> list[int]:
    """The cluster labels that are the object: the largest (0), and the cluster holding most of a view's points
    where that view has little in the largest (under :data:`OWN_SIDE_SHARE` of its points in it, over it in the
    other): the views are all of the object, so what such a view mostly sees is the object's side the others do
    not. Two cameras facing each other across a mug see two halves with no point between them: rays graze the
    mug at its outline and their points thin out there, so the halves lie centimetres apart, and one was dropped
    as another object (-54 %)."""
    joined = [0]
    for view in np.unique(view_of):
        mine = labels[(view_of == view) & (labels >= 0)]
        if len(mine) == 0:
            continue
        counts = np.bincount(mine)
        best = int(np.argmax(counts))
        if best != 0 and counts[0] < OWN_SIDE_SHARE * len(mine) < counts[best] and best not in joined:
            joined.append(best)
    return joined


def _cluster_spacing(points: np.ndarray, view_of: np.ndarray) -> float:
    """Metres: the spacing the clustering cell is counted in, the median nearest-neighbour distance of all the
    views' points, but no less than the sparsest view's own over the root of the number of views (what views
    that interleave make of it). Two frames from one camera put each point next to its twin a noise away
    (exactly on it, the same frame twice): the union's spacing shrank to the noise, the object fell apart into
    cells, and two 0.5 mm frames of a box came out -84 % (0.2 mm: "no object above the support plane")."""
    spacing = median_spacing(points)
    if spacing == 0.0:  # most points repeated: a cell of 0 divided by zero
        spacing = median_spacing(np.unique(points, axis=0))
    ids, counts = np.unique(view_of, return_counts=True)
    if len(ids) < 2:
        return spacing
    own = [median_spacing(np.unique(points[view_of == i], axis=0)) for i, n in zip(ids, counts, strict=True) if n >= 3]
    return max(spacing, max(own, default=0.0) / float(np.sqrt(len(ids))))


#: A support plane further below the object's lowest points than this many times the object's width is refused:
#: closing the base down to it grew a grid with the gap (a 5 cm dome over a plane 100 m below took 9 GB, one 10 km
#: below was killed by the kernel at 24 GB; 10 m below gave 0.9 m^3 after 16 s).
MAX_GAP_WIDTHS = 5.0


def _gap_below(points: np.ndarray, plane: Plane) -> str | None:
    """A warning when the object's points ((n, 3) metres) all stand further above ``plane`` than the object is
    wide: no object seen rests on such a plane (a plane in another frame or other units, a floor given for
    a table), and closing the base on it makes a tower of what nobody saw. Nearer than that, a plane below
    an object seen only from above cannot be told from one it rests on; nothing is said.

    Raises:
        CloudError: the gap is more than ``MAX_GAP_WIDTHS`` times the object's width.
    """
    from estimation.carving import plane_frame

    local = plane_frame(points, plane)[2]
    lowest = float(np.percentile(local[:, 2], 1))
    width = float(np.ptp(local[:, :2], axis=0).max())
    if lowest <= width:
        return None
    said = (f"the object's lowest points lie {1000 * lowest:.0f} mm above the support plane, more than the object "
            f"is wide ({1000 * width:.0f} mm)")
    if lowest > MAX_GAP_WIDTHS * width:
        raise CloudError(f"support plane: {said}, {lowest / max(width, 1e-12):.3g} times: it is not what the object "
                         f"rests on (is it in the views' frame and units, its normal up into the object's side?)")
    return (f"{said}: it does not rest on that plane, and closing it down to the plane adds what no camera saw "
            f"(is the plane in the views' frame and units?)")


def _standing_support(points: np.ndarray, plane: Plane, *, threshold: float, toward: np.ndarray,
                      rng: np.random.Generator) -> Plane | None:
    """The plane that ``points`` (what stands on ``plane``, metres) are mostly made of, if it is a support
    with something standing on it (``STANDING_PLANE_SHARE``); else None."""
    if len(points) < MIN_CLUSTER_POINTS:
        return None
    try:
        candidate = fit_plane(points, threshold=threshold, toward=toward, rng=rng)
    except CloudError:
        return None
    if float(candidate.normal @ plane.normal) < np.cos(np.radians(PARALLEL_DEGREES)):
        return None
    h = candidate.height(points)
    inliers = np.abs(h) < threshold
    if inliers.sum() < STANDING_PLANE_SHARE * len(points):
        return None
    margin = candidate.clearance(threshold)
    # Below it, only what lies beyond its edge (the table's sides, the floor) may be more than its noise tail.
    within = _within_extent(points, candidate, inliers, EXTENT_MARGIN_THRESHOLDS * threshold)
    standing = within & (h > 2 * margin)
    if standing.sum() < MIN_CLUSTER_POINTS or not _supports(h[within], margin, int(inliers.sum())):
        return None
    return candidate


def _within_extent(points: np.ndarray, plane: Plane, inliers: np.ndarray, margin: float) -> np.ndarray:
    """(n,) bool: the points whose foot on ``plane`` lies inside the convex hull of the ``inliers``' feet, at
    least ``margin`` metres from its edge."""
    from scipy.spatial import ConvexHull, QhullError

    n = plane.normal
    u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    flat = np.stack([points @ u, points @ np.cross(n, u)], axis=1)
    try:
        hull = ConvexHull(flat[inliers])
    except (QhullError, ValueError):
        return np.zeros(len(points), dtype=bool)
    # Facet equations a . x + b <= 0 inside, a unit: -(a . x + b) is the distance inside.
    return (flat @ hull.equations[:, :2].T + hull.equations[:, 2] <= -margin).all(axis=1)


#: A given support plane with more than this share of the object's points (what stands above it) lying more
#: than its cut below it, under the object, cuts into the object: the points under a plane that a box rests
#: on are its noise tail and a flying pixel or two; a plane 3 mm up a 40 mm box has 4 % of them under it
#: (-7.8 %), 10 mm up, 8 % (-25 %).
MAX_UNDER_OBJECT_SHARE = 0.02


def _sensor_below(plane: Plane, views: list[View]) -> str | None:
    """"the sensor of VIEW lies N mm below it" for the first view whose sensor lies on ``plane`` or below it;
    None when every sensor is above it (a camera sees a support's top from above)."""
    for k, view in enumerate(views):
        height = plane.height(np.atleast_2d(view.origin))  # type: ignore[arg-type]
        if (height <= 0).any():
            return f"the sensor of {_label(view, k)} lies {1000 * -float(height.min()):.4g} mm below it"
    return None


def _sensors_above(plane: Plane, views: list[View], what: str) -> None:
    """Raise unless every view's sensor lies on ``plane``'s upper side: a camera sees a support's top from above.

    Raises:
        CloudError: a sensor on the plane or below it, naming the view and ``what`` the plane is.
    """
    under = _sensor_below(plane, views)
    if under is not None:
        raise CloudError(f"{what}: {under}, and a camera sees what rests on a plane from above (is the normal up "
                         f"into the object's side, the plane in the views' frame and units?)")


def _not_through(points: np.ndarray, plane: Plane, h: np.ndarray, cut: float, obj: np.ndarray) -> None:
    """Raise when a given ``plane`` cuts into the object: more than ``MAX_UNDER_OBJECT_SHARE`` of the object's
    points (``obj``, (n,) bool over ``points``; ``h`` their heights, metres) lie more than ``cut`` below it,
    within the object's footprint on it and no deeper than the object stands above it (a table's front face
    and the floor beyond its edge do not count; under an object standing at the edge, a strip of the face
    might)."""
    from scipy.spatial import cKDTree

    if not obj.any():
        return
    below = np.flatnonzero((h < -cut) & (h > -cut - float(h[obj].max())))
    if not len(below):
        return
    feet = points - h[:, None] * plane.normal
    spacing = median_spacing(points[obj])
    under = cKDTree(feet[obj]).query(feet[below], distance_upper_bound=2 * spacing + cut, workers=-1)[0] < np.inf
    if under.sum() > MAX_UNDER_OBJECT_SHARE * obj.sum():
        deepest = float(-h[below[under]].min())
        raise CloudError(f"support plane: {int(under.sum())} points lie up to {1000 * deepest:.4g} mm below it, under "
                         f"the object ({100 * under.sum() / obj.sum():.0f} % as many as stand above it): the plane "
                         f"cuts into the object; give the plane it rests on")


def _every_view_on_it(views: list[View], view_of: np.ndarray, obj: np.ndarray, warnings: list[str]) -> None:
    """Warn of the views none of whose points is on the object (``obj``, (n,) bool; ``view_of`` (n,) view index)."""
    seen = np.bincount(view_of[obj], minlength=len(views))
    missing = [_label(v, k) for k, v in enumerate(views) if seen[k] == 0]
    if missing:
        warnings.append(f"none of the points of {_listed(missing)} lie on the object (only the table or other "
                        f"things in view, or a view in another frame or units?)")


def _label(view: View, k: int) -> str:
    """How messages name the ``k``-th view (from 0): its name, else "view k+1"."""
    return view.name or f"view {k + 1}"


def _listed(names: list[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def estimate_views(views: list[View], density: float, *, support: Plane | str | None = None,
                   material: str | None = None, seed: int = 0, keep_strays: bool = False,
                   progress: Callable[[str], None] | None = None) -> ViewsEstimate:
    """Fuse ``views`` of one object, close its base on the support plane, estimate, and say how sure.

    Args:
        views: one or more views in one world frame; every view needs an ``origin``.
        density: kg/m^3.
        support: a :class:`Plane` or four numbers A B C D (normal up into the object's side; normalised),
            ``"auto"`` (found in the data, else the horizontal plane through the lowest point, unless a
            sensor lies below that: then none, warned) or None (no plane: nothing is cut or closed).
        material: recorded with the estimate.
        seed: RANSAC's and thinning's randomness (``"auto"``, over :data:`tolerances.VIEW_POINTS`): a whole
            number >= 0, as numpy takes.
        keep_strays, progress: see :func:`estimation.estimate.estimate`.

    Raises:
        TypeError: ``views`` not an iterable of :class:`View` records.
        SettingsError: ``seed`` not a whole number >= 0.
        CloudError: a view without origin or with one beyond ``tolerances.MAX_COORDINATE_M``, a view with no
            points, fewer than ``tolerances.MIN_POINTS`` points in all or any beyond
            ``tolerances.MAX_COORDINATE_M``, a plane with most points below it, or too few object points left.
        ReconstructionError: as :func:`estimation.estimate`.
    """
    from estimation.spacing import point_spacing, surface_noise

    wrong = TypeError("estimate_views takes a list of View records (View(points, origin) builds one)")
    if isinstance(views, View):
        raise wrong
    try:
        views = list(views)  # once: a generator checked here would be empty below ("no view saw any point")
    except TypeError:
        raise wrong from None
    if not all(isinstance(v, View) for v in views):
        raise wrong
    # numpy said "expected non-negative integer" for -1, and a SeedSequence TypeError for 1.5.
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise SettingsError(f"seed must be a whole number >= 0, got {shown(seed)}")
    for k, view in enumerate(views):
        label = _label(view, k)
        if view.origin is None:
            raise CloudError(f"{label}: no sensor origin (no VIEWPOINT header or vp_x vp_y vp_z fields; a VIEWPOINT of "
                             f"0 0 0 1 0 0 0, the PCD default, is read as unknown; pass --viewpoint X Y Z)")
        check_sensor_origin(view.origin, label)
        if len(view.points) == 0:
            raise CloudError(f"{label}: the view has no points")
        check_range(view.points, f"{label}: coordinates")  # before fusing, which would lose whose they are
    points, origins = fuse_views([(v.points, v.origin) for v in views])
    view_of = np.repeat(np.arange(len(views)), [len(v.points) for v in views])  # no view is empty (above)
    # Before the spacing and the noise: a 1-pixel depth frame (one point) or one of 1e300 m depths was an
    # IndexError inside them, and 150,000 copies of one point took 90 s in their neighbour searches.
    check_spread(points)
    spacing = point_spacing(points)
    noise = surface_noise(points)
    if len(points) > tol.VIEW_POINTS:
        # Every step below fits normals to, or searches, every point: a 4096 x 4096 frame of one depth took
        # minutes (35 s and 6.5 GB at 2048 x 2048). Thinned as the estimate thins to its budget.
        from estimation.downsample import thin_to_budget

        keep = thin_to_budget(points, spacing, noise, tol.VIEW_POINTS, seed=seed)
        log.info("views: %d points thinned to %d", len(points), len(keep))
        points, origins, view_of = points[keep], origins[keep], view_of[keep]
        spacing = point_spacing(points)
    # A repeated position is one point (a quantised sensor, a view written twice): a patch of copies fits no
    # normal, and a k-d tree's queries among 150,000 copies of one point beside a box's 5,000 took 76 s.
    keep = distinct_rows(points)
    if len(keep) < len(points):
        log.info("views: %d repeated positions dropped", len(points) - len(keep))
        points, origins, view_of = points[keep], origins[keep], view_of[keep]
    threshold = max(PLANE_NOISE_SIGMAS * noise, PLANE_SPACINGS * spacing)
    warnings: list[str] = []
    plane: Plane | None
    found = False  # the plane was found in the data (not given, not the fallback through the lowest point)
    if isinstance(support, str):
        if support != "auto":
            raise CloudError(f"support plane: expected 'auto' or A B C D, got {support!r}")
        plane = find_support_plane(points, origins, threshold=threshold, rng=np.random.default_rng(seed))
        found = plane is not None
        if plane is None:
            plane = plane_below(points)
            under = _sensor_below(plane, views)
            if under is None:
                warnings.append(f"no support plane in the data; assumed the horizontal plane through the lowest "
                                f"point (z = {-plane.offset:.4g} m)")
            else:
                # A guess the views contradict: a camera under it could have seen the base. Not the user's
                # error (they asked for auto), so closed as without a plane, and said.
                warnings.append(f"no support plane in the data, and the horizontal plane through the lowest point "
                                f"will not do ({under}): closed without a support plane (give one with "
                                f"--support-plane A B C D)")
                plane = None
    elif support is not None:
        plane = _checked_plane(support)
        _sensors_above(plane, views, "support plane")
    else:
        plane = None
    cut = 0.0
    if plane is not None:
        h = plane.height(points)
        # At least the RANSAC threshold, not only 3 rms: the plane's noise tail next to the object would join it
        # (bracket scan: +8 % at 3 rms, +4 % at the threshold; the skirt of close_bottom restores the band cut).
        cut = plane.clearance(_cut_threshold(points, h, noise, threshold))
        below = float((h < -cut).mean())
        if below > MAX_BELOW_GIVEN:
            raise CloudError(f"support plane: {100 * below:.0f} % of the points lie more than {1000 * cut:.2g} mm "
                             f"below it (its normal must point up into the object's side)")
        obj, others = _largest_above(points, origins, plane, cut, view_of)
        if found:
            # Whole frames of a tabletop hold the floor too, a plane with everything above it: the "object"
            # above the floor is then the table with the object standing on it. Its own support is the table.
            for _ in range(STANDING_ROUNDS):
                higher = _standing_support(points[obj], plane, threshold=threshold, toward=origins.mean(axis=0),
                                           rng=np.random.default_rng(seed))
                if higher is None:
                    break
                plane = higher
                h = plane.height(points)
                cut = plane.clearance(_cut_threshold(points, h, noise, threshold))
                obj, others = _largest_above(points, origins, plane, cut, view_of)
                warnings.append(f"what stood on the first plane found was itself mostly a plane with something "
                                f"standing on it (a table on the floor?): took that plane (z = {-plane.offset:.4g} "
                                f"m where level) as the support")
        if support is not None and not isinstance(support, str):
            _not_through(points, plane, h, cut, obj)
        _every_view_on_it(views, view_of, obj, warnings)
        if (n_others := int(others.sum())) > OTHER_CLUSTERS_SHARE * int((obj | others).sum()):
            warnings.append(f"{n_others} points above the support plane lie apart from the object and were dropped "
                            f"(another object in the views?)")
        others = points[others]
        points, origins = points[obj], origins[obj]
        if (gap := _gap_below(points, plane)) is not None:
            warnings.append(gap)
        normals = oriented_normals(points, origins)
        from estimation.carving import carving_views, depth_of_points

        # A view that came as points carves as the depth image they imply: without it the far side of a
        # box seen by one or two cameras was closed by a thin shell (-30 to -80 %).
        pictures = [[v.depth] if v.depth is not None else depth_of_points(v.points, v.origin, plane)  # type: ignore[arg-type]
                    for v in views]
        # A view that cannot be pictured carves nothing; the others still carve what they saw through (until
        # session 41 one such view, eight points or a stray behind its sensor, stopped every view carving, and a
        # box seen by two cameras came out -67 %, silently).
        unpictured = [_label(v, k) for k, (v, p) in enumerate(zip(views, pictures, strict=True)) if p is None]
        if unpictured:
            warnings.append(f"{_listed(unpictured)} could not be pictured as a depth image (too few points, or spread "
                            f"wider than a camera sees): {'it does' if len(unpictured) == 1 else 'they do'} not carve "
                            f"the space seen through, and what no view saw is closed on less evidence")
        carving = None
        if any(p is not None for p in pictures):
            # A file does not say its sensor's noise: the fused points' own, for every pixel.
            carving = carving_views([replace(d, sigma=noise) for p in pictures if p is not None for d in p], plane, cut)
        closed = close_on_plane(points, origins, normals, plane, cell=point_spacing(points), cut=cut, noise=noise,
                                views=carving, others=others)
    else:
        normals = oriented_normals(points, origins)  # for coverage only: nothing is closed without a plane
        closed = close_on_plane(points, origins, np.full_like(points, np.nan), None, cell=0.0, cut=0.0)
    completion = closed.completion
    observed = len(points)
    # Observed normals are refitted (NaN here): with the base and skirt as neighbours, those near the base turn.
    alln = np.where(closed.completed[:, None], closed.normals, np.nan)
    cloud = fused_cloud(closed.points, closed.origins, completed=closed.completed, completed_normals=alln)
    result = on_support(estimate(cloud, density, material=material, keep_strays=keep_strays, progress=progress),
                        closed.support)
    share, bounds = assess(result, points, noise, normals=normals, open_past_frame=completion.open_past_frame)
    warnings.extend(result.warnings)
    if len(completion.points) and completion.base_area > 0:
        warnings.append(f"the base ({completion.base_area * 1e4:.3g} cm^2) was closed on the support plane, "
                        f"not observed")
    elif len(completion.points):  # no flat base ("the base (0 cm^2) was closed" said so of a carved hull's points)
        how = [f"{n:,} {what}" for n, what in ((completion.carved, "on the hull the views carved"),
                                                (completion.mirrored, "mirrored"), (completion.turned, "turned"))
               if n] or [f"{len(completion.points):,}"]
        warnings.append(f"what no view saw was closed on the support plane and the views' evidence ({', '.join(how)} "
                        f"points), not observed")
    if completion.open_past_frame:
        warnings.append(f"the object runs out of a depth image's frame where no other view looked: what lies past "
                        f"the frame's border is unknown, the estimate is of the part seen, and the volume is only "
                        f"known to be at least {bounds[0]:.4g} m^3")
    elif share < COVERAGE_WARNING and _one_sided(points, origins):
        # Every view from one side: what lies behind the seen surface is bounded by nothing they saw (a ball
        # seen by one camera came out at 18 % of its volume with an interval that stopped at 40 %).
        bounds = (bounds[0], float("inf"))
        warnings.append(f"only {100 * share:.0f} % of the closed surface was observed, all from one side: nothing "
                        f"bounds what lies behind it, so the volume is only known to be at least {bounds[0]:.4g} m^3")
    elif share < COVERAGE_WARNING:
        warnings.append(f"only {100 * share:.0f} % of the closed surface was observed, the rest rests on "
                        f"completion: with the sensor noise, the volume lies in {bounds[0]:.4g}..{bounds[1]:.4g} m^3")
    return ViewsEstimate(result, share, bounds, tuple(len(v.points) for v in views), observed,
                         len(completion.points), plane, tuple(warnings))


#: Coverage below this earns a warning that the answer rests on completion.
COVERAGE_WARNING = 0.9

def _one_sided(points: np.ndarray, origins: np.ndarray) -> bool:
    """Whether every view of ``points`` ((n, 3), their sensors ``origins`` (n, 3), metres) looks from one side:
    ``completion.ONE_SIDED`` in three dimensions (one camera's 60 degree view of an object ~0.97, two cameras 90
    degrees apart ~0.71)."""
    return float(np.linalg.norm(mean_view_direction(points, origins))) >= ONE_SIDED


def assess(result: PhysicalEstimate, observed: np.ndarray, noise: float, *,
           normals: np.ndarray | None = None, open_past_frame: bool = False) -> tuple[float, tuple[float, float]]:
    """Coverage (0-1) of ``result``'s mesh by the ``observed`` points and its volume interval (m^3).

    Args:
        result: an estimate (its mesh, cell and bounds are used).
        observed: (n, 3) float64 metres, same frame: the points a sensor returned (no completed ones).
        noise: metres, the observed points' sigma (``spacing.surface_noise``).
        normals: (n, 3) the observed points' outward normals, if known: a face counts as seen only by points
            facing its way (``completion.coverage``).
        open_past_frame: the completion's flag (``Completion.open_past_frame``): a camera's frame cut the object
            where no view looked past it, so the interval has no top (the object may run on out of view).
    """
    from estimation.spacing import point_spacing

    # A face between two measured points is observed: the radius follows the observed points' spacing
    # when the reconstruction's cell is finer (completed points can make it so).
    radius = 2 * max(result.cell, point_spacing(observed) if len(observed) > 1 else 0.0)
    seen, total = coverage(result.vertices, result.faces, observed, radius=radius, normals=normals)
    share = seen / total if total > 0 else 0.0
    low, high = honest_bounds(result.volume, result.volume_bounds_m3, total - seen, total, noise=noise,
                              extent=float(result.obb.extents.min()))
    return share, (low, float("inf") if open_past_frame else high)


#: A support plane more than ``MAX_BELOW_GIVEN`` of an estimate's points lie this many reconstruction cells
#: below is not what the object rests on (:func:`on_support`): nothing is cut at it.
SUPPORT_BELOW_CELLS = 2.0


def on_support(result: PhysicalEstimate, plane: Plane | None, *, points: np.ndarray | None = None
               ) -> PhysicalEstimate:
    """``result`` less all of its solid below ``plane``: its surface cut there, and its mass properties less those
    of the piece cut away.

    An object closed on the plane it rests on (completion's base, :func:`estimation.completion.close_on_plane`)
    has nothing below that plane. The reconstruction leaves some there all the same: its cells straddle the base's
    edge, and the noisy points and normals around that edge push a vertex out (the 20-object clutter seen by three
    cameras at sigma 1 mm: every object 0.4 to 2.5 mm below its plane). A foot on one side of a base is what a
    convex hull stands on: a soup can built so rested tilted 1.6 degrees on the twin's table.

    The piece's flat-faced mass properties are taken from the estimate's (:func:`estimation.inertia.without`), so
    what the estimate holds beyond its mesh (the curved slivers of ``estimation.curvature``) stays, and its
    volume interval moves down by the piece's volume. A surface that does not reach below ``plane`` (or ``plane``
    None) comes back as it is. With ``points`` ((n, 3) metres, the cloud the estimate was made from), a plane more
    than ``MAX_BELOW_GIVEN`` of them lie more than ``SUPPORT_BELOW_CELLS`` cells below is not the object's
    support: nothing is cut, and a warning says so; so does a plane above the whole surface, and a surface
    manifold3d cannot take as closed.
    """
    from estimation.inertia import mass_properties, without
    from estimation.meshparts import split_at_plane

    if plane is None or len(result.faces) == 0:
        return result
    if float(plane.height(result.vertices).min()) >= 0.0:
        return result

    def kept(why: str) -> PhysicalEstimate:
        return replace(result, warnings=(*result.warnings, f"{why}: nothing cut at the support plane"))

    if points is not None and len(points):
        below = float((plane.height(np.asarray(points, np.float64)) < -SUPPORT_BELOW_CELLS * result.cell).mean())
        if below > MAX_BELOW_GIVEN:
            return kept(f"{100 * below:.0f} % of the points lie below the support plane given, so it is not the "
                        f"object's")
    split = split_at_plane(result.vertices, result.faces, plane.normal, plane.offset)
    if split is None:
        return kept("the surface is not a closed manifold")
    (vertices, faces), (under_v, under_f) = split
    if not len(faces):
        return kept("the whole surface lies below the support plane given, so it is not the object's")
    if not len(under_f):
        return result
    try:
        under = mass_properties(under_v, under_f, result.mass.density)
    except ReconstructionError:  # a sliver with no volume to speak of: the mesh is cut, the mass as it was
        return replace(result, vertices=vertices, faces=faces)
    log.info("cut at the support plane: %.3g cm^3 of %.4g (%.3f %%)", 1e6 * under.volume, 1e6 * result.volume,
             100 * under.volume / result.volume)
    bounds = result.volume_bounds_m3
    if bounds is not None:
        bounds = (max(0.0, bounds[0] - under.volume), bounds[1] - under.volume)
    return replace(result, vertices=vertices, faces=faces, mass=without(result.mass, under), volume_bounds_m3=bounds)


def with_completion(result: PhysicalEstimate, points: np.ndarray, completed: np.ndarray, *,
                    normals: np.ndarray | None = None) -> PhysicalEstimate:
    """``result``, the estimate of ``points`` ((n, 3) metres) some of which a sender's completion added where no
    sensor saw (``completed``, (n,) bool), with the volume interval of what was observed (:func:`assess`, the
    noise the observed points' own; it widens the estimate's own interval), and, when less than ``COVERAGE_WARNING`` of its surface
    was observed, a warning saying so. A cloud over the wire (``sync.messages.Cloud.completed``) says which
    points were completed but not from where they were seen: the one-sided check of :func:`estimate_views`
    cannot be made here.

    Raises:
        ValueError: ``completed`` not one flag per point, or ``normals`` not one per point.
    """
    from estimation.spacing import surface_noise

    points = np.asarray(points, np.float64)
    completed = np.asarray(completed, bool)
    if completed.shape != (len(points),) or (normals is not None and np.shape(normals) != points.shape):
        raise ValueError(f"with_completion: {len(points)} points, {completed.shape} flags, "
                         f"{None if normals is None else np.shape(normals)} normals")
    if not completed.any():
        return result
    observed = points[~completed]
    if len(observed) < tol.MIN_POINTS:
        share, bounds = 0.0, (0.0, float("inf"))
    else:
        share, bounds = assess(result, observed, surface_noise(observed),
                               normals=None if normals is None else np.asarray(normals, np.float64)[~completed])
    warnings = result.warnings
    if share < COVERAGE_WARNING:
        warnings += (f"only {100 * share:.0f} % of the closed surface was observed; the rest ({100 * completed.mean():.0f} "
                     f"% of the points) was completed by the sender where no sensor saw: the volume lies in "
                     f"{bounds[0]:.4g}..{bounds[1]:.4g} m^3",)
    return replace(result, volume_bounds_m3=bounds, warnings=warnings)
