"""From a scene cloud to object clouds: the support plane (RANSAC) and the objects on it (clustering).

Pure numpy/scipy. The plane is found by RANSAC and refined by least squares on its inliers; what lies
above it is clustered by connectivity of occupied voxels (two points are in one object when a chain of
occupied cells at most ``cell`` apart joins them), with the cell taken from the data's own spacing. A
simulator's ground-truth labels can be passed to :func:`check_segments` to count merges and splits; they
never replace the clustering. Where the caller knows several objects are in one cluster (a tracker's
predictions), :func:`split_cluster` parts it at finer cells.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from estimation.contracts import as_points
from estimation.errors import CloudError

log = logging.getLogger(__name__)

#: RANSAC draws: with half the points on the plane, 200 draws miss it with probability 0.875^200 ~ 1e-12.
RANSAC_ITERATIONS = 200

#: Points within this many plane-noise sigmas (RMS of the inliers' distances) of the plane are the plane.
PLANE_SIGMAS = 3.0

#: Clustering cell, in median point spacings: objects closer than ~2 cells merge, so this trades merging
#: touching objects against splitting one object along a sparsely seen strip. 3 spacings bridges the
#: gaps a 1 % dropout and a dropped edge pixel leave.
CLUSTER_SPACINGS = 3.0

#: Clusters with fewer points are noise (a few stray plane points, flying pixels that survived).
MIN_CLUSTER_POINTS = 50

#: Below the cut, down to ``PLANE_SIGMAS`` of the plane's own noise, an object's lowest band is taken back
#: (:func:`segment`): a point there joins the object within ``BAND_SPACINGS`` spacings (or noise sigmas,
#: where more) of it or of a band point that joined it, when at least ``BAND_NEIGHBOURS`` other points above
#: the plane's 3 sigma lie as near. An object's wall goes on through the band (a dozen neighbours at that
#: radius); the table's noise above 3 sigma is 0.13 % of its points, so a stray one far from any object has
#: another that near about once in a hundred.
BAND_SPACINGS = 2.0
BAND_NEIGHBOURS = 3

#: A cluster holds an object when at least this share of its points carry that object's label (check).
LABEL_SHARE = 0.1


@dataclass(frozen=True)
class Plane:
    """``normal . x + offset = 0``; ``normal`` (3,) unit, pointing to the side the sensors are on.

    Attributes:
        normal: (3,) float64 unit vector.
        offset: metres.
        rms: metres, RMS distance of the inliers from the plane (its noise).
        inliers: number of points within the threshold.
    """

    normal: np.ndarray
    offset: float
    rms: float
    inliers: int

    def height(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (n,) of ``points`` (n, 3) metres from the plane, positive on the sensors' side."""
        return points @ self.normal + self.offset

    def clearance(self, threshold: float) -> float:
        """Metres above the plane that clear its points' noise: ``PLANE_SIGMAS`` rms, and at least
        ``threshold`` (the RANSAC distance), where the plane's own noise tail no longer reaches."""
        return max(PLANE_SIGMAS * self.rms, threshold)

    def as_abcd(self) -> tuple[float, float, float, float]:
        """(A, B, C, D) with ``A x + B y + C z + D = 0``, the CLI's convention."""
        return (*(float(v) for v in self.normal), float(self.offset))


