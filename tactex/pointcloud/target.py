"""Target mass from colours: the marks a person (or dirt) leaves on a surface (TEC §V-A1).

A marking is a colour, so a point is marked when its *hue* is near the marking's and its colour is
saturated and bright enough (HSV): white, grey, beige and black are never "red", however high their
red channel. The TEC clouds mark their target pure red (255, 0, 0) on black; a camera sees a red
marker as e.g. (190, 40, 45) — both lie well inside the defaults. TEC's own rule, one raw channel
≥ a level, stays available as :func:`target_from_channel` (``--target-threshold`` on the CLI).

Files are marked point by point *before* the voxel grid, and a voxel is marked when all of its points
are (:data:`MARKED_FRACTION`): on the TEC clouds this reproduces their red ≥ 1.0 after averaging
exactly, and a voxel half on a red line and half on the table is not called red.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tactex.errors import ConfigError, InputError
from tactex.pointcloud.cloud import SurfaceCloud

__all__ = [
    "CHANNELS",
    "COLOR_HUES_DEG",
    "HUE_HALF_WIDTH_DEG",
    "MARKED_FRACTION",
    "MIN_VALUE",
    "TARGET_CHOICES",
    "TargetRule",
    "color_mask",
    "describe_target",
    "file_target",
    "target_from_channel",
    "target_from_color",
]

CHANNELS = {"red": 0, "green": 1, "blue": 2}
#: Hue [deg] of each marking colour.
COLOR_HUES_DEG = {"red": 0.0, "green": 120.0, "blue": 240.0}
#: Hues within this of the marking's hue count as that colour [deg] (red: 340°–20°).
HUE_HALF_WIDTH_DEG = 20.0
#: Darker colours than this value (HSV brightness, 0–1) have no reliable hue (sensor noise on black).
MIN_VALUE = 0.3
#: Default minimum saturation (0–1): beige is ~0.3, white ~0, a red marker seen by a camera ~0.75.
DEFAULT_MIN_SATURATION = 0.5
#: A voxel is target when at least this fraction of its points is marked.
MARKED_FRACTION = 1.0
#: What ``--target`` accepts: a colour (by hue), the file's stored target, or the whole surface.
TARGET_CHOICES = ("auto", "red", "green", "blue", "stored", "all")


def _check_color(color: str) -> str:
    name = str(color).lower()
    if name not in COLOR_HUES_DEG:
        raise ConfigError(f"unknown target colour '{color}'; valid: {', '.join(COLOR_HUES_DEG)}")
    return name


def _check_unit(name: str, value: float) -> None:
    if not (math.isfinite(value) and 0.0 <= value <= 1.0):
        raise ConfigError(f"{name}={value} must lie in [0, 1] (colours are scaled to 0–1)")


def color_mask(colors: np.ndarray, color: str = "red", min_saturation: float = DEFAULT_MIN_SATURATION) -> np.ndarray:
    """Boolean (N,) mask of the RGB colours (N, 3) in [0, 1] that are ``color`` by hue (within
    :data:`HUE_HALF_WIDTH_DEG`), saturation ≥ ``min_saturation`` and value ≥ :data:`MIN_VALUE`."""
    from tactex.pointcloud.color import HsvRange, hsv_mask

    hue = COLOR_HUES_DEG[_check_color(color)]
    _check_unit("target_saturation", min_saturation)
    lo, hi = (hue - HUE_HALF_WIDTH_DEG) % 360.0, (hue + HUE_HALF_WIDTH_DEG) % 360.0
    return hsv_mask(colors, HsvRange(hue_deg=(lo, hi), saturation=(min_saturation, 1.0), value=(MIN_VALUE, 1.0)))


def target_from_color(
    cloud: SurfaceCloud, color: str = "red", min_saturation: float = DEFAULT_MIN_SATURATION, mass: float = 1.0
) -> SurfaceCloud:
    """A copy of ``cloud`` with target ``mass`` on the points of colour ``color`` (see :func:`color_mask`)."""
    if cloud.colors is None:
        raise InputError("the cloud has no colours, so no point can be marked by colour")
    marked = color_mask(cloud.colors, color, min_saturation)
    return cloud.with_target(np.where(marked, float(mass), 0.0))


def target_from_channel(
    cloud: SurfaceCloud, channel: str = "red", threshold: float = 1.0, mass: float = 1.0
) -> SurfaceCloud:
    """Mark as target the points whose ``channel`` ≥ ``threshold`` (colours in [0, 1]): TEC's rule.

    The TEC clouds mark the target with red = 255, i.e. red ≥ 1.0 after voxel averaging
    (a voxel counts only when all its points are marked). White is also red ≥ 1.0: for a camera's
    cloud use :func:`target_from_color`. Returns a copy with ``target`` set to ``mass`` on marked
    points and 0 elsewhere.
    """
    if cloud.colors is None:
        raise InputError("the cloud has no colours; a colour threshold needs an RGB cloud")
    if channel not in CHANNELS:
        raise ConfigError(f"unknown colour channel '{channel}'; valid: {', '.join(CHANNELS)}")
    if not 0.0 <= threshold <= 1.0:
        raise ConfigError(f"target_threshold={threshold} must lie in [0, 1] (colours are scaled to 0–1)")
    # Averaging in float can land a hair below 1.0 for all-255 voxels.
    marked = cloud.colors[:, CHANNELS[channel]] >= threshold - 1e-9
    return cloud.with_target(np.where(marked, float(mass), 0.0))


@dataclass(frozen=True)
class TargetRule:
    """How a cloud file's target is chosen.

    Attributes:
        target: ``auto`` (the file's stored target when it has one, else red by hue when it has
            colours; ``tactex clean --cloud`` decides the same way), ``red``,
            ``green``, ``blue`` (by hue and saturation), ``stored`` or ``all`` (the whole surface).
        saturation: minimum HSV saturation of a marked colour, 0–1.
        threshold: when given, TEC's raw rule instead of hue: the colour's channel ≥ this level, 0–1.
    """

    target: str = "auto"
    saturation: float = DEFAULT_MIN_SATURATION
    threshold: float | None = None

    def __post_init__(self) -> None:
        name = str(self.target).lower()
        if name not in TARGET_CHOICES:
            raise ConfigError(f"unknown target '{self.target}'; valid: {', '.join(TARGET_CHOICES)}")
        object.__setattr__(self, "target", name)
        _check_unit("target_saturation", self.saturation)
        if self.threshold is not None:
            _check_unit("target_threshold", self.threshold)
            if name in ("stored", "all"):
                raise ConfigError(f"target_threshold applies to a colour; target={name} takes no threshold")

    def color(self, has_colors: bool, has_target: bool = False) -> str | None:
        """The marking colour this rule uses on a cloud with/without colours and a stored target
        (None: no colour, the stored target or the whole surface)."""
        if self.target == "auto":
            return "red" if has_colors and not has_target else None
        return self.target if self.target in COLOR_HUES_DEG else None

    def describe(self, color: str) -> str:
        if self.threshold is not None:
            return f"{color} channel ≥ {self.threshold:g}"
        return (f"{color} by hue (within {HUE_HALF_WIDTH_DEG:g}° of {COLOR_HUES_DEG[color]:g}°), "
                f"saturation ≥ {self.saturation:g}, brightness ≥ {MIN_VALUE:g}")


def _closest_color(colors: np.ndarray) -> str:
    """A few words on the most saturated colours of a cloud, for a message that found no mark."""
    from matplotlib.colors import rgb_to_hsv

    hsv = rgb_to_hsv(np.clip(colors, 0.0, 1.0))
    bright = hsv[hsv[:, 2] >= MIN_VALUE]
    if bright.shape[0] == 0:
        return "all its points are darker than the brightness a colour needs"
    top = bright[np.argsort(bright[:, 1])[-max(1, bright.shape[0] // 100):]]  # the most saturated 1 %
    return (f"its most saturated colours have hue ≈ {np.median(top[:, 0]) * 360:.0f}° and saturation "
            f"≈ {np.median(top[:, 1]):.2f}")


def file_target(raw: SurfaceCloud, voxel_size_m: float, rule: TargetRule, source: str) -> tuple[SurfaceCloud, str]:
    """The cloud of a file voxelised at ``voxel_size_m`` (0: as it is) with its target chosen by
    ``rule``, and the rule in words. Colours are judged point by point before the voxel grid (see
    the module's doc); the raw threshold after it, as TEC does."""
    from tactex.pointcloud.voxel import voxel_down_sample

    def voxels(cloud: SurfaceCloud) -> SurfaceCloud:
        return voxel_down_sample(cloud, voxel_size_m) if voxel_size_m > 0 else cloud

    if rule.target == "all":
        cloud = voxels(raw)
        return cloud.with_target(np.ones(len(cloud))), "the whole surface"
    color = rule.color(raw.colors is not None, raw.n_target > 0)
    if rule.target in COLOR_HUES_DEG and raw.colors is None:
        raise InputError(f"'{source}' has no colours, so --target {rule.target} cannot select a target; "
                         "use --target all for the whole surface")
    if color is None:
        cloud = voxels(raw)
        if cloud.n_target == 0:
            raise InputError(f"'{source}' carries no target (no colours, no non-zero 'target' array); mark the "
                             "target in red, or use --target all to explore the whole surface")
        return cloud, "the target stored in the file"
    words = rule.describe(color)
    if rule.threshold is not None:
        cloud = target_from_channel(voxels(raw), color, rule.threshold)
    else:
        marked = voxels(target_from_color(raw, color, rule.saturation))
        cloud = marked.with_target(np.where(marked.target >= MARKED_FRACTION - 1e-9, 1.0, 0.0))
    if cloud.n_target == 0:
        hint = ("lower --target-threshold" if rule.threshold is not None
                else "lower --target-saturation, or give --target-threshold for TEC's raw channel rule")
        raise InputError(f"no point of '{source}' is marked ({words}); {_closest_color(raw.colors)}. "
                         f"Choose another --target colour, {hint}, or use --target all")
    return cloud, words


def describe_target(cloud: SurfaceCloud) -> str:
    """How many points are target and where (bounding box of the target points [m])."""
    mask = cloud.target > 0
    n = int(mask.sum())
    share = 100.0 * n / max(len(cloud), 1)
    if n == 0:
        return f"0 of {len(cloud)} points are target"
    pts = cloud.points[mask]
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    box = ", ".join(f"{a} {lo[i]:+.3f}…{hi[i]:+.3f}" for i, a in enumerate("xyz"))
    return f"{n} of {len(cloud)} points are target ({share:.1f} %), within {box} m"
