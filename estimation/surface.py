"""The paper's own method: a local interpolating triangulation of the downsampled points.

The paper used PCL's greedy projection triangulation. Open3d has no port of it; its ball-pivoting
triangulation is the same kind of algorithm (grows triangles from a seed over the points, leaves holes
where it cannot continue), so it stands in. The mesh is open in general: its volume is the paper's
signed-tetrahedra sum against the OBB centre (``inertia.mass_properties`` with ``apex``), with each face
wound to agree with its points' normals, which is the paper's sign rule.
"""

from __future__ import annotations

import numpy as np

#: Ball radii, in mean point spacings: small fills the surface, larger bridges gaps.
BALL_RADII_SPACINGS = (1.0, 2.0, 4.0)


def triangulate(points: np.ndarray, normals: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Ball-pivoting triangulation of oriented points; faces wound to agree with the point normals.

    Args:
        points: (n, 3) metres. normals: (n, 3) unit, outward. spacing: mean point spacing, metres.

    Returns:
        vertices (n, 3) metres (the input points) and faces (f, 3) int.
    """
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pcd.normals = o3d.utility.Vector3dVector(normals)
    radii = o3d.utility.DoubleVector([r * spacing for r in BALL_RADII_SPACINGS])
    mesh = o3d.geometry.TriangleMesh.create_from_point_cloud_ball_pivoting(pcd, radii)
    vertices = np.asarray(mesh.vertices)
    faces = np.asarray(mesh.triangles, dtype=np.int64)
    if len(faces) == 0:
        return vertices, faces.reshape(0, 3)
    tri = vertices[faces]
    winding = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    # open3d copies the input points in order, so vertex normals are the given ones.
    face_normal = np.asarray(normals)[faces].sum(axis=1)
    flip = np.einsum("ij,ij->i", winding, face_normal) < 0
    faces[flip] = faces[flip][:, ::-1]
    return vertices, faces
