"""From depth images to one object's cloud: back-projection, flying-pixel rejection, fused views, normals.

Pure numpy/scipy (no simulator): a depth image from a real camera goes through the same functions as one
from ``scenes/cameras.py``. Conventions: pinhole camera, OpenCV axes (x right, y down, z forward), depth
is the z coordinate in the camera frame (what RGB-D cameras report), NaN where there was no return.

Why per-point sensor origins: a fused cloud's points were seen from different places. A normal is
oriented towards the camera that saw its point (the point was on the camera's side of the surface); one
viewpoint for all (``estimate(viewpoint=...)``) flips every normal on the far side of a two-view cloud.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from estimation import tolerances as tol
from estimation.cloud import PointCloud, make_cloud
from estimation.contracts import as_points
from estimation.errors import CloudError

log = logging.getLogger(__name__)

#: A pixel whose 3x3 neighbourhood spans more depth than this many times its own axial noise (and at
#: least ``MIN_EDGE_JUMP_M``) sits on a depth edge. Edge pixels are where structured-light and ToF
#: sensors return "flying pixels" (a mix of foreground and background depth, Sabov & Krueger 2008), so
#: they are dropped: a 1-pixel erosion of each silhouette, which other views cover.
EDGE_SIGMAS = 6.0

#: Smallest depth jump that counts as an edge, metres: a tilted plane's neighbouring pixels differ by up
#: to a few millimetres at 1-2 m and grazing angles; a smaller threshold would eat tilted faces.
MIN_EDGE_JUMP_M = 0.01


@dataclass(frozen=True)
class Intrinsics:
    """A pinhole camera's intrinsics: focal lengths and principal point in pixels, image size.

    Attributes:
        fx, fy: focal lengths, pixels.
        cx, cy: principal point, pixels (pixel centres at integer + 0.5).
        width, height: image size, pixels.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @classmethod
    def from_fov(cls, width: int, height: int, fov_y_deg: float) -> Intrinsics:
        """Square pixels, centred principal point, vertical field of view ``fov_y_deg`` degrees."""
        f = 0.5 * height / np.tan(np.radians(fov_y_deg) / 2)
        return cls(f, f, width / 2, height / 2, int(width), int(height))

    def rays(self) -> np.ndarray:
        """(height * width, 3) float64 camera-frame directions with z = 1, row-major pixel order."""
        u, v = np.meshgrid(np.arange(self.width) + 0.5, np.arange(self.height) + 0.5)
        return np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy, np.ones_like(u)], -1).reshape(-1, 3)


