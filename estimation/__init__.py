"""Point cloud in, geometry and physical properties out. Knows nothing of MuJoCo or Zenoh."""

from estimation.cloud import PointCloud, check_estimable, make_cloud
from estimation.cloudfile import load_cloud, save_cloud
from estimation.errors import CloudError, CloudFileError, MaterialError, ReconstructionError, TwinError
from estimation.estimate import METHODS, PhysicalEstimate, Timings, estimate, from_mesh
from estimation.inertia import MassProperties, mass_properties
from estimation.materials import Material, material, materials
from estimation.obb import OrientedBox, oriented_box

__all__ = [
    "METHODS",
    "CloudError",
    "CloudFileError",
    "MassProperties",
    "Material",
    "MaterialError",
    "OrientedBox",
    "PhysicalEstimate",
    "PointCloud",
    "ReconstructionError",
    "Timings",
    "TwinError",
    "check_estimable",
    "estimate",
    "from_mesh",
    "load_cloud",
    "make_cloud",
    "mass_properties",
    "material",
    "materials",
    "oriented_box",
    "save_cloud",
]
