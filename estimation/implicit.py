"""Inside/outside on the narrow band: implicit moving least squares near the points, flood fill beyond.

Near the points, a band node's value is the Gaussian-weighted mean of its nearest points' plane
distances ``n_i . (x - p_i)`` (Kolluri's IMLS), scattered from each point to the 27 fine nodes around
it. The kernel is one fine cell wide and the fine cell is about one point spacing, so a wall two
spacings thick keeps nodes of the right sign on both faces: the far face's points weigh
``exp(-(2 h)^2 / h^2) ~ 2 %`` against the near face's. (The old fixed 128-cell grid made cells
wider than thin walls, and then the far face's planes outvoted the near face's: walls thickened.)

A plane says little far from its point: beyond a convex crease, the planes of the other face's points
extend past the edge and read the outside as inside. With exact normals a 60 mm cube grew spikes up to
3 mm along its edges from such nodes (a few points at the corner of a node's reach outvoting none from
the face below it). So a node's value is trusted only where some point's foot on its own plane lies
within a cell of that point, and the nearest point is no more than a cell further than the value says
(``EXTRAPOLATION_CELLS``), as for any node beside a sampled surface: on a face the nearest point is at
most about a spacing (<= a cell) along it from the node's foot.

Band nodes no point reached (or reached only by extrapolated planes) take the sign of their
neighbours, spreading in from the trusted nodes and from the coarse flood fill, then settling to their
neighbours' majority, so every node has a sign and the zero level is closed. Only the sign is used
downstream: the surface's position comes from the points' own planes (``estimation.dualcontour``), not
from interpolating this field.
"""

from __future__ import annotations

import numpy as np

from estimation.sparsegrid import Band

#: Gaussian width of the IMLS weights, fine cells (one cell ~ one point spacing; see module doc).
KERNEL_CELLS = 1.0

#: Magnitude (fine cells) given to nodes signed by spreading rather than measured; also the clamp on
#: measured values. Beyond 1.5 cells no edge crossing can be interpolated anyway.
FAR_CELLS = 1.5

#: How far (cells) a point's plane is read past the point: a node's value is trusted where some point's
#: foot lies within this of it and the nearest point within ``|value|`` plus this (module doc).
EXTRAPOLATION_CELLS = 1.0

#: Rounds of majority voting that settle the spread signs (``_spread_signs``).
SETTLE_ROUNDS = 8

#: Neighbour offsets of a node (the 27 around it, itself included), a cell's 8 corners from its lowest,
#: and a node's 6 face neighbours.
NEIGHBOURS_27 = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)])
CORNERS_8 = np.array([(i, j, k) for i in (0, 1) for j in (0, 1) for k in (0, 1)])
FACES_6 = np.array([(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)])


def band_field(points: np.ndarray, normals: np.ndarray, band: Band) -> tuple[np.ndarray, np.ndarray]:
    """Signed values (metres, negative inside) on every band node, and which were measured.

    Args:
        points: (n, 3) float64, metres, band frame. normals: (n, 3) unit, outward.
        band: the narrow band around ``points``.

    Returns:
        values (band.size,) float32, and measured (band.size,) bool: True where points were within
        reach and the value is trusted (an IMLS distance), False where the sign was spread from
        neighbours.
    """
    h = band.h
    # Each point reaches the 27 nodes around its nearest node: every node within 1.5 cells (per axis).
    # The Gaussian weight and the plane value are separable per axis, so both are built from three
    # (n, 3) factors (one per axis offset -1, 0, 1) broadcast to (n, 3, 3, 3), in NEIGHBOURS_27's order.
    base = np.rint((points - band.origin) / h).astype(np.int64)
    r = band.position(base) - points
    steps = np.array([-1, 0, 1])
    along = r[:, :, None] + h * steps  # (n, axis, offset): node minus point, metres
    w = np.exp(-(along / (KERNEL_CELLS * h)) ** 2)
    d = normals[:, :, None] * along
    a2 = along**2
    weight = (w[:, 0, :, None, None] * w[:, 1, None, :, None] * w[:, 2, None, None, :]).reshape(-1)
    plane = (d[:, 0, :, None, None] + d[:, 1, None, :, None] + d[:, 2, None, None, :]).reshape(-1)
    distance2 = (a2[:, 0, :, None, None] + a2[:, 1, None, :, None] + a2[:, 2, None, None, :]).reshape(-1)
    target = _locate_27(band, base)
    weight_sum = np.bincount(target, weights=weight, minlength=band.size + 1)[:-1]
    value_sum = np.bincount(target, weights=weight * plane, minlength=band.size + 1)[:-1]
    # Trust (module doc): some point's foot on its plane lies within a cell of it, and the nearest point
    # is no more than a cell further than the value says.
    nearest2 = np.full(band.size + 1, np.inf)
    np.minimum.at(nearest2, target, distance2)
    foot2 = np.full(band.size + 1, np.inf)
    np.minimum.at(foot2, target, distance2 - plane**2)
    measured = weight_sum > 0
    far = FAR_CELLS * h
    values = np.zeros(band.size, dtype=np.float32)
    values[measured] = np.clip(value_sum[measured] / weight_sum[measured], -far, far)
    reach = EXTRAPOLATION_CELLS * h
    measured &= (foot2[:-1] <= reach**2) & (np.sqrt(nearest2[:-1]) <= np.abs(values) + reach)
    _air_pockets(points, normals, band)
    _spread_signs(values, measured, band, far)
    return values, measured


