"""The point cloud record and the checks every estimate starts with."""

from __future__ import annotations

import logging
import math
import numbers
from dataclasses import dataclass, field, replace

import numpy as np

from estimation import tolerances as tol
from estimation.contracts import all_finite, as_points
from estimation.errors import CloudError, refused_number
from estimation.obb import column_bounds

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PointCloud:
    """Points sampled on one object's surface.

    Attributes:
        points: (n, 3) float64, metres, in the cloud's own frame.
        normals: (n, 3) float64 unit vectors pointing out of the object, or None when unknown.
        colors: (n, 3) float64 in [0, 1], or None.
        dropped_nonfinite: rows removed because a coordinate was NaN or inf.
        sensor_origins: (n, 3) float64, metres, same frame as ``points``: where the sensor stood when it
            saw each point (for orienting normals and carving free space), or None when unknown. One
            origin for the whole cloud is stored as a read-only broadcast view (row stride 0), so it costs
            24 bytes, not 24 bytes a point.
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    dropped_nonfinite: int = field(default=0)
    sensor_origins: np.ndarray | None = None

    def __post_init__(self) -> None:
        # make_cloud builds clean records; one built by hand is held to the same rules here, so a list, a NaN
        # or a normal of the wrong length is a CloudError at the door, not an IndexError deep in an estimate.
        points = self.points
        if not (isinstance(points, np.ndarray) and points.dtype == np.float64 and points.ndim == 2):
            object.__setattr__(self, "points", points := as_points(points, "points", allow_nonfinite=True))
        elif points.shape[1] != 3:
            raise CloudError(f"points: expected shape (n, 3), got {points.shape}")
        _check_finite(points, "points", "coordinates (make_cloud drops such rows)")
        for name, unit in (("normals", "unit vectors"), ("colors", "values in [0, 1]"),
                           ("sensor_origins", "positions")):
            value = getattr(self, name)
            if value is None:
                continue
            if not (isinstance(value, np.ndarray) and value.dtype == np.float64):
                object.__setattr__(self, name, value := as_points(value, name, allow_nonfinite=True))
            # A subset of the points with the old origins (or normals) would silently pair them with wrong rows.
            if value.shape != points.shape:
                raise CloudError(f"{name}: expected shape {points.shape} to match points, got {value.shape}")
            _check_finite(value[:1] if is_single_origin(value) else value, name, unit)
        if self.normals is not None:
            # On a sample of rows: a full check would cost a 1M-point estimate 8 ms. It catches the usual
            # mistakes (unnormalised or zero normals); make_cloud normalises every row.
            sample = self.normals[:: max(1, len(points) // 20000)]
            length = np.sqrt(np.einsum("ij,ij->i", sample, sample))
            if len(sample) and np.abs(length - 1).max() > tol.UNIT_NORMAL_TOLERANCE:
                raise CloudError(f"normals: expected unit vectors, found lengths {length.min():.3g} to "
                                 f"{length.max():.3g} (make_cloud normalises them)")
        if self.colors is not None and len(points) and not (0.0 <= self.colors.min() and self.colors.max() <= 1.0):
            raise CloudError("colors: expected values in [0, 1] (make_cloud rescales 0-255)")
        dropped = self.dropped_nonfinite
        if isinstance(dropped, bool) or not isinstance(dropped, numbers.Integral) or dropped < 0:
            raise CloudError(f"dropped_nonfinite: expected a count of rows, got {str(dropped)[:40]}")

    def __len__(self) -> int:
        return len(self.points)

    def without_normals(self) -> PointCloud:
        return replace(self, normals=None)

    def subset(self, keep: np.ndarray) -> PointCloud:
        """The points ``keep`` selects ((n,) bool or indices), with their normals, colours and origins."""
        take = lambda a: None if a is None else a[keep]  # noqa: E731
        points, origins = self.points[keep], self.sensor_origins
        if origins is not None:  # one origin stays one broadcast row
            origins = np.broadcast_to(origins[0], points.shape) if is_single_origin(origins) else origins[keep]
        return replace(self, points=points, normals=take(self.normals), colors=take(self.colors),
                       sensor_origins=origins)

    def transformed(self, rotation: np.ndarray, translation: np.ndarray) -> PointCloud:
        """Return the cloud moved by ``x -> R x + t`` (normals rotated, sensor origins moved too)."""
        rotation = np.asarray(rotation, dtype=np.float64)
        translation = np.asarray(translation, dtype=np.float64)
        normals = None if self.normals is None else self.normals @ rotation.T
        origins = self.sensor_origins
        if origins is not None:
            if is_single_origin(origins):
                origins = np.broadcast_to(rotation @ origins[0] + translation, origins.shape)
            else:
                origins = origins @ rotation.T + translation
        return replace(
            self, points=self.points @ rotation.T + translation, normals=normals, sensor_origins=origins
        )


def check_is_cloud(value: object, caller: str) -> None:
    """Raise unless ``value`` is a :class:`PointCloud`: one check for every function that takes the record.

    Raises:
        TypeError: naming ``caller``, what it takes, how to build one, and what came in (an (n, 3) array was an
            AttributeError deep inside).
    """
    if not isinstance(value, PointCloud):
        raise TypeError(f"{caller} takes a PointCloud (make_cloud(points) builds one from an (n, 3) array), "
                        f"got {type(value).__name__}")


def _check_finite(values: np.ndarray, name: str, what: str) -> None:
    """Raise naming ``name`` unless every entry of ``values`` is finite."""
    if all_finite(values):
        return
    bad = int((~np.isfinite(values).all(axis=1)).sum())
    raise CloudError(f"{name}: {bad} of {len(values)} rows hold NaN or inf; expected finite {what}")


def is_single_origin(origins: np.ndarray) -> bool:
    """True when ``origins`` ((n, 3)) is one origin broadcast to every row, as make_cloud stores a (3,)."""
    return origins.ndim == 2 and origins.strides[0] == 0


def make_cloud(
    points: object,
    normals: object | None = None,
    colors: object | None = None,
    *,
    scale: float = 1.0,
    sensor_origins: object | None = None,
    copy: bool = True,
) -> PointCloud:
    """Build a clean :class:`PointCloud`: drop non-finite rows, scale to metres, normalise normals.

    Args:
        points: (n, 3) coordinates in the file's units.
        normals: (n, 3) or None. Rows with zero or non-finite normals make the whole set unusable; then
            normals are dropped (estimated later) rather than half-trusted.
        colors: (n, 3) or None; 0-255 integers are rescaled to [0, 1].
        scale: multiply coordinates by this to get metres (0.001 for millimetres).
        sensor_origins: (3,) one sensor position for every point, or (n, 3) one per point, in the same
            frame and units as ``points`` (scaled with them); rows dropped from ``points`` are dropped
            here too. None when unknown.
        copy: False lets the record share the given arrays when nothing needs changing (the file
            readers hand over fresh arrays); True never aliases the caller's arrays.

    Raises:
        CloudError: empty cloud, wrong shapes, no finite point left, or non-finite sensor origins.
    """
    if isinstance(scale, bool) or not isinstance(scale, numbers.Real) or not (math.isfinite(scale) and scale > 0):
        # NaN made every point NaN past the finiteness check; a negative one mirrored the object.
        raise CloudError(f"scale must be a positive number of metres per unit, got {str(scale)[:40]}")
    pts = as_points(points, "points", allow_nonfinite=True)
    if len(pts) == 0:
        raise CloudError("the cloud is empty (0 points)")
    # The flat check is ~15x faster than the per-row one and true for almost every cloud.
    good = np.ones(len(pts), dtype=bool) if np.isfinite(pts).all() else np.isfinite(pts).all(axis=1)
    dropped = int((~good).sum())
    if dropped == len(pts):
        raise CloudError(f"all {len(pts)} points have NaN or inf coordinates")
    if dropped:
        log.warning("%s", nonfinite_note(dropped, len(pts)))
        pts = pts[good]
    if scale != 1.0:
        pts = pts * float(scale)
    elif copy and not dropped and np.may_share_memory(pts, points):
        pts = pts.copy()  # the record must not alias the caller's array

    nrm = None
    if normals is not None:
        n = as_points(normals, "normals", allow_nonfinite=True)
        if len(n) != len(good):
            raise CloudError(f"normals: expected {len(good)} rows to match points, got {len(n)}")
        if dropped:
            n = n[good]
        length = np.sqrt(np.einsum("ij,ij->i", n, n))  # 3x faster than np.linalg.norm(n, axis=1)
        if np.isfinite(length).all() and (length > 0).all():
            nrm = n / length[:, None]
        else:
            log.warning("some normals are zero or non-finite; ignoring all given normals")

    col = None
    if colors is not None:
        c = np.asarray(colors, dtype=np.float64)
        # Colours only colour the views (rerun): ones that cannot be colours are left out, said, not fatal.
        if c.shape != (len(good), 3):
            log.warning("colors: expected one (r, g, b) per point, (%d, 3), got shape %s; left out", len(good), c.shape)
        elif not (np.isfinite(c).all() and c.min(initial=0.0) >= 0.0 and c.max(initial=0.0) <= 255.0):
            log.warning("colors: values outside 0..255 (or NaN); left out")
        else:
            c = c[good] if dropped else c.copy() if copy and np.may_share_memory(c, colors) else c
            col = c / 255.0 if c.max(initial=0.0) > 1.0 else c
    origins = None if sensor_origins is None else _origins(sensor_origins, good, dropped, float(scale))
    return PointCloud(pts, nrm, col, dropped, origins)


def _origins(value: object, good: np.ndarray, dropped: int, scale: float) -> np.ndarray:
    """Check and scale ``sensor_origins`` for make_cloud: (3,) is broadcast, (n, 3) follows the points."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise CloudError(
            f"sensor_origins: expected a numeric (3,) or (n, 3) array, got {type(value).__name__}"
        ) from exc
    kept = len(good) - dropped
    if arr.shape == (3,):
        one = as_points(arr[None], "sensor_origins")[0] * scale
        one.flags.writeable = False
        return np.broadcast_to(one, (kept, 3))
    if arr.ndim != 2 or arr.shape != (len(good), 3):
        raise CloudError(f"sensor_origins: expected shape (3,) or ({len(good)}, 3) to match points, got {arr.shape}")
    if dropped:
        arr = arr[good]
    return as_points(arr, "sensor_origins") * scale


