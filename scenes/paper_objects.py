"""The paper's eight test objects as watertight meshes with exactly its expected volumes.

The paper names the shapes and their volumes (``shared/paper/table1_obb.csv``) but not their dimensions.
Ours are chosen so the OBB errors the shape fixes come out as the paper's (cylinder 4/pi - 1 = 27 %,
bridge 50 %, box ~0 %), then each mesh is scaled uniformly so its volume equals the expected value
exactly: the polygonal approximation of round shapes loses ~0.01 % otherwise.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

#: Expected volumes from the paper's Table 1, m^3 (rotation 0 rows).
EXPECTED_VOLUME_M3: dict[str, float] = {
    "box": 20250.00e-6,
    "cylinder": 7901.16e-6,
    "cone": 4581.66e-6,
    "torus": 10846.60e-6,
    "chunk": 66000.00e-6,
    "mug": 46941.40e-6,
    "stack": 129803.00e-6,
    "bridge": 512000.00e-6,
}

#: The paper's rotations, degrees.
ROTATIONS_DEG = (0, 7, 45)

#: Segments around round shapes: enough that the facets are ~1 mm on a 20 cm radius.
_SECTIONS = 128


def _box(extents: tuple[float, float, float], center: tuple[float, float, float] = (0, 0, 0)) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(center))


def _union(*meshes: trimesh.Trimesh) -> trimesh.Trimesh:
    return trimesh.boolean.union(list(meshes), engine="manifold")


def _difference(a: trimesh.Trimesh, *b: trimesh.Trimesh) -> trimesh.Trimesh:
    return trimesh.boolean.difference([a, *b], engine="manifold")


def _make_box() -> trimesh.Trimesh:
    # Three well-separated sides, so the moment-of-inertia axes are the box's own: with near-equal
    # sides the two eigenvalues nearly tie and sampling noise turns the OBB.
    return _box((0.45, 0.30, 0.15))


def _make_cylinder() -> trimesh.Trimesh:
    return trimesh.creation.cylinder(radius=0.10, height=0.2515, sections=_SECTIONS)


def _make_cone() -> trimesh.Trimesh:
    cone = trimesh.creation.cone(radius=0.125, height=0.28, sections=_SECTIONS)
    cone.apply_translation([0, 0, -0.07])  # centroid of a cone is at h/4
    return cone


def _make_torus() -> trimesh.Trimesh:
    # R/r = 4.2 gives the paper's ~160 % OBB error: (2(R+r))^2 2r / (2 pi^2 R r^2).
    return trimesh.creation.torus(major_radius=0.2135, minor_radius=0.0508, major_sections=_SECTIONS, minor_sections=48)


def _make_chunk() -> trimesh.Trimesh:
    # A 60 x 40 x 30 cm block with a 20 x 20 x 15 cm corner bitten out: 72000 - 6000 cm^3.
    block = _box((0.60, 0.40, 0.30))
    bite = _box((0.20, 0.20, 0.15), center=(0.20 + 0.001, 0.10 + 0.001, 0.075 + 0.001))
    return _difference(block, bite)


def _make_mug() -> trimesh.Trimesh:
    outer = trimesh.creation.cylinder(radius=0.20, height=0.45, sections=_SECTIONS)
    cavity = trimesh.creation.cylinder(radius=0.10, height=0.40, sections=_SECTIONS)
    cavity.apply_translation([0, 0, 0.05 + 0.001])  # 5 cm floor; cavity pokes out of the rim
    body = _difference(outer, cavity)
    ring = trimesh.creation.torus(major_radius=0.12, minor_radius=0.03, major_sections=64, minor_sections=24)
    ring.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    ring.apply_translation([0.20, 0, 0])
    handle = _difference(ring, trimesh.creation.cylinder(radius=0.19, height=0.5, sections=_SECTIONS))
    return _union(body, handle)


def _make_stack() -> trimesh.Trimesh:
    # Three 40 x 40 x 27 cm blocks, each stepped 20 cm in x and 10 cm in y: a leaning staircase.
    blocks = [_box((0.40, 0.40, 0.27), center=(0.20 * i, 0.10 * i, 0.27 * i)) for i in range(3)]
    return _union(*blocks)


def _make_bridge() -> trimesh.Trimesh:
    # A 120 x 100 x 64 cm block with a 60 x 42.7 cm tunnel under it: 768000 - 256000 cm^3.
    block = _box((1.20, 1.00, 0.64))
    tunnel = _box((0.60, 1.00 + 0.01, 0.64 * 2 / 3), center=(0, 0, -0.32 + 0.64 / 3 - 0.001))
    return _difference(block, tunnel)


_BUILDERS: dict[str, Callable[[], trimesh.Trimesh]] = {
    "box": _make_box,
    "cylinder": _make_cylinder,
    "cone": _make_cone,
    "torus": _make_torus,
    "chunk": _make_chunk,
    "mug": _make_mug,
    "stack": _make_stack,
    "bridge": _make_bridge,
}

NAMES: tuple[str, ...] = tuple(_BUILDERS)


def paper_rotation(degrees: float) -> np.ndarray:
    """The paper's rotation: ``degrees`` about Z, then the same about local X, then local Y. (3, 3)."""
    # Upper-case axes in scipy are intrinsic (each about the already-rotated frame).
    return Rotation.from_euler("ZXY", [degrees] * 3, degrees=True).as_matrix()


def paper_object(name: str, rotation_deg: float = 0.0) -> trimesh.Trimesh:
    """One of the paper's eight objects: watertight, metres, volume exactly as expected, centred at its
    centre of mass, then rotated by :func:`paper_rotation`.

    Raises:
        KeyError: unknown name (the message lists the names).
    """
    if name not in _BUILDERS:
        raise KeyError(f"unknown paper object {name!r}; choose from {', '.join(NAMES)}")
    mesh = _BUILDERS[name]()
    mesh.merge_vertices()
    assert mesh.is_watertight and mesh.is_winding_consistent, name
    mesh.apply_translation(-mesh.center_mass)
    mesh.apply_scale((EXPECTED_VOLUME_M3[name] / mesh.volume) ** (1 / 3))
    if rotation_deg:
        transform = np.eye(4)
        transform[:3, :3] = paper_rotation(rotation_deg)
        mesh.apply_transform(transform)
    return mesh
