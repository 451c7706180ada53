"""What a cloud can resolve: its point spacing and its noise, both measured from the points.

The reconstruction cell follows from these two numbers instead of a constant: finer than the spacing
leaves cells without points, finer than the noise turns noise into surface.
"""

from __future__ import annotations

import math

import numpy as np

from estimation import tolerances as tol
from estimation.neighbours import nearest

#: Points sampled for the statistics: medians over 5000 are stable to about 1 %.
SAMPLE = 5000

#: Neighbours for the spacing: the 8th neighbour's distance is well past the nearest-neighbour
#: randomness of a random sample and still local.
SPACING_NEIGHBOURS = 8

#: Largest cloud whose spacing is measured on all its points; larger ones on a uniform subset (the
#: tree over 250k points cost 0.12 s of CPU on a 1M-point cloud, the one over 60k ~20 ms; a subset
#: spaced wider than a thin wall reads the spacing low, which only makes the voxel finer).
SPACING_SUBSET = 60_000

#: Largest cloud whose noise is measured on all its points; larger ones on a uniform subset. Noise is
#: a property of each point, so a subset reads the same sigma, but it must stay dense: the small first
#: patch must not reach a thin wall's other face (the 100k-point clouds the thresholds below were set
#: on), and measured after thinning to the point budget a 2.3 mm cup wall read as 1 mm of noise.
NOISE_SUBSET = 100_000

#: Neighbours for the noise: a patch several sigma wide, or the ball around a noisy point cuts the
#: noise slab and the plane fit follows the noise (24 neighbours read 0.3-0.45 mm for 0.5 mm).
NOISE_NEIGHBOURS = 64

#: Neighbours of the first, small noise patch.
NOISE_FIRST_NEIGHBOURS = 24

#: Nearest points of the first patch that place the sample's own face: closer than a wall two spacings thick.
NOISE_OWN_NEIGHBOURS = 8

#: The first sheet cut from those points' plane starts from their spread divided by this (``_first_sheet``):
#: the passes converge from a third of the truth (``SHEET_ITERATIONS``).
NOISE_START_BELOW = 3.0

#: Noise the small patch reads below this fraction of the spacing is left as read: it is too small
#: to set the cell (FINE_CELL_NOISE x 0.1 spacing is under the spacing), and widening the patch
#: would risk reading a thin wall's other face as noise.
NOISE_VISIBLE_SPACINGS = 0.1

#: The noise patch must be this many sigma in radius (the slab it samples is +-2 sigma thick).
NOISE_PATCH_SIGMAS = 5.0

#: Widening steps for the noise patch (the second is already within a few % of the truth).
NOISE_ITERATIONS = 3


def point_spacing(points: np.ndarray, tree=None) -> float:  # type: ignore[no-untyped-def]
    """Typical distance between neighbouring surface points, metres: the square root of area per point.

    ``k`` neighbours within ``r`` cover ``pi r^2`` of surface, so ``sqrt(pi / k) * r_k`` (median
    over a sample).

    Args:
        points: (n, 3) float64, metres. tree: a ``cKDTree`` over ``points`` (built when None).
    """
    local = local_spacings(points, tree)
    return float(np.median(local)) if len(local) else 0.0


def sparse_spacing(points: np.ndarray, share: float) -> float:
    """The spacing the sparsest ``share`` (0-1) of the surface's area is sampled at, metres: the
    :func:`local_spacings` quantile weighted by the area each point stands for (its spacing squared).

    A cloud sampled evenly reads about 1.3 times :func:`point_spacing` at a share of 0.1; one whose half
    is sampled 30 times less densely (a side a scanner saw from afar), 6.5 times.
    """
    local = local_spacings(points)
    return _area_quantile(local, local**2, 1.0 - share) if len(local) else 0.0