def depth_to_points(depth: np.ndarray, intrinsics: Intrinsics, rotation: np.ndarray,
                    position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Back-project a depth image into the world.

    Args:
        depth: (height, width) float64, metres along the camera's z; NaN (or <= 0) where no return.
        intrinsics: the camera's.
        rotation: (3, 3) camera-to-world rotation (columns: the camera's x, y, z axes in the world).
        position: (3,) metres, world frame: the camera centre.

    Returns:
        points (n, 3) float64 metres, world frame, and their flat pixel indices (n,) int64.

    Raises:
        CloudError: the depth image's shape does not match the intrinsics.
    """
    depth = np.asarray(depth, dtype=np.float64)
    if depth.shape != (intrinsics.height, intrinsics.width):
        raise CloudError(f"depth: expected shape ({intrinsics.height}, {intrinsics.width}), got {depth.shape}")
    flat = depth.ravel()
    with np.errstate(invalid="ignore"):
        index = np.flatnonzero(np.isfinite(flat) & (flat > 0))
    rays = intrinsics.rays()[index] * flat[index, None]
    return rays @ np.asarray(rotation, dtype=np.float64).T + np.asarray(position, dtype=np.float64), index


def edge_mask(depth: np.ndarray, sigma: np.ndarray | float, *, sigmas: float = EDGE_SIGMAS,
              min_jump: float = MIN_EDGE_JUMP_M) -> np.ndarray:
    """(height, width) bool: pixels on a depth edge (likely flying pixels), to drop before fusing.

    Args:
        depth: (height, width) float64 metres, NaN where no return (a NaN neighbour is not an edge:
            dropouts are random, and an edge against nothing is a silhouette against the far range).
        sigma: the axial noise at each pixel, metres, (height, width) or a scalar.
        sigmas, min_jump: the jump threshold is ``max(sigmas * sigma, min_jump)``.
    """
    from scipy import ndimage

    filled_hi = np.where(np.isfinite(depth), depth, -np.inf)
    filled_lo = np.where(np.isfinite(depth), depth, np.inf)
    hi = ndimage.maximum_filter(filled_hi, size=3, mode="nearest")
    lo = ndimage.minimum_filter(filled_lo, size=3, mode="nearest")
    with np.errstate(invalid="ignore"):
        jump = np.maximum(hi - depth, depth - lo)
        return np.isfinite(depth) & (jump > np.maximum(sigmas * np.asarray(sigma), min_jump))


def fuse_views(views: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate views into one cloud with per-point sensor origins.

    Args:
        views: (points (n_i, 3) float64 metres world frame, origin (3,) metres world frame) per view;
            views with no points are skipped.

    Returns:
        points (n, 3) and sensor_origins (n, 3), float64 metres, world frame.

    Raises:
        CloudError: no view has any point.
    """
    kept = [(as_points(p, "points"), np.asarray(o, dtype=np.float64)) for p, o in views if len(p)]
    if not kept:
        raise CloudError("no view saw any point of the object")
    points = np.concatenate([p for p, _ in kept])
    origins = np.concatenate([np.broadcast_to(o, p.shape) for p, o in kept])
    return points, origins


def oriented_normals(points: np.ndarray, sensor_origins: np.ndarray, *, k: int = tol.NORMAL_NEIGHBOURS,
                     fixed: np.ndarray | None = None) -> np.ndarray:
    """PCA normals (n, 3) (:func:`estimation.normals.estimate_normals`), each flipped towards the sensor that
    saw its point.

    Args:
        points: (n, 3) float64 metres.
        sensor_origins: (n, 3) float64 metres, same frame: where each point was seen from.
        k: neighbours per point (itself included).
        fixed: (n, 3) unit normals to keep where finite (completed points whose outward side is known,
            such as a support plane's bottom); NaN rows are estimated. None: estimate all.

    Raises:
        CloudError: shapes disagree or fewer than 3 points.
    """
    from estimation.normals import estimate_normals, orient_to_viewpoint

    pts = as_points(points, "points")
    org = as_points(sensor_origins, "sensor_origins")
    if org.shape != pts.shape:
        raise CloudError(f"sensor_origins: expected shape {pts.shape} to match points, got {org.shape}")
    if len(pts) < 3:
        raise CloudError(f"too few points for normals: {len(pts)}")
    normals = orient_to_viewpoint(pts, estimate_normals(pts, k), org)
    if fixed is not None:
        given = np.isfinite(fixed).all(axis=1)
        normals[given] = fixed[given]
    return normals


def fused_cloud(points: np.ndarray, sensor_origins: np.ndarray, *, completed: np.ndarray | None = None,
                completed_normals: np.ndarray | None = None) -> PointCloud:
    """A :class:`PointCloud` with normals oriented per point, ready for ``estimate`` (no viewpoint needed).

    Args:
        points: (n, 3) float64 metres, world frame, observed and completed points.
        sensor_origins: (n, 3) float64 metres: each observed point's camera; completed rows are ignored.
        completed: (n,) bool, True for points no camera saw (e.g. the closed bottom), or None.
        completed_normals: (n, 3) unit outward normals for the completed rows (others ignored), or None.
    """
    pts = as_points(points, "points")
    fixed = None
    if completed is not None and completed.any():
        fixed = np.full_like(pts, np.nan)
        if completed_normals is not None:
            fixed[completed] = completed_normals[completed]
    normals = oriented_normals(pts, sensor_origins, fixed=fixed)
    return make_cloud(pts, normals, sensor_origins=sensor_origins)


#: Neighbours whose spread gives a model point's normal for :func:`unseen_motions`: more than for a
#: reconstruction's normals (``tolerances.NORMAL_NEIGHBOURS``), as the test needs the normals' direction
#: averaged over a millimetre of noise, not sharp edges.
MOTION_NORMAL_NEIGHBOURS = 40

#: A motion (turns scaled by the points' RMS radius) whose point-to-plane information is under this share of
#: the best-seen motion's may move the surface along itself. ``tests/test_cameras.py`` checks the split on
#: noisy models (sigma 1 mm): a ball's three turns and a can's or a ring's turn about its axis fall under it,
#: the flat box's weakest turn and every motion of a box, a brick or a bracket stay above.
UNSEEN_MOTION_SHARE = 0.02

#: Such a motion counts only if it is mostly a turn (its turn part at least this long; the eigenvectors are
#: unit) and the points, turned along it until the farthest moves ``SYMMETRY_TEST_SPACINGS`` of their
#: spacing (the 99th percentile of nearest-neighbour distances), land on themselves: the 99th percentile of
#: their distances to the points at most ``SYMMETRY_SPREAD`` spacings. The point-to-plane information does
#: not see an open edge: a book seen from above alone has null shifts and turn in its plane, but ICP finds
#: them at its outline, which moves. On clutter20's ICP models the true turns of balls, cans and rings
#: stayed well under the bound and the outline-bound turns of a book or a sponge seen by one camera well
#: over it (looked at by hand; ``bench/cameras.py`` prints the turns at rest that result, and
#: ``tests/test_cameras.py`` checks the split on a ball, a can, a ring, a crate, a book and a bracket).
MIN_TURN_PART = 0.5
SYMMETRY_TEST_SPACINGS = 3.0
SYMMETRY_SPREAD = 1.8


@dataclass(frozen=True)
class SurfaceMotions:
    """The motions of a rigid surface its own points cannot show (:func:`unseen_motions`).

    Attributes:
        centre: (3,) the points' centroid, metres (the turns are about it).
        scale: metres, the points' RMS distance from it (turns are scaled by it to compare with shifts).
        basis: (6, m) columns in (turn x scale, shift) coordinates, each a pure turn about some axis; m = 0
            for a surface that shows every motion, 3 for a ball, 1 for a can or a ring (about its axis).
    """

    centre: np.ndarray
    scale: float
    basis: np.ndarray

    def without(self, step: np.ndarray) -> np.ndarray:
        """``step`` (4, 4), a rigid motion of the points' frame, less its part along :attr:`basis`: what the
        surface can show of it (a ball's turns about its centre removed, its centre's shift kept)."""
        from scipy.spatial.transform import Rotation

        if not self.basis.shape[1]:
            return step
        rot, t = step[:3, :3], step[:3, 3]
        turn = Rotation.from_matrix(rot).as_rotvec()
        shift = rot @ self.centre + t - self.centre  # the centre's own motion
        xi = np.concatenate([turn * self.scale, shift])
        # Of the motions that look the same (xi plus any mix of the basis), the one without the basis's
        # turns: a ball keeps its orientation and moves with its centre, a can keeps its axis where it is.
        mix = np.linalg.lstsq(self.basis[:3], xi[:3], rcond=None)[0]
        xi = xi - self.basis @ mix
        out = np.eye(4)
        out[:3, :3] = Rotation.from_rotvec(xi[:3] / self.scale).as_matrix()
        out[:3, 3] = self.centre + xi[3:] - out[:3, :3] @ self.centre
        return out

    def moved(self, transform: np.ndarray) -> SurfaceMotions:
        """The same motions of the surface after ``transform`` (4, 4) moved it: centre and axes where it put
        them (to hold them while registering, onto this surface, points in the frame ``transform`` maps to)."""
        rot = transform[:3, :3]
        return SurfaceMotions(rot @ self.centre + transform[:3, 3], self.scale,
                              np.vstack([rot @ self.basis[:3], rot @ self.basis[3:]]))


def unseen_motions(points: np.ndarray, *, k: int = MOTION_NORMAL_NEIGHBOURS,
                   share: float = UNSEEN_MOTION_SHARE) -> SurfaceMotions:
    """The rigid motions that slide a surface, sampled by ``points`` ((n, 3) metres), along itself.

    The eigenvectors of the point-to-plane information matrix (the sum of ``[(q x n) / scale, n]`` outer
    products, ``q`` a point about the centroid, ``n`` its PCA normal from ``k`` neighbours) whose eigenvalue
    is under ``share`` of the largest: ICP cannot see motion along them, so what it reports there is noise.
    """
    from scipy.spatial import cKDTree
    from scipy.spatial.transform import Rotation

    from estimation.normals import estimate_normals

    pts = as_points(points, "points")
    centre = pts.mean(axis=0)
    q = pts - centre
    scale = float(np.sqrt((q**2).sum(axis=1).mean()))
    if len(pts) < 3 or scale <= 0:
        return SurfaceMotions(centre, max(scale, 1.0), np.zeros((6, 0)))
    normals = estimate_normals(pts, min(k, len(pts)))
    rows = np.hstack([np.cross(q, normals) / scale, normals])
    values, vectors = np.linalg.eigh(rows.T @ rows)
    tree = cKDTree(q)
    spacing = float(np.percentile(tree.query(q, k=2, workers=-1)[0][:, 1], 99))
    reach = float(np.linalg.norm(q, axis=1).max())
    kept = []
    for u in vectors[:, values < share * values.max()].T:
        turn = np.linalg.norm(u[:3])
        if turn < MIN_TURN_PART:
            continue
        # A pure turn about some axis: the eigenvectors may mix a can's turn with its shift along its axis
        # (a screw) when no end of it was seen; the shift is not the turn's to take away.
        u = np.concatenate([u[:3], u[3:] - (u[3:] @ u[:3]) / turn**2 * u[:3]])
        # Along u until the farthest point moves SYMMETRY_TEST_SPACINGS spacings (turn angle per unit of u:
        # turn / scale radians).
        step = SYMMETRY_TEST_SPACINGS * spacing / reach / (turn / scale)
        moved = q @ Rotation.from_rotvec(step * u[:3] / scale).as_matrix().T + step * u[3:]
        if np.percentile(tree.query(moved, workers=-1)[0], 99) <= SYMMETRY_SPREAD * spacing:
            kept.append(u)
    return SurfaceMotions(centre, scale, np.array(kept).T if kept else np.zeros((6, 0)))


@dataclass(frozen=True)
class Registration:
    """A rigid motion found by ICP: ``x -> transform[:3, :3] x + transform[:3, 3]``, world frame.

    Attributes:
        transform: (4, 4) float64.
        fitness: share of source points with a correspondence within the distance (0-1).
        rmse: metres, RMS distance of those correspondences.
        covariance: (6, 6) of the motion's rotation (radians, about x y z through ``pivot``) and translation
            (metres), in that order: ``rmse^2`` times the inverse of the correspondences' information matrix
            (Open3D's ``get_information_matrix_from_point_clouds``). It counts the noise only, not what
            partial overlap and a changed view do to ICP: at rest the tracked error runs well above it
            (``bench/cameras.py`` prints both).
        pivot: (3,) metres, world frame: the point the covariance's rotation turns about.
    """

    transform: np.ndarray
    fitness: float
    rmse: float
    covariance: np.ndarray | None = None
    pivot: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def position_sigma(self, point: np.ndarray) -> float:
        """Metres: the standard deviation, along its worst direction, of where the motion puts ``point``
        ((3,) metres, world frame, after the motion); 0 when not known. A small motion moves it by
        ``omega x (point - pivot) + t``, so the rotation's uncertainty counts with the point's distance from
        the pivot."""
        if self.covariance is None:
            return 0.0
        p = np.asarray(point, dtype=np.float64) - self.pivot
        jacobian = np.hstack([-np.array([[0, -p[2], p[1]], [p[2], 0, -p[0]], [-p[1], p[0], 0]]), np.eye(3)])
        return _worst_sigma(jacobian @ self.covariance @ jacobian.T)

    @property
    def angle_sigma(self) -> float:
        """Radians: the standard deviation of the rotation about its worst axis (0: not known)."""
        return 0.0 if self.covariance is None else _worst_sigma(self.covariance[:3, :3])


def _worst_sigma(covariance: np.ndarray) -> float:
    return float(np.sqrt(max(float(np.linalg.eigvalsh(covariance).max()), 0.0)))


class IcpTarget:
    """A cloud prepared once to register several sources onto (:func:`icp_target`).

    Its normals (``tol.NORMAL_NEIGHBOURS`` neighbours, unoriented: point-to-plane ICP does not read their
    sign) are fitted where a correspondence first asks for them: a segment's points far from any source
    point never are.

    Attributes:
        points: (m, 3) float64 metres, from ``pivot``.
        pivot: (3,) metres, the cloud's centroid: what ICP turns about.
        tree: a ``cKDTree`` of ``points``.
    """

    def __init__(self, points: np.ndarray) -> None:
        from scipy.spatial import cKDTree

        self.pivot = points.mean(axis=0)
        self.points = points - self.pivot
        self.tree = cKDTree(self.points)
        self._normals = np.full_like(self.points, np.nan)

    def normals(self, index: np.ndarray) -> np.ndarray:
        """(k, 3) unit normals of the points ``index`` (k,)."""
        from estimation.neighbours import nearest
        from estimation.normals import patch_axes

        missing = np.unique(index[np.isnan(self._normals[index, 0])])
        if len(missing):
            neighbours = nearest(self.tree, self.points[missing], min(tol.NORMAL_NEIGHBOURS, len(self.points)))[1]
            self._normals[missing] = patch_axes(self.points, neighbours)[1][:, :, 0]
        return self._normals[index]


def icp_target(target: np.ndarray) -> IcpTarget:
    """``target`` ((m, 3) metres) prepared to register onto: centred on its centroid, with a k-d tree.

    Raises:
        CloudError: fewer than 3 points.
    """
    tgt = as_points(target, "target")
    if len(tgt) < 3:
        raise CloudError(f"register: need 3 points on each side, got {len(tgt)} in the target")
    # Solved about the target's centroid, not the world origin: point-to-plane ICP turns about the origin,
    # and a surface that does not pin every turn (a ball, a can about its axis) leaves a turn about its own
    # centre free, which about an origin a metre away is a turn plus a large shift. A 1 cm ball at rest went
    # 0.1 to 9 m off from a start 1 mm off, every other scan.
    return IcpTarget(tgt)


def register(source: np.ndarray, target: np.ndarray | IcpTarget, *, init: np.ndarray, max_distance: float,
             iterations: int = 50, hold: SurfaceMotions | None = None) -> Registration:
    """Point-to-plane ICP moving ``source`` onto ``target``.

    Open3D's ``registration_icp`` with ``TransformationEstimationPointToPlane`` step for step (each
    iteration's update solved from the correspondences within ``max_distance``, as three Euler angles and
    a shift; stopped when fitness and RMSE change by less than 1e-6), in numpy: Open3D sums its normal
    equations across threads in no fixed order, so the same clouds gave a different last bit from run to
    run, and a camera-fed replay was not repeatable. Here they agree with Open3D's to about 1e-15.

    Args:
        source: (n, 3) float64 metres.
        target: (m, 3) float64 metres in the same frame, or an :func:`icp_target` of them (normals and
            tree worked out once for several sources).
        init: (4, 4) float64, the starting motion (the last tracked one).
        max_distance: metres, the largest correspondence distance (a few noise sigmas plus the motion
            expected between two registrations).
        iterations: ICP iterations at most.
        hold: the motions ``source``'s own surface cannot show (:func:`unseen_motions` of it, in its frame):
            they stay as ``init`` has them. Two fits, the better kept (:func:`_better`): one where no
            iteration turns about their axes (:func:`_free_motions`), and one moving freely with its motion
            along them taken away after (:meth:`SurfaceMotions.without`). The second alone let a marker seen
            from one side slide 5-13 degrees about its axis from one scan to the next on the noise, and
            taking that turn away about an axis fitted a few degrees off left a turn of 2-3 degrees across
            it; the first alone can stop in a worse minimum than the second (below).

    Raises:
        CloudError: fewer than 3 points on either side.
    """
    src = as_points(source, "source")
    tgt = target if isinstance(target, IcpTarget) else icp_target(target)
    if len(src) < 3:
        raise CloudError(f"register: need 3 points on each side, got {len(src)} and {len(tgt.points)}")
    pivot = tgt.pivot
    shift, back = np.eye(4), np.eye(4)
    shift[:3, 3], back[:3, 3] = -pivot, pivot
    moving = src - pivot
    init = np.asarray(init, dtype=np.float64)
    start = shift @ init @ back
    held = None if hold is None or not hold.basis.shape[1] else hold
    transform, match = _icp(moving, tgt, start, max_distance, iterations, held)
    if held is not None:
        # A second start of the search: the same ICP moving freely, its motion along ``hold`` then taken
        # away. Held ICP can stop in a worse minimum: on a ring seen by three Kinect-model cameras it
        # stopped at an RMSE of 2.187 mm, a couple of millimetres from the ring's place, where the free
        # fit, its turn about the axis taken away, matched to 2.143 mm 0.5 mm from it.
        loose = _icp(moving, tgt, start, max_distance, iterations, None)[0]
        step = np.linalg.inv(init) @ back @ loose @ shift
        kept = shift @ init @ held.without(step) @ back
        other = _correspondences(moving, tgt, kept, max_distance)
        if _better(other, match):
            transform, match = kept, other
    covariance = None
    if match.found.any():
        information = _information(tgt.points[match.index[match.found]])
        if np.isfinite(information).all() and np.linalg.matrix_rank(information) == 6:
            covariance = match.rmse**2 * np.linalg.inv(information)
    return Registration(back @ transform @ shift, match.fitness, match.rmse, covariance, pivot)


def _icp(moving: np.ndarray, tgt: IcpTarget, transform: np.ndarray, max_distance: float, iterations: int,
         held: SurfaceMotions | None) -> tuple[np.ndarray, _Match]:
    """Point-to-plane iterations from ``transform`` (4, 4, in the target's centred frame) until fitness and
    RMSE settle; none along ``held`` (carried by :func:`_free_motions`) when given."""
    match = _correspondences(moving, tgt, transform, max_distance)
    for _ in range(iterations):
        if not match.found.any():
            break
        free = None if held is None else _free_motions(held, transform)
        update = _point_to_plane_step(match, tgt, free)
        transform = update @ transform
        before, match = match, _correspondences(moving, tgt, transform, max_distance)
        if abs(before.fitness - match.fitness) < ICP_RELATIVE and abs(before.rmse - match.rmse) < ICP_RELATIVE:
            break
    return transform, match


def _better(a: _Match, b: _Match) -> bool:
    """Whether fit ``a`` beats ``b``: more of the source matched (by over :data:`FITNESS_MARGIN`), or about as
    much and closer (a lower RMSE)."""
    if abs(a.fitness - b.fitness) > FITNESS_MARGIN:
        return a.fitness > b.fitness
    return a.rmse < b.rmse


#: Fitnesses (shares of the source matched) this close count as equal when two fits are compared.
FITNESS_MARGIN = 0.01

#: ICP stops when an iteration changes the fitness and the RMSE (metres) by less than this (Open3D's
#: ``ICPConvergenceCriteria`` defaults).
ICP_RELATIVE = 1e-6


@dataclass(frozen=True)
class _Match:
    moved: np.ndarray  # (n, 3) the source, moved, in the target's centred frame
    index: np.ndarray  # (n,) each point's nearest target point (len(target) where none within reach)
    found: np.ndarray  # (n,) bool: a target point within reach
    fitness: float
    rmse: float


def _correspondences(moving: np.ndarray, tgt: IcpTarget, transform: np.ndarray, max_distance: float) -> _Match:
    from estimation.neighbours import PARALLEL_QUERIES

    moved = moving @ transform[:3, :3].T + transform[:3, 3]
    workers = -1 if len(moved) >= PARALLEL_QUERIES else 1
    dist, index = tgt.tree.query(moved, distance_upper_bound=max_distance, workers=workers)
    found = np.isfinite(dist)
    rmse = float(np.sqrt(np.mean(dist[found] ** 2))) if found.any() else 0.0
    return _Match(moved, index, found, float(found.mean()), rmse)


def _free_motions(hold: SurfaceMotions, transform: np.ndarray) -> np.ndarray:
    """(6, 6 - m): the update coordinates (a turn, radians, and a shift, metres) an ICP iteration may move in:
    every shift, and the turns orthogonal to the ``m`` turn axes of ``hold``, carried to where ``transform``
    (4, 4) has the source now. A turn about a held axis through any point is a turn about it through the
    source's centre plus a shift, so the held turn stays as it was wherever the update's turns are taken
    about; a complement taken in the turns and shifts together tied a seen shift across a can's axis to a
    turn about it (about a degree for 2 mm, its points' centroid 13 mm off its axis)."""
    axes = transform[:3, :3] @ hold.basis[:3]
    q = np.linalg.qr(axes, mode="complete")[0]
    free = np.zeros((6, 6 - axes.shape[1]))
    free[:3, :3 - axes.shape[1]] = q[:, axes.shape[1]:]
    free[3:, 3 - axes.shape[1]:] = np.eye(3)
    return free


def _point_to_plane_step(match: _Match, tgt: IcpTarget, free: np.ndarray | None = None) -> np.ndarray:
    """(4, 4): the small motion that best moves the matched points onto their targets' tangent planes,
    linearised in three Euler angles and a shift, the rotation then made exact (Rz Ry Rx, as Open3D); only
    along the columns of ``free`` (6, k) when given (:func:`_free_motions`)."""
    from scipy.spatial.transform import Rotation

    p = match.moved[match.found]
    j = match.index[match.found]
    n = tgt.normals(j)
    jacobian = np.hstack([np.cross(p, n), n])
    residual = np.einsum("ij,ij->i", p - tgt.points[j], n)
    if free is not None:
        jacobian = jacobian @ free
    # A least-squares solve: a surface that pins no turn about some axis (a ball) leaves it at zero.
    x = np.linalg.lstsq(jacobian.T @ jacobian, -jacobian.T @ residual, rcond=None)[0]
    if free is not None:
        x = free @ x
    out = np.eye(4)
    out[:3, :3] = Rotation.from_euler("xyz", x[:3]).as_matrix()  # extrinsic x, y, z: Rz Ry Rx
    out[:3, 3] = x[3:]
    return out


def _information(q: np.ndarray) -> np.ndarray:
    """(6, 6) information matrix of point-to-point correspondences at the target points ``q`` (k, 3), rotation
    first (Open3D's ``get_information_matrix_from_point_clouds``): the sum of G^T G, G = [-[q]x | I]."""
    x, y, z = q[:, 0], q[:, 1], q[:, 2]
    zero, one = np.zeros(len(q)), np.ones(len(q))
    g = np.stack([np.stack([zero, z, -y, one, zero, zero], axis=1),
                  np.stack([-z, zero, x, zero, one, zero], axis=1),
                  np.stack([y, -x, zero, zero, zero, one], axis=1)], axis=1)  # (k, 3, 6)
    return np.einsum("kri,krj->ij", g, g)
