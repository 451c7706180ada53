"""Dual contouring on the narrow band: one vertex per surface cell, placed on the points' own planes.

Marching cubes puts vertices on grid edges by interpolating a field, and any smooth field rounds a
crease by about a cell: low-poly objects shrank 1-3 %. Here every grid edge whose ends have opposite
signs gives one quad, joining the vertices of the four cells around it, so the surface is the boundary
of the set of inside nodes: closed and consistently oriented by construction. Each cell's vertex
minimises the squared distances to the tangent planes ``n_i . (x - p_i) = 0`` of the points near the
cell (a quadric error function, Ju et al. 2002). On a flat face the planes agree and the vertex lands
on the face; where two faces meet the vertex lands on their crease, where three meet on the corner.
Small eigenvalues of the quadric (one direction poorly constrained, i.e. a smooth or flat patch) are
dropped and the vertex stays at the mean edge crossing along those directions.

Only planes that pass near the cell count, and only those facing the cell's way: the far face of a wall
two cells thick does not, so the vertex is not pulled into the wall. A point counts for the cells around
its normal line, as far along it on both sides of the surface as the noise reaches: a point counted for
the cells near its own position (the 8 around it) is counted where the noise moved it, so cells outside
a face saw mostly the points moved outward; every convex crease bulged (a 40 mm tetrahedron at sigma
0.5 mm came out +0.8 % with exact normals, now -0.1 %).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimation.implicit import FAR_CELLS
from estimation.sparsegrid import Band

#: Eigenvalues of the quadric below this fraction of the largest are dropped. A crease of 25 degrees
#: or more keeps its second direction (sin^2(25 deg) / 2 ~ 0.09 of the weight on each side); estimated
#: normals on a flat face wobble by a few degrees (~0.005) and are dropped.
QEF_RELATIVE_EIGENVALUE = 0.05

#: A plane counts for a cell when it passes within this margin (cells) of the cell: a little slack for
#: noise and for curvature between the point and the cell.
PLANE_MARGIN_CELLS = 0.25

#: Planes within this many noise sigmas beyond the cell also count (see ``_place_vertices``).
NOISE_MARGIN_SIGMAS = 3.0

#: Gaussian width (cells) of the weight of a point's plane by its distance from the cell centre.
WEIGHT_CELLS = 1.0

#: Cells whose plane normals agree this well (|weighted mean normal|, ~6 degrees of spread) are one
#: face: their vertex needs no eigen-decomposition.
FLAT_AGREEMENT = 0.995

#: A cell's quadric keeps a second direction (a crease) only where its share exceeds the noise's by
#: this many times the normals' mean tilt variance: the share along one tangent direction of
#: noise-tilted normals is about that variance, and the larger of two such shares runs above it.
NOISE_TILT_FACTOR = 3.0

#: A vertex may leave its cell by this much (cells) before it falls back to the mean crossing.
VERTEX_SLACK_CELLS = 0.5

#: Share of a cell's normal spread a linear turn with position may leave unexplained, beyond what the
#: noise in the positions hides, for the cell to count as curved rather than creased
#: (``_turns_with_position``).
CURVED_MARGIN = 0.05

#: ...and whose fitted curvature turns the normal by less than this (radians) across a cell.
CURVED_MAX_TURN = 1.0

#: A point's foot is where its normal line crosses its cell's mean plane; lines steeper than this
#: cosine to the mean normal (at a crease, where the point's face ends) are taken at this cosine.
FOOT_COSINE = 0.5

#: Cells a point's plane may count for, by lowest corner relative to the point's nearest node: every
#: cell whose centre is within 1.5 cells of the node along each axis, so within 2 cells of the point.
GATHER_OFFSETS = np.array([(i, j, k) for i in range(-2, 2) for j in range(-2, 2) for k in range(-2, 2)])

#: A point's plane counts for cells whose centre is within this many cells of its normal line (its
#: weight there is exp(-2.25)).
GATHER_RADIUS_CELLS = 1.5


@dataclass(frozen=True)
class DualSurface:
    """The contoured surface and what it says about the data.

    Attributes:
        vertices: (v, 3) float64 metres; faces: (f, 3) int64, outward.
        cells: cells with a vertex.
        opposed_cells: cells with sign changes facing both ways along an axis: both faces of a wall
            thinner than about a cell pass through them, and their single vertex cannot be right.
        unmeasured_area: m^2 of surface between band nodes no point reached (holes closed by the shell).
        unmeasured_patches: (k, 2) float64: that area by connected patch (quads sharing a corner), m^2, and
            each patch's half width, m (twice its area over its perimeter, at most a disc's radius).
        normals: (v, 3) float64, unit outward: each vertex's surface normal from the points' planes near
            it (the weighted mean normal, or the quadric's dominant direction), not from the mesh.
        smooth: (v,) bool: the planes near the vertex agree (``FLAT_AGREEMENT``, or their quadric has
            one direction beyond what noise tilts the normals: a face or a gently curved patch), so the
            vertex is on the surface to second order. False at creases and
            corners, on patches curved more than a cell resolves (there the quadric's vertex lies on
            the tangent planes, outside a convex surface) and where no plane reached.
    """

    vertices: np.ndarray
    faces: np.ndarray
    cells: int
    opposed_cells: int
    unmeasured_area: float
    normals: np.ndarray
    smooth: np.ndarray
    unmeasured_patches: np.ndarray


def contour(points: np.ndarray, normals: np.ndarray, band: Band, values: np.ndarray,
            measured: np.ndarray, *, noise: float = 0.0, tilt: np.ndarray | None = None) -> DualSurface:
    """Dual-contour the sign of ``values`` on ``band`` with vertices from the oriented points' planes.

    Args:
        points: (n, 3) float64 metres (band frame); normals: (n, 3) unit, outward.
        band: the narrow band; values: (band.size,) float32, negative inside; measured: (band.size,) bool.
        noise: standard deviation of the points about the surface, metres.
        tilt: (n,) variance of each normal's tilt from noise, radians^2 (``normals.fit_normals``); None:
            the normals are exact.
    """
    h = band.h
    far = FAR_CELLS * h
    dims = band.dims
    stored = np.arange(band.size)
    inside = values < 0

    # Sign-changing edges (u, u + e_axis). Each edge is found from its band end; an edge with both ends
    # in the band is taken from its lower end only.
    edge_lo, edge_axis, edge_in_lo, edge_t = [], [], [], []
    for axis in range(3):
        for direction in (1, -1):
            at, far_inside = band.step(stored, axis, direction)
            in_band = at >= 0
            other_inside = np.where(in_band, inside[np.maximum(at, 0)], far_inside)
            change = other_inside != inside
            if direction == -1:
                change &= ~in_band  # band-band edges were taken from their lower end
            here = np.flatnonzero(change)
            there = at[here]
            v_here = values[here]
            v_other = np.where(there >= 0, values[np.maximum(there, 0)], np.where(other_inside[here], -far, far))
            lo_index = band.index_of(here)
            if direction == -1:
                lo_index[:, axis] -= 1
            v_lo, v_hi = (v_here, v_other) if direction == 1 else (v_other, v_here)
            edge_lo.append(lo_index)
            edge_axis.append(np.full(len(here), axis))
            edge_in_lo.append(inside[here] if direction == 1 else other_inside[here])
            edge_t.append(np.clip(v_lo / np.where(v_lo == v_hi, 1.0, v_lo - v_hi), 0.0, 1.0))
    lo = np.concatenate(edge_lo)
    axis = np.concatenate(edge_axis)
    in_lo = np.concatenate(edge_in_lo)
    t = np.concatenate(edge_t)
    if len(lo) == 0:
        from estimation.errors import ReconstructionError

        raise ReconstructionError("the reconstructed field has no surface (no inside found)")

    # The four cells (by their lowest corner) around each edge, counter-clockwise seen from +axis.
    b_axis, c_axis = (axis + 1) % 3, (axis + 2) % 3
    eb, ec = np.eye(3, dtype=np.int64)[b_axis], np.eye(3, dtype=np.int64)[c_axis]
    corners = np.stack([lo, lo - eb, lo - eb - ec, lo - ec], axis=1)  # (e, 4, 3)
    # Outward normal is +axis when the low end is inside; else reverse the loop.
    corners[~in_lo] = corners[~in_lo][:, ::-1]
    keys = (corners[..., 0] * dims[1] + corners[..., 1]) * dims[2] + corners[..., 2]
    cell_keys, quads = np.unique(keys.ravel(), return_inverse=True)
    quads = quads.reshape(-1, 4)
    n_cells = len(cell_keys)

    # Mean edge crossing per cell: the vertex where the planes leave it free.
    crossing = band.position(lo) + (t * h)[:, None] * np.eye(3)[axis]
    count = np.bincount(quads.ravel(), minlength=n_cells)
    mean = np.stack([np.bincount(quads.ravel(), weights=np.repeat(crossing[:, i], 4), minlength=n_cells)
                     for i in range(3)], axis=1) / count[:, None]

    # Each cell's outward direction from its own sign changes (the quads' normals), and whether it
    # has sign changes facing both ways along one axis: both faces of a wall in one cell, where one
    # vertex cannot be right.
    outward = np.where(in_lo, 1.0, -1.0)
    cell_of = quads.ravel()
    facing = np.zeros((n_cells, 3))
    both_ways = np.zeros(n_cells, dtype=bool)
    for ax in range(3):
        on_axis = np.repeat(axis == ax, 4)
        plus = np.bincount(cell_of[on_axis], weights=np.repeat(outward[axis == ax] > 0, 4), minlength=n_cells)
        minus = np.bincount(cell_of[on_axis], minlength=n_cells) - plus
        facing[:, ax] = plus - minus
        both_ways |= (plus > 0) & (minus > 0)
    vertices, supported, vertex_normals, smooth = _place_vertices(points, normals, band, cell_keys, mean, noise, facing, tilt)
    opposed = both_ways

    tri = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    # Split each quad along its shorter diagonal: the longer one would fold across a crease.
    d02 = np.linalg.norm(vertices[quads[:, 0]] - vertices[quads[:, 2]], axis=1)
    d13 = np.linalg.norm(vertices[quads[:, 1]] - vertices[quads[:, 3]], axis=1)
    alt = d13 < d02
    tri = np.concatenate([np.where(alt[:, None], quads[:, [0, 1, 3]], quads[:, [0, 1, 2]]),
                          np.where(alt[:, None], quads[:, [1, 2, 3]], quads[:, [0, 2, 3]])])
    area = np.linalg.norm(np.cross(vertices[quads[:, 1]] - vertices[quads[:, 0]],
                                   vertices[quads[:, 3]] - vertices[quads[:, 0]]), axis=1)
    # A quad none of whose cells any point's plane passes through is surface the cloud did not see.
    unseen = ~supported[quads].any(axis=1)
    return DualSurface(vertices=vertices, faces=tri.astype(np.int64), cells=n_cells,
                       opposed_cells=int(opposed.sum()), unmeasured_area=float(area[unseen].sum()),
                       normals=vertex_normals, smooth=smooth,
                       unmeasured_patches=_patches(quads[unseen], area[unseen], vertices))


def _patches(quads: np.ndarray, area: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """(k, 2): the area (m^2) and the half width (m, 2 area / perimeter: a disc's radius, a strip's width; at most
    the radius of a disc of that area) of each connected patch of ``quads`` (q, 4), quads sharing a corner joined;
    ``area`` (q,) is each quad's."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if len(quads) == 0:
        return np.zeros((0, 2))
    q, n = len(quads), len(vertices)
    # Quads and vertices as one graph's nodes, each quad linked to its four corners.
    links = coo_matrix((np.ones(4 * q), (np.repeat(np.arange(q), 4), q + quads.ravel())), shape=(q + n, q + n))
    labels = np.unique(connected_components(links, directed=False)[1][:q], return_inverse=True)[1]
    # The rim: quad edges no other quad of the patches shares.
    edges = np.sort(np.stack([quads, np.roll(quads, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    _, first, count = np.unique(edges, axis=0, return_index=True, return_counts=True)
    rim = first[count == 1]
    length = np.linalg.norm(vertices[edges[rim, 0]] - vertices[edges[rim, 1]], axis=1)
    areas = np.bincount(labels, weights=area)
    perimeter = np.bincount(labels[rim // 4], weights=length, minlength=len(areas))
    # No wider than a disc of the same area (the isoperimetric bound), which a patch with no rim (a whole closed
    # piece no point reached) also takes.
    return np.stack([areas, np.minimum(2 * areas / np.maximum(perimeter, 1e-300), np.sqrt(areas / np.pi))], axis=1)


def _place_vertices(points: np.ndarray, normals: np.ndarray, band: Band, cell_keys: np.ndarray,
                    mean: np.ndarray, noise: float,
                    facing: np.ndarray, tilt: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each cell's vertex: the quadric minimiser of the planes through it, else the mean crossing.

    Returns:
        vertices (c, 3), supported (c,) bool (some plane reached the cell), normals (c, 3) unit (the
        planes' normal there; the cell's facing where none reached) and smooth (c,) bool (see
        ``DualSurface``).
    """
    h = band.h
    dims = band.dims
    n_cells = len(cell_keys)
    cell, src, centre, line2 = _gather(points, normals, band, cell_keys, noise)
    p, n = points[src], normals[src]
    # Planes facing away from the cell's own surface belong to the other face of a wall (or the far
    # side of a thin gap): they would pull the vertex into the wall. A crease's two faces both face
    # the cell's way, down to a knife edge of ~20 degrees.
    ok = np.einsum("ij,ij->i", n, facing[cell]) > 0
    cell, p, n, centre, src, line2 = cell[ok], p[ok], n[ok], centre[ok], src[ok], line2[ok]

    def acc(values: np.ndarray) -> np.ndarray:
        return np.bincount(cell, weights=values, minlength=n_cells)

    # Weight by the distance along the surface only: along the normal it is noise, and weighting it would
    # favour points that the noise moved towards the cell, a bias. The distance is taken from the cell
    # centre to where the point's normal line crosses the cell's mean plane (its foot), so moving a point
    # along its normal leaves its weight unchanged. A point's own plane would mix its offset along the
    # normal into that distance where the normals turn across the cell (a curved patch, near an edge),
    # favouring the points the noise moved outward. The mean plane is first weighted by the distance to
    # the line.
    w = np.exp(-line2 / (WEIGHT_CELLS * h) ** 2)
    plane = np.stack([acc(w * n[:, i]) for i in range(3)], axis=1)
    plane = (plane / np.maximum(np.linalg.norm(plane, axis=1, keepdims=True), np.finfo(float).tiny))[cell]
    rel = p - centre
    along = np.einsum("ij,ij->i", plane, rel) / np.maximum(np.einsum("ij,ij->i", plane, n), FOOT_COSINE)
    foot = rel - n * along[:, None]
    w = np.exp(-((foot**2).sum(axis=1) - np.einsum("ij,ij->i", plane, foot) ** 2) / (WEIGHT_CELLS * h) ** 2)
    d = np.einsum("ij,ij->i", n, p)

    a = np.empty((n_cells, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            a[:, i, j] = a[:, j, i] = acc(w * n[:, i] * n[:, j])
    rhs = np.stack([acc(w * n[:, i] * d) for i in range(3)], axis=1)
    weight = acc(w)
    normal_sum = np.stack([acc(w * n[:, i]) for i in range(3)], axis=1)

    # Where the planes agree (a face, or a gently curved patch), the quadric has one direction: the
    # vertex is the mean crossing moved onto the weighted mean plane. Only the rest (creases, corners)
    # need the eigen-decomposition.
    agree = np.linalg.norm(normal_sum, axis=1) / np.maximum(weight, np.finfo(float).tiny)
    flat = agree > FLAT_AGREEMENT
    rest = np.flatnonzero(~flat & (weight > 0))
    lam, vec = np.linalg.eigh(a[rest])
    # A second direction is a crease only beyond what noise tilting the normals puts there: the
    # weighted mean tilt variance is the quadric's share along a tangent direction on a noisy face.
    share = np.full(len(rest), QEF_RELATIVE_EIGENVALUE)
    if tilt is not None:
        share += NOISE_TILT_FACTOR * acc(w * tilt[src])[rest] / weight[rest]
    keep = lam > share[:, None] * lam[:, -1:]
    # A quadric with one direction left is a face too, whose normals wobble more than FLAT_AGREEMENT
    # allows (estimated on noisy points they do everywhere). Minimising it would put the vertex on the
    # mean tangent plane, outside a convex surface by k t^2 / 2: noisy curved shapes came out twice as
    # far outside as the noise itself moves the points.
    one = keep.sum(axis=1) == 1
    # A second direction is a crease only where the normals jump between faces; on a patch curved
    # tightly for its cell they turn with position instead, and the quadric's minimiser (where the
    # tangent planes meet) lies outside a convex patch (a 7 mm tube at sigma 1 mm: half its cells taken
    # for creases, their vertices 0.25 mm out, +1.9 %).
    one[~one] = _turns_with_position(rest[~one], cell, p - centre, n, w, normal_sum, noise, h)
    flat[rest[one]] = True
    sharp, lam, vec, keep = rest[~one], lam[~one], vec[~one], keep[~one]
    vertex = mean.copy()
    plane_only = mean.copy()
    normal_out = facing / np.maximum(np.linalg.norm(facing, axis=1, keepdims=True), np.finfo(float).tiny)
    if flat.any():
        nbar = normal_sum[flat] / np.linalg.norm(normal_sum[flat], axis=1, keepdims=True)
        # The surface's height along the mean normal at the points' weighted centroid c, two ways: the
        # mean tangent plane (sum w n_i . (p_i - c) / sum w) and c itself. On a curved patch the tangent
        # planes pass outside the surface by ~k t^2 / 2 (t: a point's distance from c along the surface)
        # and the centroid lies inside by as much; their mean is on the surface to second order.
        # Coordinates are taken from the cell centre, not the grid origin, where the normals' spread
        # would lever a cell's worth of error.
        f = flat[cell]
        cf, wf, nf = cell[f], w[f], n[f]
        q = p[f] - centre[f]

        def acc_flat(values: np.ndarray) -> np.ndarray:
            return np.bincount(cf, weights=values, minlength=n_cells)[flat]

        wsum = weight[flat]
        c = np.stack([acc_flat(wf * q[:, i]) for i in range(3)], axis=1) / wsum[:, None]
        height = 0.5 * (acc_flat(wf * np.einsum("ij,ij->i", nf, q)) - np.einsum("ij,ij->i", normal_sum[flat], c)) / wsum
        # The vertex stays at the mean crossing m along the surface (the centroid drifts from the crease
        # of a face that ends in the cell), so the height is carried from c to m: the surface falls away
        # from its tangent plane by mu^T S mu / 2 over a tangential step mu, S the shape operator, fitted
        # from how the normals turn across the cell (n_i - nbar ~ S t_i, least squares). All of it lives
        # in the tangent plane, so it is worked in a 2-D basis (u, v) of it: 2 x 2 moments, and a closed-form
        # pseudo-inverse instead of a batched 3 x 3 one (a third of the reconstruction on a mug).
        u, v = _tangent_basis(nbar)
        m = _TangentMoments.of(_rows_of(cf, flat), q, nf, wf, u, v)
        # A cell whose points lie on one spot (one point; rounding leaves ~1e-24 m^2) pins no curvature:
        # spreads under a millionth of a cell are zero, not inverted.
        shape = m.normal_by_position @ _pinv_2x2(m.tuu, m.tuv, m.tvv, QEF_RELATIVE_EIGENVALUE,
                                                 wsum * (1e-6 * h) ** 2)
        cell_centre = band.position(_unravel(cell_keys[flat], dims)) + h / 2
        step = mean[flat] - cell_centre - c
        mu = np.stack([np.einsum("ij,ij->i", step, u), np.einsum("ij,ij->i", step, v)], axis=1)
        fall = 0.5 * np.einsum("ni,nij,nj->n", mu, shape, mu)
        # Noise along the surface lifts the points off a curved one: a point moved by t along the
        # tangent plane sits k t^2 / 2 above the surface, so isotropic noise of sigma puts the points'
        # mean sigma^2 H outside (H = (k1 + k2) / 2, the trace of the shape operator over 2). The
        # spread about the planes (``noise``) is taken as the spread along them too.
        lift = noise**2 * 0.5 * (shape[:, 0, 0] + shape[:, 1, 1])
        offset_m = height - fall - lift - np.einsum("ij,ij->i", nbar, step)
        moved = mean[flat] + nbar * offset_m[:, None]
        vertex[flat] = plane_only[flat] = moved
        normal_out[flat] = nbar
    if len(sharp):
        # Minimise the quadric about the mean crossing: x = m + A^+ (b - A m), small eigenvalues
        # dropped (the directions the planes do not pin down keep the mean).
        a_s, m_s = a[sharp], mean[sharp]
        inv = np.where(keep & (lam > 0), 1.0 / np.where(lam > 0, lam, 1.0), 0.0)
        along = np.einsum("nji,nj->ni", vec, rhs[sharp] - np.einsum("nij,nj->ni", a_s, m_s))
        vertex[sharp] = m_s + np.einsum("nij,nj->ni", vec, inv * along)
        # The planes' dominant direction, turned to agree with their mean: the normal at a crease is
        # not defined, but one direction is reported.
        top = vec[:, :, -1]
        normal_out[sharp] = top * np.where(np.einsum("ij,ij->i", top, normal_sum[sharp]) < 0, -1.0, 1.0)[:, None]
        # The same with only the dominant direction: the fallback where a crease solution leaves the cell.
        inv1 = np.zeros_like(inv)
        inv1[:, -1] = inv[:, -1]
        plane_only[sharp] = m_s + np.einsum("nij,nj->ni", vec, inv1 * along)

    low = band.origin + h * _unravel(cell_keys, dims) - VERTEX_SLACK_CELLS * h
    high = low + h * (1 + 2 * VERTEX_SLACK_CELLS)
    inside_full = ((vertex >= low) & (vertex <= high)).all(axis=1)
    inside_plane = ((plane_only >= low) & (plane_only <= high)).all(axis=1)
    out = np.where(inside_full[:, None], vertex, np.where(inside_plane[:, None], plane_only, mean))
    out[weight == 0] = mean[weight == 0]
    return out, weight > 0, normal_out, flat & (weight > 0)


def _gather(points: np.ndarray, normals: np.ndarray, band: Band, cell_keys: np.ndarray, noise: float
            ) -> tuple[np.ndarray, ...]:
    """Point-cell pairs whose plane counts for the cell: the cell lies within reach of the point's
    plane and within ``GATHER_RADIUS_CELLS`` of its normal line.

    Returns (cell, src, centre, line2): the cell's row in ``cell_keys``, the point's row, the cell
    centre (metres) and the squared distance from the centre to the line (m^2).
    """
    h = band.h
    dims = band.dims
    # The grid keeps several empty cells round the data (``grid.PAD_CELLS``), so every gathered
    # index is inside it and keys, linear in the index, do not wrap.
    node = np.rint((points - band.origin) / h).astype(np.int64)
    to_node = band.origin + h * node - points
    from_node = h * (GATHER_OFFSETS + 0.5)  # (g, 3): each candidate cell's centre from the node
    offset = np.einsum("ij,ij->i", normals, to_node)[:, None] + normals @ from_node.T  # (n, g)
    rel2 = ((to_node**2).sum(axis=1)[:, None] + 2.0 * to_node @ from_node.T + (from_node**2).sum(axis=1))
    line2 = rel2 - offset**2
    # A plane meets the cube of side h around a centre iff |n . (centre - p)| <= h/2 * sum |n_k|.
    # Noise moves planes off the surface both ways, and the window along the normal must hold that
    # spread on both sides of every cell: a narrower one keeps the planes the noise moved towards the
    # cell and biases each vertex towards it (at convex creases, outward).
    reach = h * (0.5 * np.abs(normals).sum(axis=1) + PLANE_MARGIN_CELLS) + NOISE_MARGIN_SIGMAS * noise
    src, g = np.nonzero((np.abs(offset) <= reach[:, None]) & (line2 <= (GATHER_RADIUS_CELLS * h) ** 2))
    node_key = (node[:, 0] * dims[1] + node[:, 1]) * dims[2] + node[:, 2]
    offset_key = (GATHER_OFFSETS[:, 0] * dims[1] + GATHER_OFFSETS[:, 1]) * dims[2] + GATHER_OFFSETS[:, 2]
    key = node_key[src] + offset_key[g]
    pos = np.minimum(np.searchsorted(cell_keys, key), len(cell_keys) - 1)
    hit = cell_keys[pos] == key
    src, g = src[hit], g[hit]
    centre = band.position(node[src] + GATHER_OFFSETS[g]) + h / 2
    return pos[hit], src, centre, line2[src, g]


def _turns_with_position(cells: np.ndarray, cell: np.ndarray, q: np.ndarray, n: np.ndarray, w: np.ndarray,
                         normal_sum: np.ndarray, noise: float, h: float) -> np.ndarray:
    """(len(cells),) bool: in each of ``cells`` the normals turn linearly with position (a curved patch)
    rather than jump from one face to another (a crease).

    The tangential part of the normals is fitted as a linear function of the points' tangential position
    (weighted least squares in the cell's tangent plane). On a curved patch that explains all of their
    spread but what noise in the positions hides: a share noise^2 / (the positions' spread per axis) of
    it, as errors in a regressor attenuate its fit. At a crease a line cannot follow the jump: at sigma
    1 mm a tetrahedron's crease cells left 0.6 to 1 of the spread unexplained, a 7 mm tube's cells 0.17 to
    0.45 with 0.2 to 0.5 expected from the noise. ``CURVED_MARGIN`` is the slack on top, and the
    turn must be gentle enough for one cell (``CURVED_MAX_TURN``).

    Args:
        cells: rows of the cells to test. cell, q, n, w: each gathered point's cell row, position from
            its cell's centre (metres), unit normal and weight. normal_sum: (c, 3) each cell's weighted
            normal sum. noise: the points' standard deviation about the surface, metres. h: cell size,
            metres.
    """
    if not len(cells):
        return np.zeros(0, dtype=bool)
    selected = np.zeros(len(normal_sum), dtype=bool)
    selected[cells] = True
    mine = selected[cell]
    u, v = _tangent_basis(normal_sum[cells] / np.linalg.norm(normal_sum[cells], axis=1, keepdims=True))
    m = _TangentMoments.of(_rows_of(cell[mine], selected), q[mine], n[mine], w[mine], u, v, with_spread=True)
    assert m.normal_spread is not None
    shape = m.normal_by_position @ _pinv_2x2(m.tuu, m.tuv, m.tvv, 1e-9)  # the fitted shape operator, 1/m
    explained = np.einsum("nij,nij->n", shape, m.normal_by_position)  # trace(N T^+ N^T)
    unexplained = 1.0 - explained / np.maximum(m.normal_spread, np.finfo(float).tiny)
    weight = np.maximum(m.weight, np.finfo(float).tiny)
    hidden_by_noise = np.minimum(noise**2 / np.maximum((m.tuu + m.tvv) / (2 * weight), np.finfo(float).tiny), 1.0)
    # A turn of more than about a radian per cell is no patch one vertex can follow: the rim of a wall
    # a cell thick (two creases in one cell) turns its normals half a circle, nearly linearly.
    gentle = np.sqrt((shape**2).sum(axis=(1, 2))) * h < CURVED_MAX_TURN
    return gentle & (unexplained < hidden_by_noise + CURVED_MARGIN)


@dataclass(frozen=True)
class _TangentMoments:
    """Weighted second moments of the points' normals and positions about their means, per cell, in each
    cell's tangent basis (u, v): what a linear fit of the normals' turn with position needs.

    Attributes:
        weight: (k,) sum of weights. normal_by_position: (k, 2, 2) [i, j] = sum w (n_i - mean)(q_j - mean).
        tuu, tuv, tvv: (k,) the positions' moments, m^2 (weighted sums). normal_spread: (k,) the
        tangential normals' summed variance (weighted sum), when asked for.
    """

    weight: np.ndarray
    normal_by_position: np.ndarray
    tuu: np.ndarray
    tuv: np.ndarray
    tvv: np.ndarray
    normal_spread: np.ndarray | None

    @classmethod
    def of(cls, row: np.ndarray, q: np.ndarray, n: np.ndarray, w: np.ndarray, u: np.ndarray,
           v: np.ndarray, *, with_spread: bool = False) -> _TangentMoments:
        """``row``: each point's cell (0..k-1); ``q`` (m, 3) positions from the cell centre, metres; ``n``
        (m, 3) unit normals; ``w`` (m,) weights; ``u``, ``v`` (k, 3) each cell's tangent basis;
        ``with_spread``: also ``normal_spread`` (None otherwise: the vertex fit has no use for it)."""
        k = len(u)
        ur, vr = u[row], v[row]
        qu, qv = np.einsum("ij,ij->i", q, ur), np.einsum("ij,ij->i", q, vr)
        nu, nv = np.einsum("ij,ij->i", n, ur), np.einsum("ij,ij->i", n, vr)

        def acc(values: np.ndarray) -> np.ndarray:
            return np.bincount(row, weights=values, minlength=k)

        weight = acc(w)
        safe = np.maximum(weight, np.finfo(float).tiny)
        squ, sqv, snu, snv = (acc(w * x) for x in (qu, qv, nu, nv))  # weighted sums per cell

        def cov(a: np.ndarray, sa: np.ndarray, b: np.ndarray, sb: np.ndarray) -> np.ndarray:
            return acc(w * a * b) - sa * sb / safe  # weighted sum of products about the means

        normal_by_position = np.stack([np.stack([cov(nu, snu, qu, squ), cov(nu, snu, qv, sqv)], axis=1),
                                       np.stack([cov(nv, snv, qu, squ), cov(nv, snv, qv, sqv)], axis=1)], axis=1)
        spread = cov(nu, snu, nu, snu) + cov(nv, snv, nv, snv) if with_spread else None
        return cls(weight, normal_by_position, cov(qu, squ, qu, squ), cov(qu, squ, qv, sqv), cov(qv, sqv, qv, sqv),
                   spread)


def _rows_of(cells: np.ndarray, selected: np.ndarray) -> np.ndarray:
    """Each of ``cells`` (rows of the full cell list, all ``selected``) as a row of the selected ones."""
    return (np.cumsum(selected) - 1)[cells]


def _tangent_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (c, 3) each, orthogonal to each other and to the unit ``normal`` (c, 3)."""
    helper = np.where(np.abs(normal[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(normal, u)


def _pinv_2x2(a: np.ndarray, b: np.ndarray, c: np.ndarray, rcond: float, floor: np.ndarray | float = 0.0
              ) -> np.ndarray:
    """Pseudo-inverses (k, 2, 2) of the symmetric positive semi-definite [[a, b], [b, c]] (each (k,)):
    eigenvalues at or below ``rcond`` times the largest, or ``floor``, are dropped (as
    ``np.linalg.pinv(..., hermitian=True)`` does with the first)."""
    half_trace = 0.5 * (a + c)
    radius = np.hypot(0.5 * (a - c), b)
    big, small = half_trace + radius, half_trace - radius
    cutoff = np.maximum(rcond * np.maximum(np.abs(big), np.abs(small)), floor)
    matrix = np.stack([np.stack([a, b], axis=1), np.stack([b, c], axis=1)], axis=1)
    eye = np.eye(2)
    both = (big > cutoff) & (small > cutoff)
    one = (big > cutoff) & ~both
    out = np.zeros_like(matrix)
    det = np.where(both, a * c - b * b, 1.0)
    adjugate = np.stack([np.stack([c, -b], axis=1), np.stack([-b, a], axis=1)], axis=1)
    out[both] = adjugate[both] / det[both, None, None]
    # One eigenvalue kept: (M - small I) / (big - small) projects onto its eigenvector.
    projector = (matrix[one] - small[one, None, None] * eye) / (big[one] - small[one])[:, None, None]
    out[one] = projector / big[one, None, None]
    return out


def _unravel(keys: np.ndarray, dims: np.ndarray) -> np.ndarray:
    rest, z = np.divmod(keys, dims[2])
    x, y = np.divmod(rest, dims[1])
    return np.stack([x, y, z], axis=1)