def _area_quantile(values: np.ndarray, areas: np.ndarray, q: float) -> float:
    """The ``q`` (0-1) quantile of ``values`` ((n,), n > 0) weighted by the ``areas`` ((n,)) their points stand for."""
    order = np.argsort(values, kind="stable")
    cumulative = np.cumsum(areas[order])
    return float(values[order][min(int(np.searchsorted(cumulative, q * cumulative[-1])), len(values) - 1)])


#: Each widening step of :func:`line_gap` thins by voxels this many times wider than the last. Under the noise a
#: patch is a blob, and once it reaches the next line it is flat: a line's patches are collinear only in between,
#: a window a factor of about two wide at lines 2 mm apart with 0.2 mm of noise, which doubling could step over.
LINE_WIDENING = math.sqrt(2.0)

#: Most widening steps (to 16 times the spacing): past that a patch spans a fair share of a small object.
LINE_WIDENINGS = 8

#: A patch is still inside the noise while its smallest principal variance is over this share of its largest:
#: widen it. A clean surface's 8-point patches read under 0.001; a sphere sampled evenly at sigma 0.5 mm 0.17 at
#: its spacing, 0.04 at four times it; lines with 0.2 mm of noise 0.03-0.14 at 0.1-0.3 mm along them.
LINE_NOISE_SHARE = 0.05

#: Neighbours searched for the nearest point of another line: its own line's points come first, this many
#: reach ten times the thinned spacing along it either side.
LINE_REACH = 32

#: A neighbour lies on another line when it is farther from the sample's line than along it, and farther than
#: this many times the lines' own spread across them (their noise, sigma): two points of one noisy line lie that far
#: apart across it once in 500 (exp(-25 / 4)).
LINE_ACROSS_SPREADS = 5.0


