"""Normals: estimate them from the points, and orient them out of the object.

The paper's surface failed because normals were estimated without a viewpoint and pointed the wrong way.
We orient each normal by looking, along it, at the flood-filled outside (``grid.occupancy``): the side
where the outside is nearer is out. An optional viewpoint is used instead where given (single-view scans).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from estimation import tolerances as tol
from estimation.grid import Grid, Occupancy
from estimation.neighbours import nearest

#: How far (cells) beyond the shell's closing radius we look for the outside on either side of a point.
PROBE_CELLS = 1.0

#: How far (cells) the probe looks when the shell encloses nothing (``orient_outward``).
NEAR_PROBE_CELLS = 0.5

#: Blur (cells) of the outside indicator: turns the 0/1 mask into a ramp we can compare on both sides.
OUTSIDE_BLUR_CELLS = 1.5

#: Below this difference of blurred outside-ness the probe cannot tell (thin walls with outside on both
#: sides); such normals take their confident neighbours' side.
CONFIDENT_DIFFERENCE = 0.05


#: Edges between points the outside probe cannot read carry a sign only along one sheet (``on_one_sheet``): each
#: point's sheet is placed by the centroid of this many nearest points, whose noise is sigma / sqrt(32) = 0.18
#: sigma; two such centroids on one sheet lie well within SHEET_GAP_SIGMAS of each other along the normal (99.9 %
#: of one sheet's edges on bench/thin_parts.py's noisy heatsink), while half a wall thick enough to resolve under
#: the noise (6 sigmas: issue 12's 3 mm at 0.5 mm) is 3 sigmas.
OWN_SHEET_CENTROID = 32
SHEET_GAP_SIGMAS = 2.0

#: Neighbours looked at for a wall's other face: enough to reach ~3 spacings, where a wall two or
#: three spacings thick has its other face.
THIN_WALL_NEIGHBOURS = 32

#: The nearest neighbours that place a point's own sheet (closer than a wall two spacings thick).
OWN_SHEET_NEIGHBOURS = 8

#: A wide normal patch is fitted again on the points within this many noise sigmas of its main sheet
#: (``_refit_own_sheet``): 3.5 sigma keeps all but ~0.05 % of that sheet's noise.
OWN_SHEET_SIGMAS = 3.5

#: Neighbours whose unoriented normals are within ~25 degrees of the point's count as sheets parallel
#: to it (the same face, or the wall's other face); crossing faces at a crease do not.
PARALLEL_COSINE = 0.9

#: The other face's pull on the mean offset must be this many standard errors from zero...
THIN_WALL_T = 6.0

#: ...and at least this fraction of the neighbourhood radius (curvature alone gives ~1/10 of it at a
#: radius of curvature of ~5 neighbourhood radii; a wall face holding a third of the neighbours at one
#: radius gives ~1/3).
THIN_WALL_OFFSET = 0.2

#: ...and at least this many noise sigmas: a noisy sheet averaged into cells can split into two
#: layers about a sigma apart, which must not read as a wall (walls under ~6 sigma are not resolvable).
THIN_WALL_NOISE = 2.0


#: Points per block when normals are fitted: bounds the (block, k, 3) gather to ~10-70 MB.
NORMAL_BLOCK = 30_000


#: Given normals (``orient_given``): the sample looked at, the neighbours on a point's sheet, and how parallel
#: (cosine) and how nearly in the point's tangent plane (offset along the normal over distance) a neighbour
#: must be to count as on it. Across a crease sharper than ~18 degrees or to a wall's other face, it is not.
GIVEN_SAMPLE, GIVEN_NEIGHBOURS = 2000, 8
SHEET_COSINE, SHEET_OFFSET = 0.95, 0.3

#: Given normals are repaired when more than this share of the sample points against their own sheet, or
#: when more than half of those the probe can read point in. On the 60 shapes and parts of
#: ``bench/given_normals.py`` the check acted on none of the outward clouds (nor the 48 noisy ones) and on all
#: of the inward, unoriented and a-tenth-flipped ones.
GIVEN_AGAINST_SHEET = 0.01
GIVEN_INWARD = 0.5

#: A re-signed sheet's side: the probe decides it with at least this many reads, this share of them one
#: way; as many unanimous thin-wall reads (``thin_wall_side``) overrule it.
MIN_SHEET_VOTES, SHEET_DECISIVE = 10, 0.75


def estimate_normals(points: np.ndarray, k: int = tol.NORMAL_NEIGHBOURS, *,
                     neighbours: np.ndarray | None = None) -> np.ndarray:
    """Unoriented unit normals (n, 3): smallest principal direction of each point's ``k`` neighbours.

    Args:
        points: (n, 3) float64, metres.
        k: neighbours per point (including itself).
        neighbours: (n, >= k) int, each point's nearest neighbours by distance (itself first), when a
            ``cKDTree.query`` already found them; the first ``k`` columns are used.
    """
    return fit_normals(points, k, neighbours=neighbours)[0]


def fit_normals(points: np.ndarray, k: int = tol.NORMAL_NEIGHBOURS, *,
                neighbours: np.ndarray | None = None, noise: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """:func:`estimate_normals`, and how far noise may have tilted each: (normals (n, 3), tilt (n,)).

    ``tilt`` is the variance (radians^2) of the normal's tilt towards the patch's narrower tangent
    direction: a plane fitted to k points spread ``lambda_1 / k`` along it, each ``residual`` off it,
    has a slope variance of ``residual / lambda_1``. Noise tilts normals on a flat face; the contouring
    must not read that as a crease (``dualcontour``).

    With ``noise`` (metres, the points' sigma about their surface) and a patch wider than
    ``tol.NORMAL_NEIGHBOURS``, each patch is fitted again on the points of its main sheet, the point's
    own face (``_refit_own_sheet``).
    """
    k = min(k, len(points))
    if neighbours is None:
        neighbours = nearest(cKDTree(points), points, k)[1]
    neighbours = neighbours[:, :k]
    normals = np.empty_like(points)
    tilt = np.empty(len(points))
    for start in range(0, len(points), NORMAL_BLOCK):
        block = slice(start, start + NORMAL_BLOCK)
        lam, vec = patch_axes(points, neighbours[block])
        normals[block] = vec[:, :, 0]
        tilt[block] = np.maximum(lam[:, 0], 0.0) / (k * np.maximum(lam[:, 1], np.finfo(float).tiny))
    if noise > 0 and k > tol.NORMAL_NEIGHBOURS:
        _refit_own_sheet(points, neighbours, normals, tilt, noise)
    return normals, tilt


def patch_axes(points: np.ndarray, neighbours: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The principal axes of each patch ``points[neighbours[i]]``: eigenvalues (q, 3) ascending (m^2, the
    patch's spread times its size) and unit eigenvectors (q, 3, 3) as columns; column 0 is the normal."""
    patch = points[neighbours]
    patch -= patch.mean(axis=1, keepdims=True)
    return np.linalg.eigh(patch.transpose(0, 2, 1) @ patch)


def _refit_own_sheet(points: np.ndarray, neighbours: np.ndarray, normals: np.ndarray, tilt: np.ndarray,
                     noise: float) -> None:
    """Fit each wide patch again (in place) on the points of its main sheet, the point's own face.

    A patch wide enough to average the noise reaches across a wall a few sigmas thick, and for a point
    the noise moved into the wall the other face is nearly as close as its own: the two sheets' spread
    across the wall then exceeds the patch's along it, and the fit turns sideways (a 3 mm plate at sigma
    0.5 mm: such points' normals 60 degrees off on average; their planes, dropped as facing away, left
    the ones the noise moved outward, and the plate came out +1.8 % thick). The patch's direction across
    its sheets is its neighbours' consensus (the principal axis of their unsigned normals: both faces
    of a wall agree on it, and most neighbours' own fits are sound); along it, the patch's median offset
    lies on the point's own face, which holds most of the patch, and the points within
    ``OWN_SHEET_SIGMAS`` of it are fitted again. Measured by hand on that plate: the inward points'
    normals 0.34 -> 0.75 in mean |cosine| to the truth, the plate +1.8 -> +0.6 %.
    """
    first = normals.copy()
    for start in range(0, len(points), NORMAL_BLOCK):
        block = slice(start, start + NORMAL_BLOCK)
        nbr = neighbours[block]
        beside = first[nbr]
        across = np.linalg.eigh(beside.transpose(0, 2, 1) @ beside)[1][:, :, -1:]
        patch = points[nbr]
        offset = (patch @ across)[:, :, 0]
        level = np.median(offset, axis=1, keepdims=True)
        weight = (np.abs(offset - level) <= OWN_SHEET_SIGMAS * noise).astype(float)[:, None, :]
        count = weight.sum(axis=2)[:, 0]
        # A patch split evenly between two layers (coordinates cut to whole millimetres, copies of a scan)
        # has its median between them and may keep fewer points than a plane needs: its first fit stands
        # (fitting none made NaNs, and eigh raised on them).
        fits = count >= 3
        patch -= (weight @ patch) / np.maximum(count, 1.0)[:, None, None]
        lam, vec = np.linalg.eigh((patch.transpose(0, 2, 1) * weight) @ patch)
        rows = np.arange(start, min(start + NORMAL_BLOCK, len(points)))[fits]
        normals[rows] = vec[fits, :, 0]
        tilt[rows] = np.maximum(lam[fits, 0], 0.0) / (count[fits] * np.maximum(lam[fits, 1], np.finfo(float).tiny))


def probe_sides(points: np.ndarray, normals: np.ndarray, grid: Grid, occ: Occupancy) -> tuple[np.ndarray, np.ndarray]:
    """Which way each normal ((n, 3), unit) points, read along it from the flood-filled outside (blurred, so
    that a shell enclosing nothing still has a side nearer the outside).

    Returns:
        ``sign``: (n,) +1 where the normal points out (or the probe could not tell), -1 where it points in;
        ``unsure``: (n,) bool, where the probe could not tell.
    """
    outside = ndimage.gaussian_filter(occ.outside.astype(np.float32), OUTSIDE_BLUR_CELLS)
    # The shell reaches ``closing`` cells from the points; the outside starts just beyond. The nearest
    # probe that tells the sides apart decides: a farther one may cross a part thinner than itself and
    # read the outside beyond it as this point's inside. A solid that encloses nothing is thinner than
    # the shell everywhere, so only the shell's own blur half a cell out is read there (a 4 mm wire in
    # 2.3 mm cells under 0.5 mm noise: 9 % of its normals flipped by the far probes, 0.1 % without).
    reach = occ.closing + PROBE_CELLS if occ.encloses else NEAR_PROBE_CELLS
    sign = np.ones(len(points))
    unsure = np.ones(len(points), dtype=bool)
    for cells in np.arange(1, 2 * reach + 1) / 2:
        at = np.flatnonzero(unsure)
        step = cells * grid.cell * normals[at]
        ahead = ndimage.map_coordinates(outside, grid.fractional(points[at] + step), order=1, mode="nearest")
        behind = ndimage.map_coordinates(outside, grid.fractional(points[at] - step), order=1, mode="nearest")
        difference = ahead - behind
        sure = np.abs(difference) >= CONFIDENT_DIFFERENCE
        sign[at[sure]] = np.where(difference[sure] < 0, -1.0, 1.0)
        unsure[at[sure]] = False
        if not unsure.any():
            break
    return sign, unsure


def orient_outward(
    points: np.ndarray, normals: np.ndarray, grid: Grid, occ: Occupancy, tree: cKDTree,
    noise: float | None = None, *, neighbours: np.ndarray | None = None,
) -> np.ndarray:
    """Flip ``normals`` ((n, 3), unit) so that each points out of the solid bounded by ``points``.

    Where a second sheet of points runs parallel within a few ``spacing`` (metres) of a point, that
    point is on a wall thinner than the flood fill's shell, which cannot see into it: the probe below
    would read the same outside on both faces (or, worse, a cavity the shell closed). There the
    material is on the side of the other sheet (``thin_wall_side``). ``noise`` (metres, the points'
    standard deviation about their surface) enables that test; sheets closer than a few sigma are noise.
    ``neighbours``: (n, >= THIN_WALL_NEIGHBOURS) int, each point's nearest neighbours from ``tree``
    (itself first), to save the two searches here.
    """
    sign, unsure = probe_sides(points, normals, grid, occ)
    at = np.flatnonzero(unsure)
    if len(at) and len(at) < len(points):
        # A stretch the probe could not read takes its sign from the sure points along its most parallel
        # edges (a spanning tree on 1 - |cos|, as for given normals). Voting with every sure neighbour, round
        # by round, let a bore's wall take its sign across the crease at its mouth, where the neighbours'
        # normals are square to its own and noise casts the vote: a 9 mm bore under 0.5 mm noise came out
        # inside out (+5.0 %, bench/shapes.py seed 1's concave-drilled-35).
        k = min(tol.NORMAL_NEIGHBOURS, len(points))
        nbr = nearest(tree, points[at], k)[1] if neighbours is None else neighbours[at, :k]
        r, c = np.repeat(at, nbr.shape[1]), nbr.ravel()
        if noise is not None:
            # A noisy fin's two faces are parallel, so the most parallel edges hop between them through the points
            # the noise put inside it: 32 % of a heatsink's normals came out inside out (bench/thin_parts.py's
            # part-heatsink-02, +11.4 %). Only edges along one sheet carry a sign.
            if neighbours is None:
                neighbours = nearest(tree, points, min(THIN_WALL_NEIGHBOURS, len(points)))[1]
            along = on_one_sheet(points, normals, r, c, noise, neighbours)
            r, c = r[along], c[along]
        roots = np.unique(c[~unsure[c]])
        flip, reached = signs_along_tree(normals, r, c, roots, sign[roots] < 0)
        sign[reached] = np.where(flip[reached], -1.0, 1.0)
    if noise is not None:
        side = thin_wall_side(points, normals, tree, min_offset=THIN_WALL_NOISE * noise, neighbours=neighbours)
        sign = np.where(side != 0, side, sign)
    return normals * sign[:, None]


def on_one_sheet(points: np.ndarray, normals: np.ndarray, r: np.ndarray, c: np.ndarray, noise: float,
                 neighbours: np.ndarray) -> np.ndarray:
    """(m,) bool: which edges ``r`` -> ``c`` (point indices) join two points of one sheet, as far as noise of
    ``noise`` (metres, one sigma) lets us tell.

    Each point's sheet is placed by the centroid of its nearest ``neighbours`` ((n, >= OWN_SHEET_CENTROID) int,
    itself first), which averages the noise down to sigma / sqrt(OWN_SHEET_CENTROID); an edge whose two centroids
    lie more than SHEET_GAP_SIGMAS sigmas apart along the first point's normal crosses from one sheet to another
    (a wall's two faces, through the points the noise put inside it). Where SHEET_GAP_SIGMAS sigmas are under the
    point spacing, the centroids' gaps come from the sampling and the curvature, not from the noise, and every edge
    is kept (clean clouds, and noisy ones sampled sparsely for their size).
    """
    own = neighbours[:, :OWN_SHEET_CENTROID]
    spacing = float(np.median(np.linalg.norm(points[own[:, 1]] - points, axis=1))) if own.shape[1] > 1 else 0.0
    if SHEET_GAP_SIGMAS * noise < spacing:
        return np.ones(len(r), dtype=bool)
    centroid = points[own].mean(axis=1)
    gap = np.abs(np.einsum("ij,ij->i", centroid[c] - centroid[r], normals[r]))
    return gap <= SHEET_GAP_SIGMAS * noise


def thin_wall_side(points: np.ndarray, normals: np.ndarray, tree: cKDTree,
                   k: int = THIN_WALL_NEIGHBOURS, min_offset: float = 0.0, *,
                   neighbours: np.ndarray | None = None) -> np.ndarray:
    """+1 or -1 where the point lies on a thin wall (its normal should be flipped by that), 0 elsewhere.

    Among a point's ``k`` neighbours, those with (unoriented) normals parallel to its own are on its
    sheet or on the wall's other face. On one sheet their offsets along the normal average to about
    zero (noise cancels, curvature leaves a small fraction of the spacing); with the other face of a
    wall within reach, the average sits clearly on that face's side. Material is there, so the
    outward normal points away from it. A t-test on the offsets keeps noise from deciding.
    """
    k = min(k, len(points))
    nbr = nearest(tree, points, k)[1] if neighbours is None else neighbours[:, :k]
    offsets = np.einsum("nkj,nj->nk", points[nbr] - points[:, None, :], normals)
    # Offsets from the point's own sheet, as its nearest neighbours place it: measured from the
    # point itself, its own noise would read as a second sheet.
    offsets -= offsets[:, :OWN_SHEET_NEIGHBOURS].mean(axis=1, keepdims=True)
    parallel = np.abs(np.einsum("nkj,nj->nk", normals[nbr], normals)) > PARALLEL_COSINE
    count = parallel.sum(axis=1)
    mean = (offsets * parallel).sum(axis=1) / np.maximum(count, 1)
    var = ((offsets - mean[:, None]) ** 2 * parallel).sum(axis=1) / np.maximum(count - 1, 1)
    t = mean / np.sqrt(var / np.maximum(count, 1) + np.finfo(float).tiny)
    # The other face must be a real share of the neighbourhood, not a stray point: its mean offset
    # must be a good part of the neighbourhood's reach.
    reach = np.linalg.norm(points[nbr[:, -1]] - points, axis=1)
    wall = ((np.abs(t) > THIN_WALL_T) & (np.abs(mean) > np.maximum(THIN_WALL_OFFSET * reach, min_offset))
            & (count >= k // 2))
    return np.where(wall, -np.sign(mean), 0.0)


def orient_to_viewpoint(points: np.ndarray, normals: np.ndarray, viewpoint: np.ndarray) -> np.ndarray:
    """Flip normals to face ``viewpoint`` (metres, same frame): a sensor sees the outside.

    ``viewpoint`` is (3,) for one sensor, or (n, 3) for each point's own sensor (a fused cloud).
    """
    facing = np.einsum("ij,ij->i", normals, np.asarray(viewpoint) - points)
    return np.where(facing[:, None] < 0, -normals, normals)


def orient_given(points: np.ndarray, normals: np.ndarray, grid: Grid, occ: Occupancy) -> tuple[np.ndarray, str | None]:
    """Given normals ((n, 3), unit), checked and, where they are not consistently outward, re-signed.

    Files carry normals from tools that do not orient them (PCA normals with arbitrary signs), that orient
    them inward, or toward a sensor that saw the object from inside; trusted as they came, inward normals
    put shapes of ``bench/given_normals.py`` up to +466 % off. A sample of points is compared with its
    own sheet (``SHEET_COSINE``, ``SHEET_OFFSET``) and read by the outside probe (:func:`probe_sides`).
    Consistent and outward: returned as they are. Consistent and inward: flipped. Otherwise their
    directions are kept and their signs propagated along each sheet (over its most parallel neighbours),
    each connected sheet then turned to the side its points read as out: towards the other face's
    material where a wall is thin (:func:`thin_wall_side`), else by the probe.

    Returns:
        The normals, and a warning saying what was done (None when they were used as given).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(points)
    tree = cKDTree(points, balanced_tree=False, compact_nodes=False)  # built for a few queries: built fast
    sample = np.unique(np.linspace(0, n - 1, min(GIVEN_SAMPLE, n)).astype(np.int64))
    k = min(GIVEN_NEIGHBOURS + 1, n)
    nbr = nearest(tree, points[sample], k)[1][:, 1:]
    on_sheet, agree = _sheet_edges(points, normals, sample, nbr)
    counted = on_sheet.sum(axis=1) > 0
    against = float(np.mean(2 * (on_sheet & ~agree).sum(axis=1)[counted] > on_sheet.sum(axis=1)[counted])) \
        if counted.any() else 0.0
    sign, unsure = probe_sides(points[sample], normals[sample], grid, occ)
    inward = float(np.mean(sign[~unsure] < 0)) if (~unsure).any() else 0.0
    if against <= GIVEN_AGAINST_SHEET:
        if inward <= GIVEN_INWARD:
            return normals, None
        # "given": the file's, or (twin estimate with views) turned towards each point's sensor, which a cloud that
        # came without normals did not give; the message names both.
        return -normals, (f"the normals (the file's, or turned towards the sensor) point into the object "
                          f"({100 * inward:.0f} % of those probed): flipped")
    # Re-sign along each sheet: every point's sheet neighbours, the edges' signs from their normals.
    nbr = nearest(tree, points, k)[1][:, 1:]
    rows = np.arange(n)
    on_sheet, agree = _sheet_edges(points, normals, rows, nbr)
    r = np.repeat(rows, nbr.shape[1])[on_sheet.ravel()]
    c = nbr.ravel()[on_sheet.ravel()]
    count, label = connected_components(coo_matrix((np.ones(len(r)), (r, c)), shape=(n, n)), directed=False)
    # Signs travel along each sheet's most parallel edges, from each sheet's first point.
    roots = np.unique(label, return_index=True)[1]
    flip = signs_along_tree(normals, r, c, roots, np.zeros(len(roots), dtype=bool))[0]
    signed = np.where(flip[:, None], -normals, normals)
    # Each sheet then takes the side its points read. The probe reads most points; where a wall's other
    # face is near, material lies towards it (thin_wall_side), which few points show but which is sure:
    # on an open shell the probe reads the same outside on both faces (a tray's inner face read inward
    # at 972 points of 972, while 33 of its points saw the outer face, all on the right side).
    # So walls decide a sheet the probe cannot (undecided, or split), or that enough of them contradict.
    side = thin_wall_side(points, signed, tree)  # given normals are not noisy: no noise floor
    sign, unsure = probe_sides(points, signed, grid, occ)
    votes = lambda mask: np.bincount(label, weights=mask, minlength=count)  # noqa: E731
    out, into = votes(~unsure & (sign > 0)), votes(~unsure & (sign < 0))
    keep, turn = votes(side > 0), votes(side < 0)
    probe_turns = into > out
    probe_decides = (np.maximum(out, into) >= SHEET_DECISIVE * (out + into)) & (out + into >= MIN_SHEET_VOTES)
    walls_sure = (np.maximum(keep, turn) >= MIN_SHEET_VOTES) & (np.minimum(keep, turn) == 0)
    turn_it = np.where(walls_sure & (~probe_decides | ((turn > 0) != probe_turns)), turn > keep,
                       np.where(probe_decides, probe_turns, turn > keep))
    signed[turn_it[label]] *= -1
    return signed, (f"the given normals are not consistently oriented ({100 * against:.0f} % of a sample point "
                    f"against their own surface): their signs were re-estimated outward")


def signs_along_tree(normals: np.ndarray, r: np.ndarray, c: np.ndarray, roots: np.ndarray,
                     root_flips: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signs carried along the most parallel edges between points (Hoppe et al. 1992: a minimum spanning tree
    on 1 - |cos| of the edges' normals), one wrong edge flipping everything past it.

    Args:
        normals: (n, 3) unit normals, their signs arbitrary.
        r, c: (m,) int, the edges' ends (point indices).
        roots: (q,) int, points whose sign is known: a virtual node joins each, so every tree grows from one.
        root_flips: (q,) bool, True where that root's normal is to be flipped.

    Returns:
        (flip, reached), both (n,) bool: whether each point's normal is to be flipped, and whether any root's
        tree reached it (False: no edge path to a root; its flip is False).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, minimum_spanning_tree

    n = len(normals)
    cos = np.abs(np.einsum("ij,ij->i", normals[r], normals[c]))
    # The roots' edges weigh least of all, so every root hangs from the virtual node itself; > 0, as csgraph
    # drops zero-weight edges.
    weight = np.r_[1.0 + 1e-9 - cos, np.full(len(roots), 1e-12)]
    rr, cc = np.r_[r, np.full(len(roots), n)], np.r_[c, roots]
    tree_edges = minimum_spanning_tree(coo_matrix((weight, (rr, cc)), shape=(n + 1, n + 1)).tocsr())
    order, pred = breadth_first_order(tree_edges, n, directed=False)
    walked = order[1:]  # every reached point, parents before children
    negative = np.zeros(n + 1, dtype=bool)
    negative[roots] = root_flips
    parent = pred[walked]
    child_of_point = parent < n
    negative[walked[child_of_point]] = np.einsum(
        "ij,ij->i", normals[parent[child_of_point]], normals[walked[child_of_point]]) < 0
    # Each point's flip is the parity of negative edges on its path to the virtual root: pointer jumping.
    flip, up = negative.copy(), np.r_[pred[:n], n]
    up[up < 0] = n
    while (up[:n] != n).any():
        flip ^= flip[up]
        up = up[up]
    reached = np.zeros(n, dtype=bool)
    reached[walked] = True
    return flip[:n] & reached, reached


def _sheet_edges(points: np.ndarray, normals: np.ndarray, at: np.ndarray,
                 nbr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For points ``at`` and their neighbours ``nbr`` ((m, k)): which neighbours lie on the point's sheet,
    and which of those have normals on the same side (both (m, k) bool)."""
    dots = np.einsum("mkj,mj->mk", normals[nbr], normals[at])
    d = points[nbr] - points[at][:, None, :]
    offset = np.abs(np.einsum("mkj,mj->mk", d, normals[at])) / np.maximum(np.linalg.norm(d, axis=2), 1e-300)
    return (np.abs(dots) > SHEET_COSINE) & (offset < SHEET_OFFSET), dots > 0
