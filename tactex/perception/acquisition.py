"""Surface acquisition (TEC §V-A1): RGB-D frames → filtered, coloured cloud with target mass.

TEC's node collects the RGB-D cloud, applies *VoxelGrid*, *PassThrough* and
*StatisticalOutlierRemoval*, then thresholds colours to segment the target distribution. Here,
in that order after back-projecting into the world frame (several views are merged): crop box →
voxel grid → statistical outlier removal → colour threshold (HSV range or one channel).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from tactex.config import param
from tactex.errors import ConfigError, PerceptionError
from tactex.perception.depth import frame_to_cloud
from tactex.perception.frame import CameraFrame
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.pointcloud.color import HsvRange, target_from_hsv
from tactex.pointcloud.filters import crop_box, statistical_outlier_removal
from tactex.pointcloud.target import target_from_channel
from tactex.pointcloud.voxel import voxel_down_sample

__all__ = ["AcquisitionConfig", "acquire_surface"]

_INF3 = (float("inf"),) * 3


@dataclass(frozen=True)
class AcquisitionConfig:
    """Pre-processing of TEC §V-A1 (voxel size as in TEC's 3 mm clouds)."""

    crop_min_m: tuple[float, float, float] = param((-float("inf"),) * 3, "crop box lower corner, world [m]")
    crop_max_m: tuple[float, float, float] = param(_INF3, "crop box upper corner, world [m]")
    voxel_size_m: float = param(0.003, "voxel grid edge [m] (0 disables)")
    sor_mean_k: int = param(50, "statistical outlier removal: neighbours (0 disables)")
    sor_std_mul: float = param(1.0, "statistical outlier removal: std multiplier")
    color_method: str = param("hsv", "target from colour: 'hsv', 'channel' or 'none'")
    hsv: HsvRange = field(default_factory=HsvRange, metadata={"help": "HSV range of the target colour", "cli": False})
    channel: str = param("red", "channel for color_method='channel'")
    channel_threshold: float = param(1.0, "channel threshold in [0, 1] for color_method='channel'")
    stride: int = param(1, "pixel stride of the back-projection")

    def __post_init__(self) -> None:
        if self.color_method not in ("hsv", "channel", "none"):
            raise ConfigError(f"unknown color_method '{self.color_method}'; valid: hsv, channel, none")
        if not (np.isfinite(self.voxel_size_m) and self.voxel_size_m >= 0):
            raise ConfigError(f"voxel_size_m must be ≥ 0, got {self.voxel_size_m!r}")
        if int(self.sor_mean_k) != self.sor_mean_k or self.sor_mean_k < 0:
            raise ConfigError(f"sor_mean_k must be an integer ≥ 0, got {self.sor_mean_k!r}")


def acquire_surface(
    frames: CameraFrame | Sequence[CameraFrame], config: AcquisitionConfig | None = None
) -> SurfaceCloud:
    """Merge frames into one world-frame cloud, filter it, and set the target from colour."""
    cfg = config or AcquisitionConfig()
    frame_list = [frames] if isinstance(frames, CameraFrame) else list(frames)
    if not frame_list:
        raise PerceptionError("acquire_surface needs at least one frame")
    want_color = cfg.color_method != "none"
    clouds = [frame_to_cloud(fr, in_world=True, stride=cfg.stride, with_colors=want_color) for fr in frame_list]
    if want_color and any(c.colors is None for c in clouds):
        raise PerceptionError(f"color_method='{cfg.color_method}' needs RGB in every frame; set color_method='none'")
    cloud = clouds[0]
    if len(clouds) > 1:
        colors = np.concatenate([c.colors for c in clouds]) if want_color else None
        cloud = SurfaceCloud(
            points=np.concatenate([c.points for c in clouds]), colors=colors, spacing=min(c.spacing for c in clouds)
        )
    cloud = crop_box(cloud, cfg.crop_min_m, cfg.crop_max_m)
    if cfg.voxel_size_m > 0:
        cloud = voxel_down_sample(cloud, cfg.voxel_size_m)
    if cfg.sor_mean_k > 0 and len(cloud) > cfg.sor_mean_k:
        cloud = statistical_outlier_removal(cloud, cfg.sor_mean_k, cfg.sor_std_mul)
    if cfg.color_method == "hsv":
        cloud = target_from_hsv(cloud, cfg.hsv)
    elif cfg.color_method == "channel":
        cloud = target_from_channel(cloud, cfg.channel, cfg.channel_threshold)
    return cloud