def check_sensor_origin(origin: np.ndarray, what: str) -> None:
    """Raise unless ``origin`` ((3,) or (n, 3) metres) lies within ``tolerances.MAX_COORDINATE_M`` of the origin.

    A sensor beyond any coordinate an estimate accepts is a damaged header or the wrong units, and orienting
    normals towards it overflows (at 1e160 m numpy warned of a divide by zero and an invalid cast and the
    estimate went on); a depth camera's pose is held to the same bound (``estimation.depthimage.pose``).

    Raises:
        CloudError: naming ``what`` and how far the sensor is.
    """
    if not np.isfinite(origin).all():
        raise CloudError(f"{what}: the sensor's position is not finite (NaN or inf): a damaged VIEWPOINT or pose?")
    far = float(np.abs(origin).max(initial=0.0))
    if far > tol.MAX_COORDINATE_M:
        raise CloudError(f"{what}: the sensor is {refused_number(far, tol.MAX_COORDINATE_M, digits=3)} m from the origin, beyond "
                         f"the {tol.MAX_COORDINATE_M:g} m "
                         "an estimate accepts (wrong --units, or a damaged VIEWPOINT?)")


def check_count_and_range(points: np.ndarray) -> None:
    """Raise unless ``points`` ((n, 3) finite, metres) are at least ``tolerances.MIN_POINTS`` rows, all within
    ``tolerances.MAX_COORDINATE_M`` of the origin: what a spacing or a neighbour search needs to be defined.

    Raises:
        CloudError: with the count, or how far the points reach (and the stray points, if a few make it).
    """
    n = len(points)
    if n < tol.MIN_POINTS:
        raise CloudError(f"too few points: {n} (need at least {tol.MIN_POINTS})")
    check_range(points)


