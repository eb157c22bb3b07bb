"""Target mass from colours: the marks a person (or dirt) leaves on a surface (TEC §V-A1)."""

from __future__ import annotations

import numpy as np

from tactex.errors import ConfigError, InputError
from tactex.pointcloud.cloud import SurfaceCloud

__all__ = ["CHANNELS", "target_from_channel"]

CHANNELS = {"red": 0, "green": 1, "blue": 2}


def target_from_channel(
    cloud: SurfaceCloud, channel: str = "red", threshold: float = 1.0, mass: float = 1.0
) -> SurfaceCloud:
    """Mark as target the points whose ``channel`` ≥ ``threshold`` (colours in [0, 1]).

    The TEC clouds mark the target with red = 255, i.e. red ≥ 1.0 after voxel averaging
    (a voxel counts only when all its points are marked). Returns a copy with ``target`` set to
    ``mass`` on marked points and 0 elsewhere.
    """
    if cloud.colors is None:
        raise InputError("the cloud has no colours; a colour threshold needs an RGB cloud")
    if channel not in CHANNELS:
        raise ConfigError(f"unknown colour channel '{channel}'; valid: {', '.join(CHANNELS)}")
    if not 0.0 <= threshold <= 1.0:
        raise ConfigError(f"threshold must lie in [0, 1] (colours are scaled to [0, 1]), got {threshold}")
    # Averaging in float can land a hair below 1.0 for all-255 voxels.
    marked = cloud.colors[:, CHANNELS[channel]] >= threshold - 1e-9
    return cloud.with_target(np.where(marked, float(mass), 0.0))