def fit_plane(points: np.ndarray, *, threshold: float, toward: np.ndarray, rng: np.random.Generator,
              iterations: int = RANSAC_ITERATIONS) -> Plane:
    """The plane with the most points within ``threshold`` (RANSAC), refined by least squares.

    Args:
        points: (n, 3) float64 metres.
        threshold: inlier distance for the RANSAC vote, metres (about 3 sigma of the sensor noise).
        toward: (3,) metres, same frame: a point on the side the normal should face (a sensor origin).
        rng: randomness for the draws.
        iterations: draws.

    Raises:
        CloudError: fewer than 3 points or no plane with 3 inliers.
    """
    pts = as_points(points, "points")
    if len(pts) < 3:
        raise CloudError(f"fit_plane: need at least 3 points, got {len(pts)}")
    sample = pts[rng.choice(len(pts), size=min(len(pts), 50_000), replace=False)]
    best, best_count = None, 2
    for _ in range(iterations):
        a, b, c = sample[rng.choice(len(sample), 3, replace=False)]
        n = np.cross(b - a, c - a)
        length = np.linalg.norm(n)
        if length == 0:
            continue
        n /= length
        count = int((np.abs((sample - a) @ n) < threshold).sum())
        if count > best_count:
            best, best_count = (n, -float(n @ a)), count
    if best is None:
        raise CloudError("fit_plane: no plane found (all draws degenerate)")
    n, d = best
    for _ in range(2):  # refit on the inliers, then once more on the refit's inliers
        near = pts[np.abs(pts @ n + d) < threshold]
        centre = near.mean(axis=0)
        n = np.linalg.svd(near - centre, full_matrices=False)[2][2]
        d = -float(n @ centre)
    if n @ np.asarray(toward, float) + d < 0:
        n, d = -n, -d
    dist = pts @ n + d
    inl = np.abs(dist) < threshold
    return Plane(n, d, float(np.sqrt(np.mean(dist[inl] ** 2))), int(inl.sum()))


