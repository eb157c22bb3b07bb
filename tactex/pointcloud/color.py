"""Target mass from an HSV colour range: a painted mark or dirt seen by the camera (TEC §V-A1).

TEC thresholds colour channels (:func:`tactex.pointcloud.target_from_channel`); under real light
a hue/saturation/value range is the robust version of the same idea. Hue is in degrees [0, 360)
and wraps: ``hue_deg=(340, 20)`` selects reds on both sides of 0°. Saturation and value are in
[0, 1]. The RGB→HSV conversion is matplotlib's vectorised ``rgb_to_hsv``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from matplotlib.colors import rgb_to_hsv

from tactex.config import param
from tactex.errors import ConfigError, InputError

__all__ = ["HsvRange", "hsv_mask", "target_from_hsv"]


@dataclass(frozen=True)
class HsvRange:
    """A colour range in HSV. Defaults select saturated red (a red marker or paint).

    Attributes:
        hue_deg: (low, high) hue [deg]; low > high wraps through 0°.
        saturation: (low, high) in [0, 1].
        value: (low, high) in [0, 1].
    """

    hue_deg: tuple[float, float] = param((340.0, 20.0), "hue range (low, high) [deg], wraps when low > high")
    saturation: tuple[float, float] = param((0.5, 1.0), "saturation range [0-1]")
    value: tuple[float, float] = param((0.3, 1.0), "value (brightness) range [0-1]")

    def __post_init__(self) -> None:
        for name, (lo, hi), top in (
            ("hue_deg", self.hue_deg, 360.0),
            ("saturation", self.saturation, 1.0),
            ("value", self.value, 1.0),
        ):
            if not (0.0 <= lo <= top and 0.0 <= hi <= top):
                raise ConfigError(f"HsvRange.{name} must lie in [0, {top:g}], got {(lo, hi)}")
            if name != "hue_deg" and lo > hi:
                raise ConfigError(f"HsvRange.{name} low must not exceed high, got {(lo, hi)}")


def hsv_mask(colors: np.ndarray, hsv_range: HsvRange) -> np.ndarray:
    """Boolean (N,) mask of the RGB colours (N, 3) in [0, 1] that fall in ``hsv_range``."""
    rgb = np.asarray(colors, dtype=np.float64)
    if rgb.ndim != 2 or rgb.shape[1] != 3:
        raise InputError(f"colors must have shape (N, 3), got {rgb.shape}")
    if rgb.size and (not np.isfinite(rgb).all() or rgb.min() < 0.0 or rgb.max() > 1.0):
        raise InputError("colors must be finite and lie in [0, 1]; divide 8-bit colours by 255")
    hsv = rgb_to_hsv(rgb)
    hue = hsv[:, 0] * 360.0
    h_lo, h_hi = hsv_range.hue_deg
    in_hue = (hue >= h_lo) & (hue <= h_hi) if h_lo <= h_hi else (hue >= h_lo) | (hue <= h_hi)
    s_lo, s_hi = hsv_range.saturation
    v_lo, v_hi = hsv_range.value
    return in_hue & (hsv[:, 1] >= s_lo) & (hsv[:, 1] <= s_hi) & (hsv[:, 2] >= v_lo) & (hsv[:, 2] <= v_hi)


def target_from_hsv(cloud: Any, hsv_range: HsvRange | None = None, mass: float = 1.0) -> Any:
    """A copy of the cloud with target ``mass`` on points whose colour is in ``hsv_range``, 0 elsewhere.

    Accepts a :class:`SurfaceCloud`; an Open3D cloud is converted (it cannot carry a target, so
    the result is a :class:`SurfaceCloud`).
    """
    from tactex.pointcloud.filters import _as_cloud

    sc, _ = _as_cloud(cloud)
    if sc.colors is None:
        raise InputError("the cloud has no colours; an HSV threshold needs an RGB cloud")
    if not (np.isfinite(mass) and mass > 0):
        raise ConfigError(f"target mass must be a positive number, got {mass!r}")
    marked = hsv_mask(sc.colors, hsv_range or HsvRange())
    return sc.with_target(np.where(marked, float(mass), 0.0))
