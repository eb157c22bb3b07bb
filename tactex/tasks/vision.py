"""Vision for the cleaning task (TEC §V-A1, Fig. 3 outer loop): capture the surface with its dirt
as a target cloud, and re-measure the dirt onto the same points later (no new basis)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.spatial import cKDTree

from tactex.errors import InputError, PerceptionError
from tactex.perception.acquisition import AcquisitionConfig, acquire_surface
from tactex.perception.frame import CameraFrame
from tactex.perception.normals import knn_normals
from tactex.pointcloud.cloud import SurfaceCloud

__all__ = ["capture_target_cloud", "remeasure_target", "workspace_crop"]


def workspace_crop(
    object_position_m: np.ndarray, half_width_m: float, table_z_m: float = 0.0, height_m: float = 0.25
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """Pass-through box around where the object is expected: it removes the table (anything
    within 2 mm of the table top) and the rest of the scene."""
    c = np.asarray(object_position_m, dtype=float)
    lo = (c[0] - half_width_m, c[1] - half_width_m, table_z_m + 0.002)
    hi = (c[0] + half_width_m, c[1] + half_width_m, table_z_m + height_m)
    return lo, hi


def capture_target_cloud(frame: CameraFrame, config: AcquisitionConfig, normal_k: int = 16) -> SurfaceCloud:
    """The filtered, voxelised cloud of one RGB-D frame, target from colour, with normals estimated
    by PCA over ``normal_k`` neighbours and oriented toward the camera (out of the surface)."""
    cloud = acquire_surface(frame, config)
    if len(cloud) <= normal_k:
        raise PerceptionError(
            f"the capture holds only {len(cloud)} points after filtering (need > {normal_k}); "
            "is the object in the camera's view and inside the crop box?"
        )
    field = knn_normals(cloud.points, normal_k, viewpoint=frame.world_T_camera[:3, 3])
    if not field.ok.any():
        raise PerceptionError("no point of the capture has a usable normal (degenerate neighbourhoods everywhere)")
    # points whose neighbourhood gives no normal are dropped: guessing one would be wrong on walls
    kept = cloud.subset(field.ok)
    return replace(kept, normals=field.normals[field.ok], spacing=cloud.spacing)


def remeasure_target(cloud: SurfaceCloud, capture: SurfaceCloud, max_distance_m: float | None = None) -> np.ndarray:
    """Target mass (N,) on ``cloud``'s points from a new ``capture``: each point takes the target
    of its nearest captured point within ``max_distance_m`` (default 1.5 × spacing); points the
    new view does not see keep their previous target."""
    radius = 1.5 * cloud.spacing if max_distance_m is None else float(max_distance_m)
    if not (np.isfinite(radius) and radius > 0):
        raise InputError(f"max_distance_m must be a positive distance [m], got {max_distance_m!r}")
    dist, idx = cKDTree(capture.points).query(cloud.points, k=1)
    seen = dist <= radius
    mass = cloud.target.copy()
    mass[seen] = capture.target[idx[seen]]
    return mass
