"""A user's cloud as the cleaning target (``tactex clean --cloud``), and its dirt painted on the simulated
object."""

from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from tactex.errors import ConfigError
from tactex.perception.normals import knn_normals
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.pointcloud.keep_out import DEFAULT_KEEP_OUT_THRESHOLD
from tactex.pointcloud.target import TargetRule
from tactex.pointcloud.target_file import load_target_file

__all__ = ["OFF_SURFACE_WARN", "load_target_cloud", "load_target_cloud_keep_out"]

#: Share of a --cloud's target off the simulated object above which the run warns [-].
OFF_SURFACE_WARN = 0.2


def load_target_cloud(path: str | Path, voxel_size_m: float, units: str = "m") -> SurfaceCloud:
    """A user's cloud (or mesh) in the robot base frame as the cleaning target: voxelised, its stored
    target or else its red marking (by hue and saturation: ``tactex explore --target auto``, white is
    not dirt), with normals estimated (16 neighbours, oriented up) where the file has none. ``units``: the
    file's length unit (m, mm, in)."""
    return load_target_cloud_keep_out(path, voxel_size_m, units=units)[0]


def load_target_cloud_keep_out(path: str | Path, voxel_size_m: float, keep_out_channel: str = "",
                               keep_out_threshold: float = DEFAULT_KEEP_OUT_THRESHOLD,
                               keep_out_mask: str = "", units: str = "m") -> tuple[SurfaceCloud, np.ndarray | None]:
    """:func:`load_target_cloud` and its keep-out zone (a boolean per returned point, None without one;
    see :mod:`tactex.pointcloud.keep_out`)."""
    loaded = load_target_file(path, voxel_size_m, TargetRule("auto"), keep_out_channel=keep_out_channel,
                              keep_out_threshold=keep_out_threshold, keep_out_mask=keep_out_mask, label="--cloud ",
                              unmarked_hint="mark the dirt red (255, 0, 0)", units=units)
    cloud, keep_out = loaded.cloud, loaded.keep_out
    if cloud.normals is None:
        field = knn_normals(cloud.points, 16, viewpoint=cloud.points.mean(axis=0) + np.array([0.0, 0.0, 1.0]))
        cloud = replace(cloud.subset(field.ok), normals=field.normals[field.ok], spacing=cloud.spacing)
        keep_out = None if keep_out is None else keep_out[field.ok]
    return cloud, keep_out


def _dirt_from_cloud(backend, cloud: SurfaceCloud, object_name: str) -> None:
    """In simulation with ``--cloud``, the dirt is the cloud's target, not the scene's ``--marking``: what the run
    reports as removed is then what the user marked (``cloud``'s target: the caller leaves out the dirt a keep-out
    zone and its clearance hold, which no footprint may touch). The cells within 0.71 voxel of a target point
    (the farthest a cell inside a marked area lies from the grid's points) are dirty."""
    from scipy.spatial import cKDTree

    pos, rot = backend.object_pose()
    target_obj = (cloud.points[cloud.target > 0] - pos) @ rot
    radius = cloud.spacing * np.sqrt(0.5)
    field = backend.dirt
    if field.paint(target_obj, radius) == 0:
        raise ConfigError(
            f"no point of --cloud's target lies on the simulated {object_name}'s surface (within {radius * 1e3:.1f} "
            "mm): the cloud must be in the robot base frame, with the object where the scene puts it (--object)")
    off = cKDTree(field.points[field.valid]).query(target_obj)[0] > radius
    if off.mean() > OFF_SURFACE_WARN:
        warnings.warn(f"clean: {off.mean():.0%} of --cloud's target lies farther than {radius * 1e3:.1f} mm from the "
                      f"simulated {object_name}'s surface and is not simulated as dirt (is the cloud in the robot "
                      "base frame?)", RuntimeWarning, stacklevel=2)

