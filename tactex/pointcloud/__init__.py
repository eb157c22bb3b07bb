"""Point clouds: the :class:`SurfaceCloud` type, I/O, voxel grid, target from colours (TEC §V-A1)."""

from tactex.pointcloud.cloud import SurfaceCloud, mean_spacing, validate_points
from tactex.pointcloud.io import (
    from_open3d,
    load_cloud,
    load_npz,
    load_pcd,
    load_ply,
    save_cloud,
    save_npz,
    save_ply,
    to_open3d,
)
from tactex.pointcloud.target import target_from_channel
from tactex.pointcloud.voxel import voxel_down_sample

__all__ = [
    "SurfaceCloud",
    "from_open3d",
    "load_cloud",
    "load_npz",
    "load_pcd",
    "load_ply",
    "mean_spacing",
    "save_cloud",
    "save_npz",
    "save_ply",
    "target_from_channel",
    "to_open3d",
    "validate_points",
    "voxel_down_sample",
]