def _air_pockets(points: np.ndarray, normals: np.ndarray, band: Band) -> None:
    """Turn to outside (in ``band.occ.outside`` and ``band.block_step_inside``, in place) every part of the
    coarse flood fill's inside that lies on the outer side of the surface nearest to it.

    The flood fill calls inside whatever the closed shell encloses, air included: a bottle's body behind a
    mouth the closing shell sealed, a hollow ball's cavity. But every measured surface separates material
    from air: the cavity lies on the outer side of its wall's inner face (a bottle of 3 mm walls with given
    normals came out filled, +250 %). Each part votes with its nodes that border the shell: on which side of
    the nearest point's plane each lies. A majority for outside makes it air; a solid's inside lies behind
    its surface and stays.
    """
    from scipy import ndimage

    from estimation.spacing import query_tree

    occ = band.occ
    inside = occ.inside
    labels, count = ndimage.label(inside)
    if count == 0:
        return
    border = inside & ndimage.binary_dilation(occ.shell)
    nodes = np.argwhere(border)
    if not len(nodes):
        return
    position = band.coarse.position(nodes)
    _, nearest = query_tree(points).query(position, workers=-1)  # few queries: the cheap tree (half the build)
    side = np.sign(np.einsum("ij,ij->i", position - points[nearest], normals[nearest]))
    votes = np.bincount(labels[nodes[:, 0], nodes[:, 1], nodes[:, 2]], weights=side, minlength=count + 1)
    air = np.flatnonzero(votes[1:] > 0) + 1
    if not len(air):
        return
    occ.outside[np.isin(labels, air)] = True
    neighbours = band.blocks[:, None, :] + FACES_6[None, :, :]
    band.block_step_inside[:] = ~occ.outside[neighbours[..., 0], neighbours[..., 1], neighbours[..., 2]]


def _locate_27(band: Band, base: np.ndarray) -> np.ndarray:
    """Band positions ((n * 27,) int64, NEIGHBOURS_27's order) of the 27 nodes around fine nodes ``base``.

    Nodes outside the band get ``band.size`` (a spare bin for ``np.bincount``). What ``Band.locate``
    does for any nodes, per axis first: the coarse block and the position in it of ``base + o`` take
    three values per axis, and only the slot look-up is done on all 27 combinations.
    """
    b = band.ratio
    shifted = base[:, :, None] + np.array([-1, 0, 1]) + b // 2  # (n, axis, offset)
    coarse = shifted // b
    within = shifted - b * coarse
    shape = band.coarse.shape
    # Points lie in the coarse grid's interior (it is padded by PAD_CELLS >= 2), so no bounds checks.
    key = (coarse[:, 0, :, None, None] * shape[1] + coarse[:, 1, None, :, None]) * shape[2] \
        + coarse[:, 2, None, None, :]
    block = band.slot.reshape(-1)[key.reshape(-1)].astype(np.int64)
    inner = ((within[:, 0, :, None, None] * b + within[:, 1, None, :, None]) * b + within[:, 2, None, None, :])
    return np.where(block >= 0, block * b**3 + inner.reshape(-1), band.size)


def _spread_signs(values: np.ndarray, measured: np.ndarray, band: Band, far: float) -> None:
    """Give unmeasured band nodes (in place) the majority sign of their signed face neighbours.

    Nodes outside the band count with the coarse flood fill's answer. Repeats until nothing changes;
    a node with no signed neighbour at the end (an island of the band no point reached) is outside.
    Then the spread nodes settle: each takes the majority of all six neighbours, for up to
    ``SETTLE_ROUNDS`` rounds.
    """
    spread = np.flatnonzero(~measured)
    pending = spread
    known = measured.copy()
    # The six neighbours of every pending node, once: (position or -1, coarse inside where -1).
    all_steps = steps = [band.step(pending, axis, direction) for axis in range(3) for direction in (1, -1)]
    while len(pending):
        votes = np.zeros(len(pending))
        for at, far_inside in steps:
            in_band = at >= 0
            vote = np.where(in_band, 0.0, np.where(far_inside, -1.0, 1.0))
            nbr = at[in_band]
            vote[in_band] = np.where(known[nbr], np.where(values[nbr] < 0, -1.0, 1.0), 0.0)
            votes += vote
        decided = votes != 0
        if not decided.any():
            values[pending] = far
            break
        values[pending[decided]] = np.where(votes[decided] < 0, -far, far)
        known[pending[decided]] = True
        pending = pending[~decided]
        steps = [(at[~decided], far_inside[~decided]) for at, far_inside in steps]
    # The rounds above sign a node from whichever neighbours were signed first; a node beside one
    # wrongly measured node (near a crease) took its sign though most of its neighbours, signed
    # later, disagree. Let every spread node follow the majority of all six until none changes,
    # measured neighbours voting by how far they are from the surface (a node a tenth of a cell
    # inside is a weak vote).
    for _ in range(SETTLE_ROUNDS):
        votes = np.zeros(len(spread))
        for at, far_inside in all_steps:
            in_band = at >= 0
            vote = np.where(far_inside, -far, far)
            vote[in_band] = values[at[in_band]]
            votes += vote
        flip = np.flatnonzero(votes * values[spread] < 0)
        if not len(flip):
            break
        values[spread[flip]] = -values[spread[flip]]