def check_range(points: np.ndarray, what: str = "coordinates") -> None:
    """Raise unless ``points`` ((n, 3) finite, metres) all lie within ``tolerances.MAX_COORDINATE_M`` of the origin.

    Raises:
        CloudError: how far ``what`` reach, and the stray points if a few make it.
    """
    far = float(np.abs(points).max()) if len(points) else 0.0
    if far > tol.MAX_COORDINATE_M:
        stray = far_points(points)
        raise CloudError(f"{what} reach {refused_number(far, tol.MAX_COORDINATE_M, digits=3)} m from the origin, beyond the "
                         f"{tol.MAX_COORDINATE_M:g} m "
                         f"an estimate accepts" + (f"; that is {stray}: remove them" if stray else
                                                   " (wrong --units or scale?)"))


def nonfinite_note(dropped: int, total: int) -> str:
    """What dropping ``dropped`` of ``total`` points with NaN or inf coordinates is called: one wording in the log and
    in an estimate's warnings, so a reader of both sees one thing said once."""
    return f"dropped {dropped} of {total} points with NaN or inf coordinates"


def check_estimable(cloud: PointCloud) -> None:
    """Raise if ``cloud`` cannot enclose a volume: too few distinct points, out of range, flat or line-like.

    Raises:
        CloudError: with the count, the coordinates' range or the principal extents in the message.
        TypeError: ``cloud`` is not a :class:`PointCloud`.
    """
    check_is_cloud(cloud, "check_estimable")
    check_spread(cloud.points)
    # Singular values of the centred cloud are its spread along the principal axes (a uniform subset of
    # 20,000 tells flat from solid as well as a million points, at a 50th of the cost).
    sample = cloud.points[:: max(1, len(cloud) // 20000)]
    centred = sample - sample.mean(axis=0)
    _, spread, axes = np.linalg.svd(centred, full_matrices=False)
    if spread[2] < tol.FLATNESS_RATIO * spread[0]:
        shape = "line-like" if spread[1] < tol.FLATNESS_RATIO * spread[0] else "flat (planar)"
        # The extents say which: a needle 1 m long and 1.5 x 0.5 mm across is flat by these ratios, a strip.
        extents = " x ".join(f"{e:.3g}" for e in np.ptp(centred @ axes.T, axis=0))
        far = far_points(cloud.points)
        raise CloudError(f"degenerate cloud: {shape}, it encloses no volume ({extents} m along its principal axes)"
                         + (f"; but that is {far}: remove them" if far else ""))


def check_spread(points: np.ndarray) -> None:
    """Raise unless ``points`` ((n, 3) finite, metres) are :func:`check_count_and_range`'s and spread: not one
    point repeated, at least ``tolerances.MIN_EXTENT_M`` across, ``tolerances.MIN_POINTS`` distinct. Before any
    neighbour search: a k-d tree's query among coincident points takes time with the square of their number.

    Raises:
        CloudError: naming which.
    """
    check_count_and_range(points)
    low, high = column_bounds(points)  # np.ptp(axis=0) took 70 ms of a 1M-point estimate
    across = float((high - low).max())
    if across == 0:
        raise CloudError("degenerate cloud: all points are identical")
    if across < tol.MIN_EXTENT_M:
        raise CloudError(f"object is {refused_number(across, tol.MIN_EXTENT_M, digits=3)} m across, below the "
                         f"{tol.MIN_EXTENT_M:g} m an estimate "
                         f"resolves (wrong --units or scale?)")
    distinct = count_distinct(points, tol.MIN_POINTS)
    if distinct < tol.MIN_POINTS:
        raise CloudError(f"too few distinct points: {distinct} distinct positions among {len(points)} points (need "
                         f"at least {tol.MIN_POINTS}; repeated rows add no surface)")


def far_points(points: np.ndarray) -> str:
    """Describe the few far points that, not the object, make a cloud look flat, line-like or vast; or "".

    One stray point 1 km from a 10 cm object turns the principal spread into a line (or, less far, a grid
    of 10^11 cells). Points farther from the median than ``tol.OUTLIER_REACH`` times the distance within
    which 99 % of the points lie are far; when the rest is solid, errors name them (they are not dropped:
    which points are the object is the caller's call). For failure paths: it looks at every point.

    Args:
        points: (n, 3) float64, metres.
    """
    found = _far(points)
    if found is None:
        return ""
    far, d, reach = found
    return f"{int(far.sum())} far point(s), up to {d.max():.3g} m from the rest, which lies within {reach:.3g} m"


def without_far_points(points: np.ndarray) -> np.ndarray:
    """``points`` ((n, 3) float64, metres) without the far points :func:`far_points` names (all of them when it
    names none): the bulk whose size says whether the object, not a few points, is implausibly large."""
    found = _far(points)
    return points if found is None else points[~found[0]]


def _far(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The far points of :func:`far_points` (a mask), each point's distance from the median and the reach of
    the rest; None when there are none or the rest is not solid."""
    # The largest coordinate difference, not the Euclidean norm: its squares overflow past 1e154 m.
    d = np.abs(points - np.median(points, axis=0)).max(axis=1)
    reach = float(np.percentile(d, 99))
    far = d > tol.OUTLIER_REACH * reach
    rest = points[~far][:: max(1, int((~far).sum()) // 20000)]
    if not far.any() or len(rest) < 4:
        return None
    spread = np.linalg.svd(rest - rest.mean(axis=0), compute_uv=False)
    if spread[2] < tol.FLATNESS_RATIO * spread[0]:
        return None
    return far, d, reach


def distinct_rows(points: np.ndarray) -> np.ndarray:
    """Indices of the first occurrence of each distinct row of ``points`` ((n, 3) float64), sorted."""
    rows = np.ascontiguousarray(points, dtype=np.float64) + 0.0  # + 0.0: -0.0 and 0.0 are one position
    # One 24-byte key a row: ~4x faster than np.unique(axis=0).
    _, first = np.unique(rows.view(np.dtype((np.void, rows.itemsize * 3))).ravel(), return_index=True)
    return np.sort(first)


def count_distinct(points: np.ndarray, enough: int) -> int:
    """Distinct rows of ``points`` ((n, 3) float64), counted until ``enough`` are found.

    Counts over a growing prefix, so a cloud with plenty of distinct points costs one small sort, and only
    a heavily repeated one is sorted whole.
    """
    m = enough
    while True:
        found = len(distinct_rows(points[:m]))
        if found >= enough or m >= len(points):
            return found
        m *= 8