def median_spacing(points: np.ndarray) -> float:
    """Median distance from a point to its nearest neighbour, metres (on at most 20,000 points)."""
    pts = points[:: max(1, len(points) // 20000)]
    d, _ = cKDTree(pts).query(pts, k=2)
    return float(np.median(d[:, 1]))


def cluster(points: np.ndarray, *, cell: float, min_points: int = MIN_CLUSTER_POINTS) -> np.ndarray:
    """Connected components of the occupied voxels of size ``cell`` (26-neighbourhood).

    Args:
        points: (n, 3) float64 metres.
        cell: voxel size, metres.
        min_points: smaller components are labelled -1 (noise).

    Returns:
        (n,) int64 labels, 0..k-1 by decreasing size, -1 for noise.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    pts = as_points(points, "points")
    if len(pts) == 0:
        return np.zeros(0, dtype=np.int64)
    keys = np.floor(pts / cell).astype(np.int64)
    cells, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    pairs = cKDTree(cells.astype(np.float64)).query_pairs(np.sqrt(3.0) + 1e-9, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(cells), len(cells)))
    _, comp = connected_components(graph, directed=False)
    labels = comp[inverse]
    sizes = np.bincount(labels)
    order = np.argsort(-sizes, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    out = rank[labels]
    out[sizes[labels] < min_points] = -1
    return out


#: Finer cells tried on a cluster that several known objects are in (:func:`split_cluster`), as fractions of
#: the clustering cell: down to one median spacing, below which one object falls apart along every dropout
#: and edge (its pieces then go back together by :func:`split_cluster`'s nearest rule, but it splits no
#: better).
SPLIT_FACTORS = (2 / 3, 1 / 2, 1 / CLUSTER_SPACINGS)

#: The pieces the seeds take at a finer cell must hold this share of the cluster's points: below it the cell
#: broke the objects themselves into fragments, and a seed's piece is one of them, not its object.
SPLIT_KEPT = 0.9


def split_cluster(points: np.ndarray, seeds: np.ndarray, cell: float) -> np.ndarray | None:
    """Split one cluster that ``seeds`` say holds several objects: (n,) int seed index per point, or None.

    The cluster is clustered again at finer cells (``SPLIT_FACTORS`` of ``cell``); each seed takes the piece
    most points near it belong to (``_pieces_at``; noise left out). Of the cells at which the pieces taken hold ``SPLIT_KEPT``
    of the points, the coarsest at which the most seeds take pieces of their own wins;
    every point of a piece no seed took (a fragment of an object, noise) goes with the seed of the nearest
    point that is in a taken piece. Seeds that share a piece share it: its points carry the lowest of their
    indices. None when no finer cell parts any two seeds (the objects touch, or one seed is not in it).

    Args:
        points: (n, 3) float64 metres, one cluster.
        seeds: (k, 3) metres, k >= 2: where the objects are known to be (their predicted frame centres).
        cell: the clustering cell that joined them, metres.
    """
    pts = as_points(points, "points")
    seeds = np.asarray(seeds, dtype=np.float64).reshape(-1, 3)
    if len(seeds) < 2 or len(pts) < 2 * MIN_CLUSTER_POINTS:
        return None
    best: tuple[int, np.ndarray, np.ndarray] | None = None
    for factor in SPLIT_FACTORS:
        labels = cluster(pts, cell=factor * cell)
        pieces = np.flatnonzero(labels >= 0)
        if len(pieces) == 0:
            continue
        taken = _pieces_at(pts[pieces], labels[pieces], seeds, cell)
        parts = len(set(taken.tolist()))
        if np.isin(labels, taken).mean() < SPLIT_KEPT:
            continue  # the objects themselves fell apart: a seed's piece is a fragment
        if parts > 1 and (best is None or parts > best[0]):
            best = (parts, labels, taken)
        if parts == len(seeds):
            break
    if best is None:
        return None
    _, labels, taken = best
    owner = np.full(int(labels.max()) + 1, -1, dtype=np.int64)
    for k in range(len(seeds) - 1, -1, -1):  # a piece seeds share goes with the lowest of their indices
        owner[taken[k]] = k
    out = np.where(labels >= 0, owner[np.maximum(labels, 0)], -1)
    claimed = out >= 0
    if not claimed.all():
        near = cKDTree(pts[claimed]).query(pts[~claimed])[1]
        out[~claimed] = out[claimed][near]
    return out


def _pieces_at(points: np.ndarray, labels: np.ndarray, seeds: np.ndarray, patch: float) -> np.ndarray:
    """(k,) the piece each seed takes: the largest piece with a point within ``patch`` (metres) of the
    seed's nearest point's distance. A seed sits inside its object, and at a fine cell the nearest surface
    may hold small fragments of it beside its main piece; a neighbour that near is taken instead, so the
    two stay together (as they were)."""
    tree = cKDTree(points)
    near = tree.query(seeds)[0]
    sizes = np.bincount(labels)
    return np.array([max(set(labels[ball].tolist()), key=lambda k: (sizes[k], -k))
                     for ball in tree.query_ball_point(seeds, near + patch)], dtype=np.int64)


@dataclass(frozen=True)
class Segmentation:
    """A scene cloud split into the support plane and objects.

    Attributes:
        plane: the support plane.
        labels: (n,) int64 per input point: cluster 0..k-1, -1 for the plane, below it and noise.
        cell: clustering cell, metres.
        margin: points less than this above the plane were taken as the plane, metres.
        cut: metres, at least ``margin``: points above it were clustered; an object's points between the
            two (its lowest band, see :func:`segment`) were given to it after.
    """

    plane: Plane
    labels: np.ndarray
    cell: float
    margin: float
    cut: float

    @property
    def count(self) -> int:
        return int(self.labels.max(initial=-1)) + 1


def segment(points: np.ndarray, *, toward: np.ndarray, rng: np.random.Generator,
            plane_threshold: float, cell: float | None = None) -> Segmentation:
    """Remove the support plane and cluster the rest.

    Points more than the RANSAC distance (or 3 sigma of the plane's noise, where more) above the plane are
    clustered; then each cluster takes back its own points between that cut and 3 sigma (its lowest band,
    ``BAND_SPACINGS``), leaving the table's stray noise there to the plane.

    Args:
        points: (n, 3) float64 metres, the scene (cropped to the workspace), world frame.
        toward: (3,) metres: a sensor origin (the plane's normal faces it).
        rng: randomness for RANSAC.
        plane_threshold: RANSAC inlier distance, metres.
        cell: clustering cell, metres; None: ``CLUSTER_SPACINGS`` median spacings of the points.

    Raises:
        CloudError: too few points for a plane.
    """
    pts = as_points(points, "points")
    plane = fit_plane(pts, threshold=plane_threshold, toward=toward, rng=rng)
    height = plane.height(pts)
    cut = plane.clearance(plane_threshold)
    above = height > cut
    spacing = median_spacing(pts[above]) if above.sum() > 2 else plane_threshold / CLUSTER_SPACINGS
    if cell is None:
        cell = CLUSTER_SPACINGS * spacing
    labels = np.full(len(pts), -1, dtype=np.int64)
    labels[above] = cluster(pts[above], cell=cell)
    # The cut clears the table's noise with room to spare (the RANSAC distance), and so takes the lowest
    # millimetres off every object with it: a 14 mm ring kept too little of its lower half to show it is its
    # own mirror image. Clustering everything above the plane's 3 sigma brought the table's stray noise into
    # the objects (a lying marker -12 % in bench/cameras.py): a point of that band joins an object only
    # next to it and among enough others (``BAND_NEIGHBOURS``).
    margin = min(cut, PLANE_SIGMAS * plane.rms)
    band = np.flatnonzero((height > margin) & ~above)
    if len(band):
        # Spacings as their nearest-neighbour distance, or the noise where the shell is thicker than that.
        radius = BAND_SPACINGS * max(spacing, plane.rms)
        lifted = cKDTree(pts[height > margin])
        crowd = lifted.query_ball_point(pts[band], radius, return_length=True, workers=-1) - 1
        band = band[crowd >= BAND_NEIGHBOURS]
    # Down the band from the clustered points, a radius at a time.
    edge = np.flatnonzero(labels >= 0)
    while len(band) and len(edge):
        near, nearest = cKDTree(pts[edge]).query(pts[band], distance_upper_bound=radius, workers=-1)
        joined = np.isfinite(near)
        if not joined.any():
            break
        labels[band[joined]] = labels[edge[nearest[joined]]]
        edge, band = band[joined], band[~joined]
    return Segmentation(plane, labels, float(cell), float(margin), float(cut))


@dataclass(frozen=True)
class SegmentCheck:
    """Clusters against ground-truth labels.

    Attributes:
        found: true labels that are the majority of exactly one cluster.
        merged: clusters holding two or more true labels (each at least ``LABEL_SHARE`` of it).
        split: true labels spread over two or more clusters (each holding it as a real share).
        missed: true labels in no cluster.
    """

    found: tuple[int, ...]
    merged: tuple[int, ...]
    split: tuple[int, ...]
    missed: tuple[int, ...]


def check_segments(labels: np.ndarray, truth: np.ndarray, expected: list[int] | tuple[int, ...]) -> SegmentCheck:
    """Count merges and splits of a clustering against the true label of every point.

    Args:
        labels: (n,) int clusters (-1: not an object).
        truth: (n,) int true labels (e.g. geom ids from the simulator's segmentation image).
        expected: the true labels that are objects.
    """
    labels, truth = np.asarray(labels), np.asarray(truth)
    holders: dict[int, list[int]] = {t: [] for t in expected}
    merged = []
    for c in range(int(labels.max(initial=-1)) + 1):
        mine = truth[labels == c]
        if len(mine) == 0:
            continue
        values, counts = np.unique(mine, return_counts=True)
        members = [int(v) for v, k in zip(values, counts, strict=True) if v in holders and k >= LABEL_SHARE * len(mine)]
        for v in members:
            holders[v].append(c)
        if len(members) > 1:
            merged.append(c)
    split = [t for t, cs in holders.items() if len(cs) > 1]
    missed = [t for t, cs in holders.items() if not cs]
    found = [t for t, cs in holders.items() if len(cs) == 1]
    return SegmentCheck(tuple(found), tuple(merged), tuple(split), tuple(missed))
