"""A seeded set of varied test shapes with exact mass properties: what `auto` was never tuned on.

Each shape is a closed, consistently wound mesh built with trimesh primitives and manifold3d booleans;
its volume, centre of mass and inertia are those of that polyhedral mesh (exact: trimesh integrates
over the mesh itself, so curved shapes are compared with their faceted truth, not the ideal solid).

Families (``FAMILIES``): thin shells and plates (1-3 mm walls, open cups, trays, tubes, bowls, brackets),
low-poly polyhedra with sharp creases (random hulls, prisms, stars, platonic solids), concave shapes
with handles and through-holes (mugs, frames, drilled blocks, unions of boxes), smooth ones, and
elongated or flat ones. Sizes run from 1 cm to 1 m. Thin walls are only put on objects of 4-15 cm:
at the benchmark's point counts a 1 mm wall on a 1 m object is far below the point spacing, and
that case is what the estimate's warnings are for, not a volume target.

Every shape is placed at a random rotation and translation (seeded) so nothing lines up with a grid.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

FAMILIES = ("thin", "crease", "concave", "smooth", "elongated")


@dataclass(frozen=True)
class Shape:
    """One generated test object.

    Attributes:
        name: unique, e.g. ``"thin-cup-03"``.
        family: one of ``FAMILIES``.
        mesh: closed mesh, metres, already at its random pose.
        min_wall: thinnest wall or plate, metres (the smallest extent for solid shapes).
    """

    name: str
    family: str
    mesh: trimesh.Trimesh
    min_wall: float

    @property
    def volume(self) -> float:
        return float(self.mesh.volume)

    @property
    def center_of_mass(self) -> np.ndarray:
        return np.asarray(self.mesh.center_mass)

    def inertia(self, density: float) -> np.ndarray:
        """(3, 3) kg m^2 about the centre of mass, world axes."""
        return np.asarray(self.mesh.moment_inertia) * density


def surface_scene(mesh: trimesh.Trimesh):  # type: ignore[no-untyped-def]
    """An Open3D ray-casting scene of ``mesh`` (float32, its own frame): closest points, face ids and signed
    distances (negative inside) of query points, for measuring an estimate against a true surface."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)), o3d.core.Tensor(mesh.faces.astype(np.uint32)))
    return scene


def inside_out(mesh: trimesh.Trimesh, points: np.ndarray, normals: np.ndarray) -> float:
    """The share of oriented ``normals`` ((n, 3), at ``points``, metres, the mesh's frame) that point into the closed
    ``mesh``: each against the outward normal of the mesh's face nearest its point."""
    import open3d as o3d

    face = surface_scene(mesh).compute_closest_points(o3d.core.Tensor(np.asarray(points, np.float32)))["primitive_ids"].numpy()
    return float(np.mean(np.einsum("ij,ij->i", np.asarray(normals), mesh.face_normals[face]) < 0))


def _box(extents, center=(0.0, 0.0, 0.0)) -> trimesh.Trimesh:  # type: ignore[no-untyped-def]
    return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(center))


def _cyl(radius: float, height: float, center=(0.0, 0.0, 0.0), sections: int = 96) -> trimesh.Trimesh:  # type: ignore[no-untyped-def]
    c = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
    c.apply_translation(center)
    return c


def _union(*meshes: trimesh.Trimesh) -> trimesh.Trimesh:
    return trimesh.boolean.union(list(meshes), engine="manifold")


def _diff(a: trimesh.Trimesh, *b: trimesh.Trimesh) -> trimesh.Trimesh:
    return trimesh.boolean.difference([a, *b], engine="manifold")


def _extrude(polygon: np.ndarray, height: float) -> trimesh.Trimesh:
    """Prism of a simple 2-D polygon ((k, 2), either winding) from z = 0 to ``height``."""
    import manifold3d

    ring = np.asarray(polygon, dtype=np.float64)
    x, y = ring[:, 0], ring[:, 1]
    if (x * np.roll(y, -1) - np.roll(x, -1) * y).sum() < 0:
        ring = ring[::-1]
    solid = manifold3d.Manifold.extrude(manifold3d.CrossSection([ring]), height).to_mesh()
    return trimesh.Trimesh(np.asarray(solid.vert_properties)[:, :3], np.asarray(solid.tri_verts), process=True)


