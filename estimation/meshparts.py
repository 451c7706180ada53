"""A closed mesh's parts, and the union a mesh of overlapping parts means.

A mesh may hold several closed parts: an assembly exported as one file, a handle written over a mug's wall, or a
hollow object's outer shell with an inward-facing inner one. The signed sum over its faces (``inertia``) integrates
the winding number: right where shells nest (a cavity counts +1 - 1 = 0) or lie apart, but where two outward parts
overlap, the space they share counts twice. The solid such a mesh means is wherever some part is: the union of its
parts, each with the cavities inside it, which ``manifold3d`` computes on float64 vertices (:func:`overlap_union`).

An inward-facing part is a cavity only where it lies in solid; elsewhere (apart from every other part, or inside
another cavity) it would count space less than nothing: it is a part wound inside out, and is turned outward
(:func:`turned_outward`).

Finding the parts costs one pass over the faces (each function makes its own); nothing else is done unless a part
faces inward or outward parts' bounding boxes overlap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimation import tolerances as tol
from estimation.inertia import signed_volumes

#: Rows of the part-by-part bounding box test taken at a time: a mesh of 10,000 parts would need 10^8 pairs at once.
_BOX_BLOCK = 1024


@dataclass(frozen=True)
class Overlap:
    """What a mesh's overlapping closed parts share, and their union.

    Attributes:
        parts: the mesh's outward closed parts.
        overlapping: how many of them have a bounding box overlapping another's.
        shared: m^3 the faces' signed sum counts more than once (the sum less the union's volume); NaN when the
            union was not formed.
        vertices: (v, 3) float64 metres, the union's surface; None when it was not formed.
        faces: (f, 3) int64, outward; None when it was not formed.
        unresolved: why the union was not formed ("" when it was).
    """

    parts: int
    overlapping: int
    shared: float
    vertices: np.ndarray | None
    faces: np.ndarray | None
    unresolved: str = ""


@dataclass(frozen=True)
class Turned:
    """A mesh's parts wound inside out, turned outward.

    Attributes:
        faces: (f, 3) int64, the mesh's faces with each inside-out part's turned (its rows reversed).
        parts: how many inside-out parts were turned outward.
        total: the mesh's closed parts.
        volume: m^3 the turned parts enclose, less the cavities turned with them.
        cavities: how many outward parts inside those were turned inward with them, as their cavities.
    """

    faces: np.ndarray
    parts: int
    total: int
    volume: float
    cavities: int = 0

    @property
    def whole(self) -> bool:
        """Every part was turned: the mesh was wound inside out as a whole."""
        return self.parts + self.cavities == self.total


def part_labels(faces: np.ndarray, vertex_count: int) -> np.ndarray:
    """(f,) int: which part each face belongs to, numbered from 0, parts joined through shared edges.

    Faces that meet at a vertex only are not joined there: two closed solids touching at a corner (a cube with a
    tetrahedron inside it that reaches one of its corners) are two parts, whose overlap the signed sum counts twice.

    Args:
        faces: (f, 3) int64 indices into ``vertex_count`` vertices, duplicate vertices merged (a triangle soup,
            as STL stores it, is one part per face).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    count = len(faces)
    if not count:
        return np.zeros(0, dtype=np.int64)
    # Each face's three edges as sorted vertex pairs; sorted, an edge's faces lie next to each other.
    a, b = faces, np.roll(faces, -1, axis=1)
    key = (np.minimum(a, b) * np.int64(vertex_count) + np.maximum(a, b)).ravel()
    order = np.argsort(key)
    same = np.flatnonzero(key[order[1:]] == key[order[:-1]])
    graph = coo_matrix((np.ones(len(same), dtype=bool), (order[same] // 3, order[same + 1] // 3)), shape=(count, count))
    _, labels = connected_components(graph, directed=True, connection="weak")
    if (labels == labels[0]).all():  # the usual case: one part, no renumbering
        return np.zeros(count, dtype=np.int64)
    return np.unique(labels, return_inverse=True)[1].astype(np.int64)


@dataclass(frozen=True)
class _Parts:
    """A mesh's parts: each one's faces (a run of ``order``), bounds and signed volume."""

    count: int
    order: np.ndarray  # (f,) face indices, sorted by part
    starts: np.ndarray  # (count,) where each part's run of ``order`` starts
    ends: np.ndarray  # (count,) and ends
    low: np.ndarray  # (count, 3) metres, each part's bounding box
    high: np.ndarray
    volumes: np.ndarray  # (count,) m^3, signed: negative for an inward-facing part

    def faces_of(self, faces: np.ndarray, parts: list[int]) -> np.ndarray:
        return faces[np.concatenate([self.order[self.starts[p]:self.ends[p]] for p in parts])]


def _parts(vertices: np.ndarray, faces: np.ndarray) -> _Parts:
    labels = part_labels(faces, len(vertices))
    count = int(labels.max(initial=0)) + 1
    tri = vertices[faces]
    # Per-part bounds over sorted runs of faces: one reduceat, no loop over the parts.
    order = np.argsort(labels, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(labels[order]) != 0])
    low = np.minimum.reduceat(tri.min(axis=1)[order], starts, axis=0)
    high = np.maximum.reduceat(tri.max(axis=1)[order], starts, axis=0)
    # The centroid as apex: each closed part's volume is the same from any apex, and rounding least from near.
    volumes = np.bincount(labels, weights=signed_volumes(tri - vertices.mean(axis=0)), minlength=count)
    return _Parts(count, order, starts, np.r_[starts[1:], len(order)], low, high, volumes)


def turned_outward(vertices: np.ndarray, faces: np.ndarray) -> Turned | None:
    """The mesh with each part wound inside out turned outward; None when no part is.

    A part facing inward (its signed volume negative) is a cavity when the space around it is solid: when the
    parts holding it (a part holds another when their solids' intersection is all of the other's, to
    ``tol.MESH_OVERLAP_SHARE``) count at least 1, each outward one +1 and each cavity -1, the winding number just
    outside it. A hollow object's inner shell lies in its outer one (1): a cavity. A part that no part holds
    (0), or one inside a cavity (1 - 1 = 0), would make the space it bounds count less than nothing: it is a
    solid wound the wrong way, and is turned. Parts are judged largest first, so whatever holds a part has been
    judged before it (a part is smaller than what holds it). Outward parts are taken as they are: one inside
    another overlaps it (:func:`overlap_union`); but one whose nearest holder was turned was wound as that one
    was, and is turned with it, its cavity: a hollow object with every face turned has an inward outer shell and
    an outward inner one, which had filled the cavity (1.0 for 0.875 kg, a review's probe). Its outer shell
    alone turned, the inner one inward, it is turned as before: a hollow object whose cavity is in its place.

    Args:
        vertices: (v, 3) float64, metres.
        faces: (f, 3) int64, a closed, consistently wound mesh with duplicate vertices merged.

    Returns:
        The turned faces and what was turned, or None when no part faces inward where it cannot be a cavity (or
        manifold3d refuses it as not closed, so that whether a part holds it is not known).
    """
    if not len(faces):  # trimesh calls no faces closed; nothing to turn
        return None
    parts = _parts(vertices, faces)
    if not (parts.volumes < 0).any():
        return None
    sign = np.sign(parts.volumes)
    solids: dict[int, object] = {}

    def solid(part: int):  # type: ignore[no-untyped-def]  # the part's solid, whichever way it was wound
        if part not in solids:
            own = parts.faces_of(faces, [part])
            solids[part] = as_manifold(vertices, own if parts.volumes[part] > 0 else own[:, ::-1])
        return solids[part]

    turned, cavities = [], []
    is_turned = np.zeros(parts.count, dtype=bool)
    for part in np.argsort(-np.abs(parts.volumes), kind="stable"):
        part = int(part)
        boxes = ((parts.low <= parts.low[part]) & (parts.high[part] <= parts.high)).all(axis=1)
        boxes[part] = False
        outward = parts.volumes[part] >= 0
        if outward and not (boxes & is_turned).any():
            continue  # outward, in no turned part: as it is
        held_by: list[int] = []
        if boxes.any():
            inside = solid(part)
            candidates = [int(other) for other in np.flatnonzero(boxes)]
            holders = [solid(other) for other in candidates]
            if inside is None or any(outer is None for outer in holders):
                continue  # manifold3d refused one: whether it is held is not known, so it is left as it is
            held_by = [other for other, outer in zip(candidates, holders, strict=True) if _holds(outer, inside)]
        if outward:
            # In a part that was wound inside out, the part nearest round it (the smallest holding it): wound as
            # that one was, it is its cavity (a hollow object's mesh with every face turned).
            if held_by and is_turned[min(held_by, key=lambda other: abs(parts.volumes[other]))]:
                sign[part], is_turned[part] = -1.0, True
                cavities.append(part)
            continue
        if sum(sign[other] for other in held_by) < 1:
            sign[part], is_turned[part] = 1.0, True
            turned.append(part)
    if not turned:
        return None
    out = faces.copy()
    for part in turned + cavities:
        rows = parts.order[parts.starts[part]:parts.ends[part]]
        out[rows] = faces[rows, ::-1]
    return Turned(out, len(turned), parts.count, float(-parts.volumes[turned].sum() - parts.volumes[cavities].sum()),
                  cavities=len(cavities))


def overlap_union(vertices: np.ndarray, faces: np.ndarray) -> Overlap | None:
    """The union of the closed parts of a mesh when outward ones overlap, else None (the signed sum is right).

    Inward-facing parts are cavities: each belongs to the smallest outward part that holds it, and the union
    is taken of outward parts with their cavities, so a part crossing another's cavity fills it where it crosses.

    Args:
        vertices: (v, 3) float64, metres.
        faces: (f, 3) int64, a closed, consistently wound mesh with duplicate vertices merged.

    Returns:
        None for no faces or one part, for parts whose bounding boxes do not overlap, and for parts whose solids do not
        overlap though their boxes do (a rod through a ring, a ball in a cavity). Where the union cannot be
        formed (an inward part inside no outward part, which :func:`turned_outward` turns first; a part
        manifold3d refuses) the record says why, without a surface: whether the parts overlap is then not known.
    """
    if not len(faces):  # no part at all (a mesh whose faces merged away): nothing to unite
        return None
    parts = _parts(vertices, faces)
    if parts.count == 1:
        return None
    low, high, volumes = parts.low, parts.high, parts.volumes
    outward = np.flatnonzero(volumes > 0)
    touching = _overlapping_boxes(low[outward], high[outward])
    if not touching.any():
        return None

    import manifold3d

    def faces_of(members: list[int]) -> np.ndarray:  # each part's faces are one run of ``order``
        return parts.faces_of(faces, members)

    homes: dict[int, list[int]] = {int(part): [int(part)] for part in outward}
    for cavity in np.flatnonzero(volumes < 0):
        # The smallest outward part whose box holds the cavity's and whose solid holds the cavity turned outward.
        around = outward[((low[outward] <= low[cavity]) & (high[cavity] <= high[outward])).all(axis=1)]
        turned = as_manifold(vertices, faces_of([int(cavity)])[:, ::-1])
        if turned is None:
            return Overlap(len(outward), int(touching.sum()), float("nan"), None, None,
                           unresolved="manifold3d refused a part as not closed")
        home = next((int(part) for part in around[np.argsort(volumes[around])]
                     if _holds(as_manifold(vertices, faces_of([int(part)])), turned)), None)
        if home is None:  # turned_outward turns such a part first
            return Overlap(len(outward), int(touching.sum()), float("nan"), None, None,
                           unresolved="an inward-facing part lies inside no outward part (inside out?)")
        homes[home].append(int(cavity))
    solids = [as_manifold(vertices, faces_of(members)) for members in homes.values()]
    if any(s is None for s in solids):
        return Overlap(len(outward), int(touching.sum()), float("nan"), None, None,
                       unresolved="manifold3d refused a part as not closed")
    union = manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add)
    shared = float(volumes.sum()) - union.volume()
    if shared <= tol.MESH_OVERLAP_SHARE * union.volume():
        return None
    mesh = union.to_mesh64()
    return Overlap(parts=len(outward), overlapping=int(touching.sum()), shared=shared,
                   vertices=np.array(mesh.vert_properties[:, :3], dtype=np.float64),
                   faces=np.asarray(mesh.tri_verts, dtype=np.int64))


def as_manifold(vertices: np.ndarray, faces: np.ndarray):  # type: ignore[no-untyped-def]
    """The ``manifold3d.Manifold`` bounded by ``faces`` ((f, 3) int64 into ``vertices``, (v, 3) metres), or None
    when manifold3d refuses it (not closed)."""
    import manifold3d

    used, local = np.unique(faces, return_inverse=True)
    made = manifold3d.Manifold(manifold3d.Mesh64(np.ascontiguousarray(vertices[used]),
                                                 local.reshape(-1, 3).astype(np.uint64)))
    return made if made.status() == manifold3d.Error.NoError else None


def split_at_plane(vertices: np.ndarray, faces: np.ndarray, normal: np.ndarray, offset: float
                   ) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None:
    """The closed surface ``vertices`` (v, 3) metres, ``faces`` (f, 3) bounds, split by the plane
    ``normal . x + offset = 0`` (``normal`` (3,) unit) into the solids on its ``normal`` side and behind it, each
    closed across the cut as (vertices, faces) (no faces: nothing on that side); None when manifold3d refuses the
    surface (not closed).
    """
    solid = as_manifold(vertices, faces)
    if solid is None:
        return None
    front, back = solid.split_by_plane(np.asarray(normal, dtype=np.float64), -float(offset))

    def arrays(part) -> tuple[np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
        mesh = part.to_mesh64()
        return (np.array(mesh.vert_properties[:, :3], dtype=np.float64).reshape(-1, 3),
                np.asarray(mesh.tri_verts, dtype=np.int64).reshape(-1, 3))

    return arrays(front), arrays(back)


def _holds(outer, inner) -> bool:  # type: ignore[no-untyped-def]
    """True when the solid ``inner`` lies within ``outer`` (their intersection is all of it, to rounding)."""
    return outer is not None and (outer ^ inner).volume() >= inner.volume() * (1 - tol.MESH_OVERLAP_SHARE)


def _overlapping_boxes(low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """(k,) bool: which of the k boxes (``low``, ``high``: (k, 3) metres) overlap another with some volume.

    Boxes that only share a face (parts side by side) do not count: their parts cannot overlap.
    """
    found = np.zeros(len(low), dtype=bool)
    for start in range(0, len(low), _BOX_BLOCK):  # a loop over blocks of rows, not rows
        rows = slice(start, start + _BOX_BLOCK)
        meet = ((low[rows, None] < high[None]) & (low[None] < high[rows, None])).all(axis=2)
        meet[np.arange(meet.shape[0]), np.arange(start, start + meet.shape[0])] = False  # not itself
        found[rows] = meet.any(axis=1)
    return found
