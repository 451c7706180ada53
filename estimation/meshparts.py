"""A closed mesh's parts, and the union a mesh of overlapping parts means.

A mesh may hold several closed parts: an assembly exported as one file, a handle written over a mug's wall, or a
hollow object's outer shell with an inward-facing inner one. The signed sum over its faces (``inertia``) integrates
the winding number: right where shells nest (a cavity counts +1 - 1 = 0) or lie apart, but where two outward parts
overlap, the space they share counts twice. The solid such a mesh means is wherever some part is: the union of its
parts, each with the cavities inside it, which ``manifold3d`` computes on float64 vertices.

Finding the parts costs one pass over the faces; nothing else is done unless outward parts' bounding boxes overlap.
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


def part_labels(faces: np.ndarray, vertex_count: int) -> np.ndarray:
    """(f,) int: which part each face belongs to, numbered from 0, parts joined through shared vertices.

    Args:
        faces: (f, 3) int64 indices into ``vertex_count`` vertices, duplicate vertices merged (a triangle soup,
            as STL stores it, is one part per face).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    # Two edges a face join its three vertices; directed, 'weak' needs no symmetric copy (~20 ms for 330k faces).
    edges = coo_matrix((np.ones(2 * len(faces), dtype=bool), (faces[:, :2].ravel(), faces[:, 1:].ravel())),
                       shape=(vertex_count, vertex_count))
    _, labels = connected_components(edges, directed=True, connection="weak")
    by_face = labels[faces[:, 0]]
    if by_face.size and (by_face == by_face[0]).all():  # the usual case: one part, no renumbering
        return np.zeros(len(faces), dtype=np.int64)
    return np.unique(by_face, return_inverse=True)[1].astype(np.int64)  # vertices no face uses are no part


def overlap_union(vertices: np.ndarray, faces: np.ndarray) -> Overlap | None:
    """The union of the closed parts of a mesh when outward ones overlap, else None (the signed sum is right).

    Inward-facing parts are cavities: each belongs to the smallest outward part that holds it, and the union
    is taken of outward parts with their cavities, so a part crossing another's cavity fills it where it crosses.

    Args:
        vertices: (v, 3) float64, metres.
        faces: (f, 3) int64, a closed, consistently wound mesh with duplicate vertices merged.

    Returns:
        None for one part, for parts whose bounding boxes do not overlap, and for parts whose solids do not
        overlap though their boxes do (a rod through a ring, a ball in a cavity). Where the union cannot be
        formed (an inward part inside no outward part, a part manifold3d refuses) the record says why, without
        a surface: whether the parts overlap is then not known.
    """
    labels = part_labels(faces, len(vertices))
    count = int(labels.max(initial=0)) + 1
    if count == 1:
        return None
    tri = vertices[faces]
    # Per-part bounds over sorted runs of faces: one reduceat, no loop over the parts.
    order = np.argsort(labels, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(labels[order]) != 0])
    low = np.minimum.reduceat(tri.min(axis=1)[order], starts, axis=0)
    high = np.maximum.reduceat(tri.max(axis=1)[order], starts, axis=0)
    # The centroid as apex: each closed part's volume is the same from any apex, and rounding least from near.
    volumes = np.bincount(labels, weights=signed_volumes(tri - vertices.mean(axis=0)), minlength=count)
    outward = np.flatnonzero(volumes > 0)
    touching = _overlapping_boxes(low[outward], high[outward])
    if not touching.any():
        return None

    import manifold3d

    ends = np.r_[starts[1:], len(order)]

    def faces_of(parts: list[int]) -> np.ndarray:  # each part's faces are one run of ``order``
        return faces[np.concatenate([order[starts[p]:ends[p]] for p in parts])]

    homes: dict[int, list[int]] = {int(part): [int(part)] for part in outward}
    for cavity in np.flatnonzero(volumes < 0):
        # The smallest outward part whose box holds the cavity's and whose solid holds the cavity turned outward.
        around = outward[((low[outward] <= low[cavity]) & (high[cavity] <= high[outward])).all(axis=1)]
        turned = _solid(vertices, faces_of([int(cavity)])[:, ::-1])
        home = next((int(part) for part in around[np.argsort(volumes[around])]
                     if turned is not None and _holds(_solid(vertices, faces_of([int(part)])), turned)), None)
        if home is None:
            return Overlap(len(outward), int(touching.sum()), float("nan"), None, None,
                           unresolved="an inward-facing part lies inside no outward part (inside out?)")
        homes[home].append(int(cavity))
    solids = [_solid(vertices, faces_of(members)) for members in homes.values()]
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


def _solid(vertices: np.ndarray, faces: np.ndarray):  # type: ignore[no-untyped-def]
    """The ``manifold3d.Manifold`` bounded by ``faces`` ((f, 3) int64 into ``vertices``, (v, 3) metres), or None
    when manifold3d refuses it (not closed)."""
    import manifold3d

    used, local = np.unique(faces, return_inverse=True)
    made = manifold3d.Manifold(manifold3d.Mesh64(np.ascontiguousarray(vertices[used]),
                                                 local.reshape(-1, 3).astype(np.uint64)))
    return made if made.status() == manifold3d.Error.NoError else None


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