def line_gap(points: np.ndarray) -> float:
    """The gap between neighbouring lines of a cloud sampled along lines, metres; 0.0 where it is not.

    A laser line scanner samples a surface in slices a few millimetres apart with points a few tenths of a
    millimetre apart along each (so, at a grazing angle, does a depth camera's pixel grid). The spacing
    (:func:`point_spacing`, from the 8th neighbour) is then measured along the lines, and the gaps between them
    are holes several cells wide. Here the points are thinned by voxels of growing size (``LINE_WIDENING``,
    from the spacing) until the patches of their ``SPACING_NEIGHBOURS`` nearest are past the noise
    (``LINE_NOISE_SHARE``); where the patches are then collinear (their second principal variance under
    ``tolerances.LINE_FLATNESS`` of their first, the median over a sample), each sample's gap is its distance
    to the nearest point off its line (``LINE_ACROSS_SPREADS``, within ``LINE_REACH`` neighbours: farther, the
    points are thinned more), and the gap returned is their median weighted by the area each point stands for
    (proportional to its gap: the sparse parts count as much as the dense ones). A surface sampled evenly, or
    in rows too close to tell apart (a 1 x 4 mm grid with 0.1 mm of noise), gives 0.0 at the first scale past
    its noise: after one patch search on a clean cloud (30-60 ms from 20k to 1M points), a few on a noisy one
    (up to 0.25 s at sigma 1 mm).

    Args:
        points: (n, 3) float64, metres; larger clouds than ``SPACING_SUBSET`` are measured on the points in a
            share of the space (``_in_blocks``).

    Returns:
        Metres: the area-weighted median distance from a point to the nearest point of a neighbouring line,
        or 0.0.
    """
    from estimation.downsample import voxel_subsample

    if len(points) > SPACING_SUBSET:
        points = points[_in_blocks(points, SPACING_SUBSET)]
    reference, tree, voxel = points, query_tree(points), 0.0
    for widening in range(LINE_WIDENINGS + 1):
        if widening:
            reference = points[voxel_subsample(points, voxel * LINE_WIDENING**widening)]
            tree = query_tree(reference)
        if len(reference) <= LINE_REACH:
            return 0.0
        sample = reference[:: max(1, len(reference) // SAMPLE)]
        dist, index = nearest(tree, sample, SPACING_NEIGHBOURS + 1)
        if not widening:  # the spacing, as point_spacing reads it
            voxel = math.sqrt(math.pi / SPACING_NEIGHBOURS) * float(np.median(dist[:, -1]))
            if not voxel > 0:
                return 0.0  # most points repeated: no lines to tell
        patch = reference[index]
        spread = patch - patch.mean(axis=1, keepdims=True)
        values, vectors = np.linalg.eigh(np.einsum("nki,nkj->nij", spread, spread))  # ascending
        largest = np.maximum(values[:, 2], np.finfo(float).tiny)
        if float(np.median(values[:, 1] / largest)) >= tol.LINE_FLATNESS:
            if float(np.median(np.maximum(values[:, 0], 0.0) / largest)) <= LINE_NOISE_SHARE:
                return 0.0  # two-dimensional past the noise: a surface
            continue  # a blob inside the noise: widen
        gap = _next_line(reference, tree, sample, vectors[:, :, 2], float(np.median(values[:, 1])) / len(patch[0]))
        if gap > 0:
            return gap
    return 0.0


#: :func:`line_gap` measures a large cloud on the points in about this many blocks, a share of all: a uniform
#: subset thins the lines too (75k points on lines 1 mm apart, 0.2 mm along, cut to every second point: an 8-point
#: patch reaches the next line, and no scale is collinear).
LINE_BLOCKS = 16


def _in_blocks(points: np.ndarray, count: int) -> np.ndarray:
    """Ascending indices of about ``count`` of ``points`` ((n, 3) metres): those in a share of the cubes of a grid
    (each holding about ``count / LINE_BLOCKS`` of them), chosen by a hash of the cube, so that the points kept
    are as dense as they came; a uniform subset where that keeps too few (a cloud in a handful of cubes)."""
    from estimation.obb import column_bounds

    low, high = column_bounds(points)
    a, b, c = np.maximum(high - low, np.finfo(float).tiny)
    # The surface is about its bounding box's (a ball's is half that): blocks of a share of it hold the share.
    side = math.sqrt(2 * (a * b + b * c + c * a) * count / (LINE_BLOCKS * len(points)))
    dims = ((high - low) / max(side, np.finfo(float).tiny)).astype(np.uint64) + np.uint64(1)
    cube = ((points - low) * (1.0 / side)).astype(np.uint64)
    linear = (cube[:, 0] * dims[1] + cube[:, 1]) * dims[2] + cube[:, 2]
    # Fibonacci hashing: the top 24 bits of the cube's number times 2^64 / golden ratio (wrapping) are spread
    # evenly whatever the cubes' numbering.
    share = (linear * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(40)
    keep = np.flatnonzero(share < np.uint64(int(count / len(points) * 2**24)))
    if len(keep) < count // 4:
        return np.arange(0, len(points), -(-len(points) // count))
    return keep


def _next_line(reference: np.ndarray, tree, sample: np.ndarray, direction: np.ndarray,  # type: ignore[no-untyped-def]
               variance: float) -> float:
    """:func:`line_gap` at one scale: each of ``sample`` ((s, 3) metres, on lines along ``direction``, (s, 3) unit)
    to the nearest of ``reference`` ((m, 3) metres, in ``tree``) off its line, where the lines' points spread by
    ``variance`` (m^2) across them; the area-weighted median, or 0.0 when most samples find none within
    ``LINE_REACH`` neighbours (a sample that finds none counts at its reach, a lower bound)."""
    dist, index = nearest(tree, sample, min(LINE_REACH + 1, len(reference)))
    offset = reference[index[:, 1:]] - sample[:, None, :]
    along = np.abs(np.einsum("nki,ni->nk", offset, direction))
    across = np.sqrt(np.maximum(dist[:, 1:] ** 2 - along**2, 0.0))
    off = (across > along) & (across > LINE_ACROSS_SPREADS * np.sqrt(variance))
    found = off.any(axis=1)
    if found.mean() < 0.5:
        return 0.0
    gaps = np.where(found, np.where(off, dist[:, 1:], np.inf).min(axis=1), dist[:, -1])
    return _area_quantile(gaps, gaps, 0.5)


def local_spacings(points: np.ndarray, tree=None) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Each sampled point's spacing, metres (``SAMPLE`` of them, spread by index): ``sqrt(pi / k) r_k`` with
    ``r_k`` the distance to its ``k``-th neighbour (see :func:`point_spacing`); empty for fewer than 2 points.

    Args:
        points: (n, 3) float64, metres. tree: a ``cKDTree`` over ``points`` (built when None).
    """
    if len(points) < 2:
        return np.zeros(0)  # one distinct position: no neighbour to be spaced from (check_estimable says so)
    if tree is None and len(points) > SPACING_SUBSET:
        # A uniform subset of m of the n points is spaced sqrt(n / m) times wider; building its tree
        # instead of the full one is what makes this cheap on a million points.
        step = -(-len(points) // SPACING_SUBSET)  # ceil: the subset holds at most SPACING_SUBSET points
        subset = points[::step]
        return local_spacings(subset) * float(np.sqrt(len(subset) / len(points)))
    tree = query_tree(points) if tree is None else tree
    k = min(SPACING_NEIGHBOURS, len(points) - 1)
    sample = points[:: max(1, len(points) // SAMPLE)]
    dist = tree.query(sample, k=k + 1, workers=-1)[0]
    if (dist[:, 1] == 0).any():
        # Repeated positions (a quantised sensor, rounded coordinates): a copy is no neighbour on the
        # surface, and a position repeated k times reads a spacing of 0. Measure over distinct points.
        from estimation.cloud import distinct_rows

        distinct = points[distinct_rows(points)]
        if len(distinct) < len(points):
            return local_spacings(distinct)
    return np.sqrt(np.pi / k) * dist[:, -1]


def surface_noise(points: np.ndarray, tree=None, *, own_sheet: bool = False) -> float:  # type: ignore[no-untyped-def]
    """Standard deviation (metres) of the points about their local tangent planes: sensor noise.

    The median over a sample of the plane-fit residual of each point's neighbours (the smallest
    principal spread), corrected for the fit's degrees of freedom. Creases and curvature add to a
    minority of neighbourhoods, which the median ignores. A neighbourhood no wider than the noise
    slab is cut by it and reads low, so the patch is widened (on a thinned reference set, to keep the
    neighbour count bounded) until it spans ``NOISE_PATCH_SIGMAS`` of the estimate.

    Args:
        points: (n, 3) float64, metres, as dense as they come (see ``NOISE_SUBSET``). tree: unused
            (kept for symmetry with ``point_spacing``).
        own_sheet: also start from each sample's own face (below), for clouds whose normals the flood fill
            will orient: there a wall read as noise hides the wall from it (the pipe above came out solid,
            +180 %). Sensed clouds keep the plain reading: the camera tables' sparse fused views lost with the
            lower one (pooled medians at 3, 2 and 1 cameras 2.0, 3.1, 5.5 -> 2.2, 4.0, 6.2 %), where the
            wider reading smooths.
    """
    if len(points) > NOISE_SUBSET:
        points = points[:: -(-len(points) // NOISE_SUBSET)]
    sample = points[:: max(1, len(points) // SAMPLE)]
    # First a small patch (a few spacings): it reads noise low, but cannot reach the other face of a
    # wall a few spacings thick, which a wide patch would read as noise. Only when noise already
    # shows there is the patch widened to measure it properly.
    tree = query_tree(points)
    k = min(NOISE_FIRST_NEIGHBOURS, len(points))
    dist, nbr = nearest(tree, sample, k)
    patches = points[nbr]
    centre = patches.mean(axis=1)
    local = patches - centre[:, None, :]
    values, vectors = np.linalg.eigh(np.einsum("nki,nkj->nij", local, local))
    radius = float(np.median(dist[:, -1]))
    spacing = float(np.sqrt(np.pi / k)) * radius
    plain = float(np.sqrt(np.median(np.maximum(values[:, 0], 0.0)) / max(k - 3, 1)))
    if plain < NOISE_VISIBLE_SPACINGS * spacing:
        return plain  # too little noise to matter, even with a wall's other face in some patches
    # The sheet through each sample: the small patch's plane, moved to its median offset, with a first sigma
    # from the offsets' median absolute deviation. That plane is tilted by the other face of a wall a few
    # spacings thick (a 3 mm pipe wall at 1.4 mm spacing: a tenth of the fits more than 60 degrees off), and
    # the gap is read as noise (1.5 mm on a clean pipe). With ``own_sheet`` the plane of the sample's nearest
    # few points is tried too, which keeps to its own face there; the smaller reading wins (from either, one
    # sheet reads its own sigma), and the wide patches below are cut about its refitted planes: the few
    # points' first plane follows noise that is most of a spacing (a closed 3 mm box at sigma 0.5 mm, 0.8 mm
    # spacing: 1.56 mm read about it).
    readings = [_first_sheet(patches, centre, vectors[:, :, 0], 1.0, refit=own_sheet)]
    if own_sheet:
        own = patches[:, :NOISE_OWN_NEIGHBOURS]
        own_centre = own.mean(axis=1)
        own_spread = own - own_centre[:, None, :]
        own_normal = np.linalg.eigh(np.einsum("nki,nkj->nij", own_spread, own_spread))[1][:, :, 0]
        readings.append(_first_sheet(patches, own_centre, own_normal, NOISE_START_BELOW, refit=True))
    sigma, centre, normal = min(readings, key=lambda reading: reading[0])
    if sigma < NOISE_VISIBLE_SPACINGS * spacing or radius >= NOISE_PATCH_SIGMAS * sigma:
        # Too little noise to matter, or the small patch already spans the slab: widening it would only
        # reach the other face of a thin wall (a 3 mm hollow ball at sigma 0.1 mm read 1.5 mm, and came
        # out solid).
        return sigma
    # Each wide patch is cut down to the sample's own sheet, about the small patch's plane: the other
    # face of a wall a few spacings thick is in it too, and read as noise (sigma 0.5 mm on that ball: 1.56).
    reference, k = points, min(NOISE_NEIGHBOURS, len(points))
    for _ in range(NOISE_ITERATIONS):
        tree = query_tree(reference)
        dist, nbr = nearest(tree, sample, k)
        sigma = _sheet_sigma(reference[nbr], centre, normal, sigma)
        radius = float(np.median(dist[:, -1]))
        if radius >= NOISE_PATCH_SIGMAS * sigma:
            break
        # Thin the reference so that k neighbours reach NOISE_PATCH_SIGMAS sigma.
        keep = max(k + 1, int(len(reference) * (radius / (NOISE_PATCH_SIGMAS * sigma)) ** 2))
        reference = reference[np.linspace(0, len(reference) - 1, keep).astype(np.int64)]
    return sigma


def _first_sheet(patches: np.ndarray, centre: np.ndarray, normal: np.ndarray, below: float, *,
                 refit: bool) -> tuple[float, np.ndarray, np.ndarray]:
    """(sigma metres, centre (n, 3), normal (n, 3)) of (n, k, 3) patches about first planes through ``centre``
    along ``normal``: each moved to its patch's median offset, the sheet cut started from the offsets' median
    absolute deviation divided by ``below`` (a plane tilted by the noise overstates it, and a band that starts
    wide takes in a wall's other face and never lets go; from below, the passes converge up to the sheet's own
    sigma, ``SHEET_ITERATIONS``). The planes returned are the cut's last fits with ``refit``, else the first."""
    offset = np.einsum("nki,ni->nk", patches - centre[:, None, :], normal)
    middle = np.median(offset, axis=1)
    centre = centre + normal * middle[:, None]
    spread = float(np.median(np.median(np.abs(offset - middle[:, None]), axis=1))) * MAD_TO_SIGMA
    sigma, fitted_centre, fitted_normal = _sheet(patches, centre, normal, spread / below)
    return (sigma, fitted_centre, fitted_normal) if refit else (sigma, centre, normal)


#: A wide patch keeps the points within this many noise sigmas of the sample's own sheet (a Gaussian keeps
#: all but 0.05 %; a wall's other face six sigmas away keeps the tail of its own noise beyond 2.5 sigma).
SHEET_SIGMAS = 3.5

#: A Gaussian's median absolute deviation times this is its sigma.
MAD_TO_SIGMA = 1.4826

#: Passes of the sheet cut: each sets the band from the last estimate. From a first estimate a third of the
#: truth (a small patch deep in the noise), the third pass is within 0.5 % of it.
SHEET_ITERATIONS = 4

#: ...stopping early once a pass moves the estimate by less than this share of it.
SHEET_SETTLED = 0.005


def _sheet_sigma(patches: np.ndarray, centre: np.ndarray, normal: np.ndarray, sigma: float) -> float:
    """Noise sigma (metres) of (n, k, 3) patches about their sheets (``_sheet``)."""
    return _sheet(patches, centre, normal, sigma)[0]


def _sheet(patches: np.ndarray, centre: np.ndarray, normal: np.ndarray,
           sigma: float) -> tuple[float, np.ndarray, np.ndarray]:
    """Noise sigma (metres) of (n, k, 3) patches, each cut to the points within ``SHEET_SIGMAS`` sigma of its
    sheet, the plane through ``centre`` (n, 3) along ``normal`` (n, 3) at first and its own fit after; the
    band follows the estimate, starting from ``sigma``. A Gaussian cut at c sigma keeps
    ``1 - 2 c phi(c) / (2 Phi(c) - 1)`` of its variance; the estimate is divided by that. Also the sheets'
    last planes (centre, normal), kept as given where a band held too few points to fit one."""
    c = SHEET_SIGMAS
    kept_variance = 1 - 2 * c * np.exp(-c * c / 2) / np.sqrt(2 * np.pi) / math.erf(c / np.sqrt(2))
    for _ in range(SHEET_ITERATIONS):
        offset = np.einsum("nki,ni->nk", patches - centre[:, None, :], normal)
        keep = np.abs(offset) <= (c * sigma if sigma > 0 else np.inf)  # no spread yet (exact points): keep all
        count = keep.sum(axis=1)
        w = keep[:, :, None]
        mean = (patches * w).sum(axis=1) / np.maximum(count, 1)[:, None]
        local = (patches - mean[:, None, :]) * w
        values, vectors = np.linalg.eigh(np.einsum("nki,nkj->nij", local, local))
        smallest = np.maximum(values[:, 0], 0.0) / np.maximum(count - 3, 1)
        last, sigma = sigma, float(np.sqrt(np.median(smallest[count > 3]) / kept_variance)) if (count > 3).any() else sigma
        fitted = (count > 3)[:, None]
        centre, normal = np.where(fitted, mean, centre), np.where(fitted, vectors[:, :, 0], normal)
        if abs(sigma - last) <= SHEET_SETTLED * sigma or (sigma == 0 and fitted.any()):
            # 0 measured is exact points on their sheets, not "no spread yet": keeping all in the next pass took
            # in a wall's other face (a clean 2 mm ruler at 1 mm spacing read 0.98 mm of noise and came out 3.3x).
            break
    return sigma, centre, normal


def query_tree(points: np.ndarray):  # type: ignore[no-untyped-def]
    """A ``cKDTree`` for a few thousand queries (a statistic's sample, the flood fill's border nodes in
    ``implicit._air_pockets``): built unbalanced and without shrinking
    its nodes, ~2x faster to build on 100k points, which is most of the cost when only SAMPLE points
    are looked up (a tree for queries from every point is worth balancing)."""
    from scipy.spatial import cKDTree

    return cKDTree(points, balanced_tree=False, compact_nodes=False)
