"""Point-cloud helpers shared by odometry, refinement and meshing: voxel downsampling, normals,
open3d clouds."""
from __future__ import annotations

import numpy as np

from ...geometry.voxels import first_per_voxel


def _o3d_cloud(points, normals=None):
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points, np.float64)))
    if normals is not None:
        pc.normals = o3d.utility.Vector3dVector(np.ascontiguousarray(normals, np.float64))
    return pc


def scan_normals(points: np.ndarray, radius: float, max_nn: int):
    """Downsampled sensor-frame points → (points, normals facing the sensor) via open3d (hybrid
    search: ``radius`` m, at most ``max_nn`` neighbours; ``SlamConfig.scan_normal_radius`` / ``_nn``)."""
    import open3d as o3d

    pc = _o3d_cloud(points)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=max_nn))
    pc.orient_normals_towards_camera_location(np.zeros(3))
    return np.asarray(pc.points), np.asarray(pc.normals)


def downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """Voxel-grid downsampling (one point per occupied voxel: the first)."""
    return points[first_per_voxel(points, voxel)] if len(points) else points
