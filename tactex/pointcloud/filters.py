"""Cloud pre-processing filters of TEC §V-A1: pass-through, crop box, statistical outlier removal.

TEC runs PCL's *VoxelGrid*, *PassThrough* and *StatisticalOutlierRemoval* (through
``perception_pcl``). These are a few vectorised numpy/scipy lines, so the core keeps them instead
of depending on PCL or Open3D; the voxel grid is :func:`tactex.pointcloud.voxel_down_sample`.

Every filter takes a :class:`SurfaceCloud` or an ``open3d.geometry.PointCloud`` (with the
``open3d`` extra) and returns the same kind. The ``*_mask`` functions work on raw (N, 3) arrays.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from tactex.errors import CloudError, ConfigError
from tactex.pointcloud.cloud import SurfaceCloud, validate_points

__all__ = [
    "crop_box",
    "crop_box_mask",
    "pass_through",
    "statistical_outlier_mask",
    "statistical_outlier_removal",
]

_AXES = {"x": 0, "y": 1, "z": 2}


def _is_open3d(obj: Any) -> bool:
    return type(obj).__module__.split(".")[0] == "open3d"


def _as_cloud(cloud: Any) -> tuple[SurfaceCloud, bool]:
    """(SurfaceCloud, came_from_open3d)."""
    if isinstance(cloud, SurfaceCloud):
        return cloud, False
    if _is_open3d(cloud):
        from tactex.pointcloud.io import from_open3d

        return from_open3d(cloud), True
    raise CloudError(
        f"expected a SurfaceCloud or an open3d.geometry.PointCloud, got {type(cloud).__name__}; "
        "wrap raw arrays with SurfaceCloud(points=...) or use the *_mask functions"
    )


def _keep(cloud: SurfaceCloud, mask: np.ndarray, from_o3d: bool, what: str) -> Any:
    if not mask.any():
        raise CloudError(f"{what} removed every one of the {len(cloud)} points; widen its limits")
    # Removing points keeps the sampling density: the spacing (e.g. TEC's h = voxel size) is kept.
    out = cloud if mask.all() else SurfaceCloud(
        points=cloud.points[mask],
        normals=None if cloud.normals is None else cloud.normals[mask],
        colors=None if cloud.colors is None else cloud.colors[mask],
        target=cloud.target[mask],
        spacing=cloud.spacing,
    )
    if from_o3d:
        from tactex.pointcloud.io import to_open3d

        return to_open3d(out)
    return out


def _bounds(value: object, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3,) or np.isnan(arr).any():
        raise ConfigError(f"{name} must be 3 numbers [m] (±inf allowed), got {value!r}")
    return arr


def crop_box_mask(points: np.ndarray, min_bound: object, max_bound: object) -> np.ndarray:
    """Boolean (N,) mask of the points inside the axis-aligned box [min_bound, max_bound] [m]
    (bounds inclusive; use ±inf to leave an axis open)."""
    pts = validate_points(points)
    lo, hi = _bounds(min_bound, "min_bound"), _bounds(max_bound, "max_bound")
    if np.any(lo > hi):
        raise ConfigError(f"crop box min_bound {lo.tolist()} exceeds max_bound {hi.tolist()} on some axis")
    return np.all((pts >= lo) & (pts <= hi), axis=1)


def crop_box(cloud: Any, min_bound: object, max_bound: object, *, negative: bool = False) -> Any:
    """Keep the points inside an axis-aligned box [m] (PCL *CropBox*); ``negative`` keeps the outside."""
    sc, o3d = _as_cloud(cloud)
    mask = crop_box_mask(sc.points, min_bound, max_bound)
    return _keep(sc, ~mask if negative else mask, o3d, "crop_box")


def pass_through(
    cloud: Any, field: str = "z", limits: tuple[float, float] = (0.0, 1.0), *, negative: bool = False
) -> Any:
    """PCL *PassThrough*: keep points whose ``field`` (x, y or z) lies in ``limits`` [m], inclusive."""
    if field not in _AXES:
        raise ConfigError(f"unknown pass-through field '{field}'; valid: {', '.join(_AXES)}")
    lo, hi = (float(v) for v in limits)
    if not lo <= hi:
        raise ConfigError(f"pass-through limits must satisfy low ≤ high, got {limits!r}")
    sc, o3d = _as_cloud(cloud)
    values = sc.points[:, _AXES[field]]
    mask = (values >= lo) & (values <= hi)
    return _keep(sc, ~mask if negative else mask, o3d, f"pass_through on {field} in [{lo}, {hi}]")


def statistical_outlier_mask(
    points: np.ndarray, mean_k: int = 50, std_mul: float = 1.0, *, workers: int = 1
) -> np.ndarray:
    """Inlier mask with PCL *StatisticalOutlierRemoval* semantics.

    For each point, d̄ = mean distance to its ``mean_k`` nearest neighbours (itself excluded).
    With μ and σ the mean and sample standard deviation (n − 1) of d̄ over the cloud, a point is
    an inlier when d̄ ≤ μ + std_mul·σ (PCL's defaults in its tutorial: mean_k = 50, std_mul = 1).
    """
    if int(mean_k) != mean_k or mean_k < 1:
        raise ConfigError(f"mean_k must be a positive integer, got {mean_k!r}")
    if not np.isfinite(std_mul):
        raise ConfigError(f"std_mul must be finite, got {std_mul!r}")
    pts = validate_points(points, min_points=int(mean_k) + 1)
    dist, _ = cKDTree(pts).query(pts, k=int(mean_k) + 1, workers=workers)
    mean_d = dist[:, 1:].mean(axis=1)
    sigma = float(mean_d.std(ddof=1)) if mean_d.size > 1 else 0.0
    return mean_d <= mean_d.mean() + float(std_mul) * sigma


def statistical_outlier_removal(cloud: Any, mean_k: int = 50, std_mul: float = 1.0, *, workers: int = 1) -> Any:
    """Drop statistical outliers (see :func:`statistical_outlier_mask`)."""
    sc, o3d = _as_cloud(cloud)
    if len(sc) <= mean_k:
        raise CloudError(
            f"statistical outlier removal with mean_k={mean_k} needs more than {mean_k} points, "
            f"the cloud holds {len(sc)}; lower mean_k"
        )
    mask = statistical_outlier_mask(sc.points, mean_k, std_mul, workers=workers)
    return _keep(sc, mask, o3d, "statistical_outlier_removal")