# ---- thin shells and plates (walls 1-3 mm, objects 4-15 cm) -------------------------------------------

def _thin_cup(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    wall = rng.uniform(1e-3, 3e-3)
    r, h = rng.uniform(0.025, 0.05), rng.uniform(0.05, 0.12)
    outer = _cyl(r, h)
    inner = _cyl(r - wall, h, center=(0, 0, wall + 1e-3))  # floor of one wall; pokes through the rim
    return _diff(outer, inner), wall


def _thin_tray(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    wall = rng.uniform(1e-3, 3e-3)
    a, b, c = rng.uniform(0.06, 0.15), rng.uniform(0.04, 0.10), rng.uniform(0.015, 0.05)
    inner = _box((a - 2 * wall, b - 2 * wall, c), center=(0, 0, wall))
    return _diff(_box((a, b, c)), inner), wall


def _thin_tube(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    wall = rng.uniform(1.5e-3, 3e-3)
    r, h = rng.uniform(0.015, 0.035), rng.uniform(0.06, 0.14)
    return _diff(_cyl(r, h), _cyl(r - wall, h + 0.01)), wall


def _thin_bowl(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    wall = rng.uniform(1.5e-3, 3e-3)
    r = rng.uniform(0.03, 0.06)
    outer = trimesh.creation.icosphere(subdivisions=4, radius=r)
    inner = trimesh.creation.icosphere(subdivisions=4, radius=r - wall)
    cut = _box((3 * r, 3 * r, 2 * r), center=(0, 0, r * rng.uniform(0.9, 1.1) - r * 0.3))
    return _diff(outer, inner, cut), wall


def _thin_plate(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    wall = rng.uniform(1e-3, 3e-3)
    plate = _box((rng.uniform(0.05, 0.15), rng.uniform(0.04, 0.10), wall))
    holes = [_cyl(rng.uniform(0.004, 0.01), 0.02, center=(x, 0, 0), sections=48)
             for x in rng.uniform(-0.015, 0.015, size=int(rng.integers(0, 3)))]
    return (_diff(plate, *holes) if holes else plate), wall


def _thin_bracket(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    wall = rng.uniform(1.5e-3, 3e-3)
    a, b, w = rng.uniform(0.04, 0.10), rng.uniform(0.03, 0.08), rng.uniform(0.02, 0.05)
    return _union(_box((a, w, wall), center=(a / 2, 0, wall / 2)),
                  _box((wall, w, b), center=(wall / 2, 0, b / 2))), wall


# ---- low-poly polyhedra with sharp creases ---------------------------------------------------------

def _random_hull(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    pts = rng.normal(size=(int(rng.integers(6, 16)), 3)) * rng.uniform(0.5, 1.5, size=3)
    hull = trimesh.convex.convex_hull(pts)
    return hull, 0.0


def _prism(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    n = int(rng.integers(3, 9))
    angles = np.sort(rng.uniform(0, 2 * np.pi, n)) if rng.random() < 0.5 else np.linspace(0, 2 * np.pi, n + 1)[:-1]
    poly = np.c_[np.cos(angles), np.sin(angles)]
    return _extrude(poly, rng.uniform(0.3, 2.0)), 0.0


def _star(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    n = int(rng.integers(4, 8))
    angles = np.linspace(0, 2 * np.pi, 2 * n + 1)[:-1]
    radius = np.where(np.arange(2 * n) % 2 == 0, 1.0, rng.uniform(0.4, 0.7))
    return _extrude(np.c_[radius * np.cos(angles), radius * np.sin(angles)], rng.uniform(0.2, 0.8)), 0.0


def _platonic(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    kind = ["tetra", "octa", "icosa", "cube", "dodeca"][int(rng.integers(0, 5))]
    if kind == "icosa":
        return trimesh.creation.icosahedron(), 0.0
    if kind == "cube":
        return _box((1, 1, 1)), 0.0
    if kind == "octa":
        pts = np.vstack([np.eye(3), -np.eye(3)])
    elif kind == "tetra":
        pts = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
    else:  # dodecahedron: the dual of the icosahedron, its face centres
        pts = trimesh.creation.icosahedron().triangles_center
    return trimesh.convex.convex_hull(pts), 0.0


def _wedge(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    # A sharp wedge (20-60 degrees): the knife edge is the hardest crease to keep.
    angle = np.radians(rng.uniform(20, 60))
    length = 1.0
    tri = np.array([(0, 0), (length, 0), (length, length * np.tan(angle))])
    return _extrude(tri, rng.uniform(0.3, 1.0)), 0.0


# ---- concave, handles and holes ---------------------------------------------------------------------

def _mug(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    r, h = rng.uniform(0.03, 0.045), rng.uniform(0.07, 0.11)
    wall = rng.uniform(3e-3, 6e-3)
    body = _diff(_cyl(r, h), _cyl(r - wall, h, center=(0, 0, wall + 1e-3)))
    handle = trimesh.creation.torus(major_radius=h * 0.3, minor_radius=rng.uniform(0.004, 0.007),
                                    major_sections=64, minor_sections=24)
    handle.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    handle.apply_translation([r + h * 0.15, 0, 0])
    return _union(body, handle), wall


def _frame(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    a, b, c = rng.uniform(0.6, 1.0), rng.uniform(0.5, 0.9), rng.uniform(0.1, 0.3)
    bar = rng.uniform(0.08, 0.15)
    return _diff(_box((a, b, c)), _box((a - 2 * bar, b - 2 * bar, 2 * c))), min(bar, c)


def _drilled(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    extents = np.array([1.0, rng.uniform(0.5, 0.9), rng.uniform(0.3, 0.6)])
    block = _box(tuple(extents))
    holes, bores = [], []
    for _ in range(int(rng.integers(1, 4))):
        radius = rng.uniform(0.05, 0.12)
        hole = _cyl(radius, 3.0, sections=64)
        axis = int(rng.integers(0, 3))
        if axis < 2:
            # A cylinder's axis is z; a quarter turn about x puts it along y, about y along x.
            hole.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, np.eye(3)[axis]))
        centre = rng.uniform(-0.2, 0.2, 3)
        hole.apply_translation(centre)
        holes.append(hole)
        bores.append((1 - axis if axis < 2 else 2, centre, radius))
    return _diff(block, *holes), _drilled_wall(extents, bores)


def _drilled_wall(extents: np.ndarray, bores: list[tuple[int, np.ndarray, float]]) -> float:
    """The thinnest wall of a block of ``extents`` (centred) drilled through by ``bores`` (axis index, a point on
    the axis, radius): a bore passing near a face or another bore leaves a sliver (seed 1's concave-drilled-35:
    its smallest extent, 19.9 mm, was taken for its wall). Bores that break through a face or each other leave
    no wall there."""
    gaps = [float(min(extents))]
    for k, (axis, centre, radius) in enumerate(bores):
        for d in range(3):
            if d != axis:  # to the two faces on either side of the bore
                gaps += [extents[d] / 2 - centre[d] - radius, extents[d] / 2 + centre[d] - radius]
        for other_axis, other_centre, other_radius in bores[:k]:
            offset = centre - other_centre
            if axis == other_axis:  # parallel: the distance between the axes across them
                apart = float(np.linalg.norm(np.delete(offset, axis)))
            else:  # crossing at right angles: their separation along the third axis
                apart = abs(float(offset[3 - axis - other_axis]))
            gaps.append(apart - radius - other_radius)
    return min(g for g in gaps if g > 0)


def _box_union(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    boxes = [_box(rng.uniform(0.15, 0.6, 3), center=rng.uniform(-0.2, 0.2, 3)) for _ in range(int(rng.integers(2, 5)))]
    merged = _union(*boxes)
    return merged.split(only_watertight=True)[0] if merged.body_count > 1 else merged, 0.0


def _l_shape(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    t = rng.uniform(0.1, 0.3)
    return _union(_box((1.0, t, t), center=(0.5, 0, 0)), _box((t, 1.0, t), center=(0, 0.5, 0)),
                  _box((t, t, rng.uniform(0.3, 0.8)), center=(0, 0, 0.2))), 0.0


# ---- smooth -------------------------------------------------------------------------------------

def _ellipsoid(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    s = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
    s.apply_scale(rng.uniform(0.5, 1.0, 3))
    return s, 0.0


def _capsule(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    return trimesh.creation.capsule(height=rng.uniform(0.5, 2.0), radius=rng.uniform(0.2, 0.5), count=[64, 64]), 0.0


def _torus(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    return trimesh.creation.torus(major_radius=1.0, minor_radius=rng.uniform(0.2, 0.5),
                                  major_sections=128, minor_sections=48), 0.0


def _blob(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    s = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
    d = s.vertices
    bumps = sum(a * np.exp(-((d @ c - 1) ** 2) * 4) for a, c in
                zip(rng.uniform(-0.2, 0.3, 4), rng.normal(size=(4, 3)) / np.sqrt(3), strict=True))
    s.vertices = d * (1 + bumps)[:, None]
    return s, 0.0


# ---- elongated and flat -----------------------------------------------------------------------------

def _rod(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    r = rng.uniform(0.03, 0.08)
    rod = _cyl(r, 1.0, sections=64) if rng.random() < 0.5 else _box((r * 2, r * 1.5, 1.0))
    return rod, r


def _disc(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    t = rng.uniform(0.06, 0.15)
    return (_cyl(1.0, t, sections=128) if rng.random() < 0.5 else _box((1.0, 0.8, t))), t


@dataclass(frozen=True)
class _Recipe:
    family: str
    kind: str
    make: Callable[[np.random.Generator], tuple[trimesh.Trimesh, float]]
    size: tuple[float, float]  # longest side, metres (None-scaled recipes keep their own size)


#: (family, kind, maker, size range in metres of the longest side; (0, 0) keeps the maker's own size).
_RECIPES = (
    _Recipe("thin", "cup", _thin_cup, (0, 0)),
    _Recipe("thin", "tray", _thin_tray, (0, 0)),
    _Recipe("thin", "tube", _thin_tube, (0, 0)),
    _Recipe("thin", "bowl", _thin_bowl, (0, 0)),
    _Recipe("thin", "plate", _thin_plate, (0, 0)),
    _Recipe("thin", "bracket", _thin_bracket, (0, 0)),
    _Recipe("crease", "hull", _random_hull, (0.01, 0.5)),
    _Recipe("crease", "prism", _prism, (0.02, 0.6)),
    _Recipe("crease", "star", _star, (0.03, 0.4)),
    _Recipe("crease", "platonic", _platonic, (0.01, 0.3)),
    _Recipe("crease", "wedge", _wedge, (0.03, 0.3)),
    _Recipe("concave", "mug", _mug, (0, 0)),
    _Recipe("concave", "frame", _frame, (0.05, 1.0)),
    _Recipe("concave", "drilled", _drilled, (0.04, 1.0)),
    _Recipe("concave", "boxes", _box_union, (0.03, 0.8)),
    _Recipe("concave", "ell", _l_shape, (0.03, 0.6)),
    _Recipe("smooth", "ellipsoid", _ellipsoid, (0.01, 0.4)),
    _Recipe("smooth", "capsule", _capsule, (0.02, 0.5)),
    _Recipe("smooth", "torus", _torus, (0.03, 0.5)),
    _Recipe("smooth", "blob", _blob, (0.02, 0.3)),
    _Recipe("elongated", "rod", _rod, (0.05, 1.0)),
    _Recipe("elongated", "disc", _disc, (0.05, 1.0)),
)


def make_shapes(count: int = 44, seed: int = 0) -> list[Shape]:
    """``count`` shapes cycling through the recipes, each with seeded size, proportions and pose.

    The same ``(count, seed)`` gives the same shapes, and the first ``k`` of a longer list are the
    ``k`` of a shorter one (so a test can take a subset of the benchmark).
    """
    shapes = []
    for i in range(count):
        recipe = _RECIPES[i % len(_RECIPES)]
        rng = np.random.default_rng([seed, i])
        mesh, wall = recipe.make(rng)
        if recipe.size != (0, 0):
            low, high = recipe.size
            size = float(np.exp(rng.uniform(np.log(low), np.log(high))))
            scale = size / float(mesh.extents.max())
            mesh.apply_scale(scale)
            wall *= scale
        if not wall:
            wall = float(min(mesh.extents))
        _place(mesh, rng, f"shape {recipe.kind} {i}")
        shapes.append(Shape(f"{recipe.family}-{recipe.kind}-{i:02d}", recipe.family, mesh, float(wall)))
    return shapes


def _place(mesh: trimesh.Trimesh, rng: np.random.Generator, what: str) -> None:
    """Check ``mesh`` is a closed solid, then move it (in place) to a seeded random pose within 1 m of the origin."""
    if not (mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0):
        raise RuntimeError(f"generated {what} is not a closed solid")
    pose = np.eye(4)
    pose[:3, :3] = Rotation.random(random_state=int(rng.integers(2**31))).as_matrix()
    pose[:3, 3] = rng.uniform(-1.0, 1.0, 3)
    mesh.apply_transform(pose)


# ---- hollow objects whose air the flood fill encloses (bench/hollows.py, tests/test_thin_walls.py) ---------

def hollow_ball(radius: float, wall: float, hole: float = 0.0) -> trimesh.Trimesh:
    """A ball ``wall`` thick (metres) with a round opening of radius ``hole`` at its top (closed when 0)."""
    outer = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    inner = trimesh.creation.icosphere(subdivisions=4, radius=radius - wall)
    if not hole:
        return _diff(outer, inner)
    bore = trimesh.creation.cylinder(radius=hole, height=radius)
    bore.apply_translation((0.0, 0.0, radius))
    return _diff(outer, inner, bore)


def closed_box(wall: float) -> trimesh.Trimesh:
    """A 100 x 70 x 50 mm box, ``wall`` thick (metres), closed all round."""
    return _diff(trimesh.creation.box(extents=(0.1, 0.07, 0.05)),
                 trimesh.creation.box(extents=(0.1 - 2 * wall, 0.07 - 2 * wall, 0.05 - 2 * wall)))


def bottle() -> trimesh.Trimesh:
    """220 mm tall, 3 mm walls, a 20 mm mouth on a 70 mm body."""
    profile = np.array([(0, 0), (35, 0), (35, 160), (13, 200), (13, 220), (10, 220), (10, 200), (32, 160), (32, 3),
                        (0, 3)], float) * 1e-3
    return trimesh.creation.revolve(profile, sections=64)


def open_pipe() -> trimesh.Trimesh:
    """600 mm long, 60 mm across, 3 mm walls, open at both ends."""
    return trimesh.creation.annulus(r_min=0.027, r_max=0.03, height=0.6, sections=64)


# ---- parts near the noise limit: 3-5 mm wires, fins, teeth and slots, not in ``make_shapes`` ---------------

def coil(wire: float, radius: float, turns: float, pitch: float, sections: int = 24) -> trimesh.Trimesh:
    """A closed helical spring, metres: a round ``wire`` (diameter) swept along a helix about z, ends capped."""
    t = np.linspace(0.0, 2 * np.pi * turns, int(100 * turns))
    path = np.c_[radius * np.cos(t), radius * np.sin(t), pitch * t / (2 * np.pi)]
    tangent = np.gradient(path, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    u = np.cross(tangent, (0.0, 0.0, 1.0))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(tangent, u)
    a = np.linspace(0.0, 2 * np.pi, sections, endpoint=False)
    ring = np.cos(a)[None, :, None] * u[:, None] + np.sin(a)[None, :, None] * v[:, None]
    vertices = np.vstack([(path[:, None] + wire / 2 * ring).reshape(-1, 3), path[0], path[-1]])
    i, j = np.meshgrid(np.arange(len(path) - 1), np.arange(sections), indexing="ij")
    p, q = (i * sections + j).ravel(), (i * sections + (j + 1) % sections).ravel()
    j = np.arange(sections)
    end = (len(path) - 1) * sections
    faces = np.vstack([np.c_[p, p + sections, q], np.c_[q, p + sections, q + sections],
                       np.c_[np.full(sections, len(vertices) - 2), j, (j + 1) % sections],
                       np.c_[np.full(sections, len(vertices) - 1), end + (j + 1) % sections, end + j]])
    mesh = trimesh.Trimesh(vertices, faces)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def _coil(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    wire = rng.uniform(0.003, 0.005)
    return coil(wire, rng.uniform(0.01, 0.02), rng.uniform(2.5, 4.5), wire + rng.uniform(0.004, 0.008)), wire


def _comb(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    tooth, gap, thick = rng.uniform(0.003, 0.005), rng.uniform(0.003, 0.006), rng.uniform(0.003, 0.006)
    n, length = int(rng.integers(5, 10)), rng.uniform(0.015, 0.03)
    width = n * (tooth + gap)
    parts = [_box((width, 0.006, thick), (width / 2, 0, 0))]
    parts += [_box((tooth, length, thick), (i * (tooth + gap) + tooth / 2, 0.003 + length / 2 - 5e-4, 0)) for i in range(n)]
    return _union(*parts), min(tooth, thick)


def _heatsink(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    fin, gap, base = rng.uniform(0.003, 0.004), rng.uniform(0.004, 0.007), rng.uniform(0.004, 0.006)
    n, height, depth = int(rng.integers(4, 8)), rng.uniform(0.015, 0.03), rng.uniform(0.03, 0.05)
    width = n * fin + (n - 1) * gap
    parts = [_box((width, depth, base), (width / 2, 0, base / 2))]
    parts += [_box((fin, depth, height), (i * (fin + gap) + fin / 2, 0, base + height / 2 - 5e-4)) for i in range(n)]
    return _union(*parts), min(fin, base)


def _slotted(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    side, height, slot = rng.uniform(0.04, 0.08), rng.uniform(0.02, 0.04), rng.uniform(0.003, 0.006)
    n = int(rng.integers(2, 6))
    cuts = [_box((slot, 2 * side, height), (-side / 2 + (i + 1) * side / (n + 1), 0, height / 2)) for i in range(n)]
    return _diff(_box((side, side, height)), *cuts), side / (n + 1) - slot


def _pipe(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    radius, wall, length = rng.uniform(0.01, 0.03), rng.uniform(0.003, 0.005), rng.uniform(0.04, 0.1)
    return _diff(_cyl(radius, length), _cyl(radius - wall, 2 * length)), wall


def _wire_ring(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    wire = rng.uniform(0.003, 0.005)
    return trimesh.creation.torus(rng.uniform(0.01, 0.025), wire / 2, major_sections=96, minor_sections=24), wire


def _nut(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    across, height = rng.uniform(0.012, 0.03), rng.uniform(0.005, 0.012)
    bore = across * rng.uniform(0.4, 0.6)
    a = np.linspace(0, 2 * np.pi, 7)[:-1]
    hexagon = np.c_[np.cos(a), np.sin(a)] * across / np.sqrt(3)
    return _diff(_extrude(hexagon, height), _cyl(bore / 2, 3 * height, sections=64)), min(height, (across - bore) / 2)


def _stool(rng: np.random.Generator) -> tuple[trimesh.Trimesh, float]:
    leg, side = rng.uniform(0.004, 0.006), rng.uniform(0.04, 0.07)
    parts = [_box((side, side, leg), (0, 0, side))]
    parts += [_box((leg, leg, side), (x * (side - leg) / 2, y * (side - leg) / 2, side / 2)) for x in (-1, 1) for y in (-1, 1)]
    return _union(*parts), leg


#: Parts whose thinnest feature is 3-6 mm: at sigma 0.5 mm noise, six to twelve sigmas.
_PARTS = (_coil, _comb, _heatsink, _slotted, _pipe, _wire_ring, _nut, _stool)


def make_parts(count: int = 16, seed: int = 0) -> list[Shape]:
    """``count`` seeded parts near the noise limit (wires, fins, teeth, slots, 3-6 mm), at random poses."""
    shapes = []
    for i in range(count):
        make = _PARTS[i % len(_PARTS)]
        rng = np.random.default_rng([seed, 1000 + i])
        mesh, wall = make(rng)
        _place(mesh, rng, f"part {make.__name__} {i}")
        shapes.append(Shape(f"part-{make.__name__.strip('_').replace('_', '-')}-{i:02d}", "part", mesh, float(wall)))
    return shapes
