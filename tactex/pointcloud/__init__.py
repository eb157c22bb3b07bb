"""Point clouds: the :class:`SurfaceCloud` type, I/O, voxel grid, target from colours (TEC §V-A1)."""

from tactex.pointcloud.cloud import SurfaceCloud, mean_spacing, validate_points
from tactex.pointcloud.color import HsvRange, hsv_mask, target_from_hsv
from tactex.pointcloud.filters import (
    crop_box,
    crop_box_mask,
    pass_through,
    statistical_outlier_mask,
    statistical_outlier_removal,
)
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
    "HsvRange",
    "SurfaceCloud",
    "crop_box",
    "crop_box_mask",
    "from_open3d",
    "hsv_mask",
    "load_cloud",
    "load_npz",
    "load_pcd",
    "load_ply",
    "mean_spacing",
    "pass_through",
    "save_cloud",
    "save_npz",
    "save_ply",
    "statistical_outlier_mask",
    "statistical_outlier_removal",
    "target_from_channel",
    "target_from_hsv",
    "to_open3d",
    "validate_points",
    "voxel_down_sample",
]
