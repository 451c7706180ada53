"""What a cloud can resolve: its point spacing and its noise, both measured from the points.

The reconstruction cell follows from these two numbers instead of a constant: finer than the spacing
leaves cells without points, finer than the noise turns noise into surface.
"""

from __future__ import annotations

import numpy as np

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
    if tree is None and len(points) > SPACING_SUBSET:
        # A uniform subset of m of the n points is spaced sqrt(n / m) times wider; building its tree
        # instead of the full one is what makes this cheap on a million points.
        step = -(-len(points) // SPACING_SUBSET)  # ceil: the subset holds at most SPACING_SUBSET points
        subset = points[::step]
        return point_spacing(subset) * float(np.sqrt(len(subset) / len(points)))
    tree = _sample_tree(points) if tree is None else tree
    k = min(SPACING_NEIGHBOURS, len(points) - 1)
    sample = points[:: max(1, len(points) // SAMPLE)]
    dist = tree.query(sample, k=k + 1, workers=-1)[0]
    if (dist[:, 1] == 0).any():
        # Repeated positions (a quantised sensor, rounded coordinates): a copy is no neighbour on the
        # surface, and a position repeated k times reads a spacing of 0. Measure over distinct points.
        from estimation.cloud import distinct_rows

        distinct = points[distinct_rows(points)]
        if len(distinct) < len(points):
            return point_spacing(distinct)
    return float(np.sqrt(np.pi / k) * np.median(dist[:, -1]))


def surface_noise(points: np.ndarray, tree=None) -> float:  # type: ignore[no-untyped-def]
    """Standard deviation (metres) of the points about their local tangent planes: sensor noise.

    The median over a sample of the plane-fit residual of each point's neighbours (the smallest
    principal spread), corrected for the fit's degrees of freedom. Creases and curvature add to a
    minority of neighbourhoods, which the median ignores. A neighbourhood no wider than the noise
    slab is cut by it and reads low, so the patch is widened (on a thinned reference set, to keep the
    neighbour count bounded) until it spans ``NOISE_PATCH_SIGMAS`` of the estimate.

    Args:
        points: (n, 3) float64, metres, as dense as they come (see ``NOISE_SUBSET``). tree: unused
            (kept for symmetry with ``point_spacing``).
    """
    if len(points) > NOISE_SUBSET:
        points = points[:: -(-len(points) // NOISE_SUBSET)]
    sample = points[:: max(1, len(points) // SAMPLE)]
    # First a small patch (a few spacings): it reads noise low, but cannot reach the other face of a
    # wall a few spacings thick, which a wide patch would read as noise. Only when noise already
    # shows there is the patch widened to measure it properly.
    tree = _sample_tree(points)
    k = min(NOISE_FIRST_NEIGHBOURS, len(points))
    dist, nbr = nearest(tree, sample, k)
    local = points[nbr] - points[nbr].mean(axis=1, keepdims=True)
    smallest = np.maximum(np.linalg.eigvalsh(np.einsum("nki,nkj->nij", local, local))[:, 0], 0.0)
    sigma = float(np.sqrt(np.median(smallest) / max(k - 3, 1)))
    spacing = float(np.sqrt(np.pi / k) * np.median(dist[:, -1]))
    if sigma < NOISE_VISIBLE_SPACINGS * spacing:
        return sigma
    reference, k = points, min(NOISE_NEIGHBOURS, len(points))
    for _ in range(NOISE_ITERATIONS):
        tree = _sample_tree(reference)
        dist, nbr = nearest(tree, sample, k)
        local = reference[nbr] - reference[nbr].mean(axis=1, keepdims=True)
        smallest = np.maximum(np.linalg.eigvalsh(np.einsum("nki,nkj->nij", local, local))[:, 0], 0.0)
        sigma = float(np.sqrt(np.median(smallest) / max(k - 3, 1)))
        radius = float(np.median(dist[:, -1]))
        if radius >= NOISE_PATCH_SIGMAS * sigma:
            break
        # Thin the reference so that k neighbours reach NOISE_PATCH_SIGMAS sigma.
        keep = max(k + 1, int(len(reference) * (radius / (NOISE_PATCH_SIGMAS * sigma)) ** 2))
        reference = reference[np.linspace(0, len(reference) - 1, keep).astype(np.int64)]
    return sigma


def _sample_tree(points: np.ndarray):  # type: ignore[no-untyped-def]
    """A ``cKDTree`` for the few thousand queries of a statistic: built unbalanced and without shrinking
    its nodes, ~2x faster to build on 100k points, which is most of the cost when only SAMPLE points
    are looked up (a tree for queries from every point is worth balancing)."""
    from scipy.spatial import cKDTree

    return cKDTree(points, balanced_tree=False, compact_nodes=False)
