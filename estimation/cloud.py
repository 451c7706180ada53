"""The point cloud record and the checks every estimate starts with."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np

from estimation import tolerances as tol
from estimation.contracts import as_points
from estimation.errors import CloudError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PointCloud:
    """Points sampled on one object's surface.

    Attributes:
        points: (n, 3) float64, metres, in the cloud's own frame.
        normals: (n, 3) float64 unit vectors pointing out of the object, or None when unknown.
        colors: (n, 3) float64 in [0, 1], or None.
        dropped_nonfinite: rows removed because a coordinate was NaN or inf.
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    dropped_nonfinite: int = field(default=0)

    def __len__(self) -> int:
        return len(self.points)

    def without_normals(self) -> PointCloud:
        return replace(self, normals=None)

    def transformed(self, rotation: np.ndarray, translation: np.ndarray) -> PointCloud:
        """Return the cloud moved by ``x -> R x + t`` (normals rotated too)."""
        rotation = np.asarray(rotation, dtype=np.float64)
        normals = None if self.normals is None else self.normals @ rotation.T
        return replace(self, points=self.points @ rotation.T + np.asarray(translation), normals=normals)


def make_cloud(
    points: object,
    normals: object | None = None,
    colors: object | None = None,
    *,
    scale: float = 1.0,
) -> PointCloud:
    """Build a clean :class:`PointCloud`: drop non-finite rows, scale to metres, normalise normals.

    Args:
        points: (n, 3) coordinates in the file's units.
        normals: (n, 3) or None. Rows with zero or non-finite normals make the whole set unusable; then
            normals are dropped (estimated later) rather than half-trusted.
        colors: (n, 3) or None; 0-255 integers are rescaled to [0, 1].
        scale: multiply coordinates by this to get metres (0.001 for millimetres).

    Raises:
        CloudError: empty cloud, wrong shapes, or no finite point left.
    """
    pts = as_points(points, "points", allow_nonfinite=True)
    if len(pts) == 0:
        raise CloudError("the cloud is empty (0 points)")
    good = np.isfinite(pts).all(axis=1)
    dropped = int((~good).sum())
    if dropped == len(pts):
        raise CloudError(f"all {len(pts)} points have NaN or inf coordinates")
    if dropped:
        log.warning("dropped %d of %d points with NaN or inf coordinates", dropped, len(pts))
    pts = pts[good] * float(scale)

    nrm = None
    if normals is not None:
        n = as_points(normals, "normals", allow_nonfinite=True)
        if len(n) != len(good):
            raise CloudError(f"normals: expected {len(good)} rows to match points, got {len(n)}")
        n = n[good]
        length = np.linalg.norm(n, axis=1)
        if np.isfinite(length).all() and (length > 0).all():
            nrm = n / length[:, None]
        else:
            log.warning("some normals are zero or non-finite; ignoring all given normals")

    col = None
    if colors is not None:
        c = np.asarray(colors, dtype=np.float64)
        if c.shape == (len(good), 3):
            c = c[good]
            col = c / 255.0 if c.max(initial=0.0) > 1.0 else c
    return PointCloud(pts, nrm, col, dropped)


def check_estimable(cloud: PointCloud) -> None:
    """Raise if ``cloud`` cannot enclose a volume: too few points, or flat or line-like.

    Raises:
        CloudError: with the count or the principal extents in the message.
    """
    n = len(cloud)
    if n < tol.MIN_POINTS:
        raise CloudError(f"too few points: {n} (need at least {tol.MIN_POINTS})")
    centred = cloud.points - cloud.points.mean(axis=0)
    # Singular values of the centred cloud are its spread along the principal axes.
    spread = np.linalg.svd(centred[:: max(1, n // 20000)], compute_uv=False)
    if spread[0] <= 0:
        raise CloudError("degenerate cloud: all points are identical")
    if spread[2] < tol.FLATNESS_RATIO * spread[0]:
        shape = "line-like" if spread[1] < tol.FLATNESS_RATIO * spread[0] else "flat (planar)"
        raise CloudError(f"degenerate cloud: {shape}, it encloses no volume")
