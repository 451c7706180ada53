"""Mass properties of a triangulated solid at uniform density: the one volume function of the project.

Integrals over signed tetrahedra (apex, v1, v2, v3), one per face (trimesh's polyhedral mass
properties). For a closed, consistently oriented mesh the apex does not matter. For the paper's open
triangulations it does: the paper takes the OBB centre, and its sign rule (sign of n . (v1 - apex)) is
what this gives when each face is wound to agree with its normal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class MassProperties:
    """Mass properties of a uniform-density solid, in the cloud's frame.

    Attributes:
        volume: m^3.
        density: kg/m^3.
        mass: kg (volume x density).
        center_of_mass: (3,) metres.
        inertia: (3, 3) kg m^2, about the centre of mass, axes of the cloud frame.
        principal_moments: (3,) kg m^2, ascending.
        principal_axes: (3, 3), columns are the principal axes (a proper rotation).
    """

    volume: float
    density: float
    mass: float
    center_of_mass: np.ndarray
    inertia: np.ndarray
    principal_moments: np.ndarray
    principal_axes: np.ndarray


def mass_properties(
    vertices: np.ndarray, faces: np.ndarray, density: float, *, apex: np.ndarray | None = None
) -> MassProperties:
    """Volume, mass, centre of mass and inertia of the solid bounded by a triangle mesh.

    Args:
        vertices: (v, 3) float64, metres.
        faces: (f, 3) int, wound counter-clockwise seen from outside (normals out).
        density: kg/m^3, > 0.
        apex: (3,) metres, the shared tetrahedron apex; defaults to the vertex centroid, which for a
            closed mesh changes nothing but rounding.
    """
    from trimesh.triangles import mass_properties as _polyhedral

    vertices = np.asarray(vertices, dtype=np.float64)
    apex = vertices.mean(axis=0) if apex is None else np.asarray(apex, dtype=np.float64)
    # Integrate about the apex: trimesh's tetrahedra all meet at the origin.
    props = _polyhedral(vertices[np.asarray(faces)] - apex, density=density)
    inertia = np.asarray(props.inertia, dtype=np.float64)
    inertia = (inertia + inertia.T) / 2
    moments, axes = np.linalg.eigh(inertia)
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1
    return MassProperties(
        volume=float(props.volume),
        density=float(density),
        mass=float(props.mass),
        center_of_mass=np.asarray(props.center_mass, dtype=np.float64) + apex,
        inertia=inertia,
        principal_moments=moments,
        principal_axes=axes,
    )
