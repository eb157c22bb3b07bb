"""Camera intrinsics and one RGB-D frame: the currency between cameras, simulator and perception."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tactex.errors import PerceptionError

__all__ = ["CameraFrame", "CameraIntrinsics", "D415_DEPTH_640x480", "D435I_DEPTH_640x480"]


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole model of a depth camera.

    Attributes:
        width, height: image size [px].
        fx, fy: focal lengths [px].
        cx, cy: principal point [px].
        depth_scale: metres per depth unit of raw integer images (RealSense: 0.001).
        min_depth_m, max_depth_m: valid range [m]; depth outside is dropped.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    depth_scale: float = 0.001
    min_depth_m: float = 0.07
    max_depth_m: float = 3.0

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
                raise PerceptionError(f"CameraIntrinsics.{name} must be a positive integer [px], got {v!r}")
        for name in ("fx", "fy", "cx", "cy", "depth_scale", "min_depth_m", "max_depth_m"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not np.isfinite(v):
                raise PerceptionError(
                    f"CameraIntrinsics.{name} must be a finite number, got {v!r}"
                    + ("; for no far limit give the sensor's real range (e.g. 10 m)" if name == "max_depth_m" else "")
                )
        if not (self.fx > 0 and self.fy > 0):
            raise PerceptionError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if not self.depth_scale > 0:
            raise PerceptionError(f"depth_scale must be > 0 [m per depth unit], got {self.depth_scale}")
        if not (0 <= self.min_depth_m < self.max_depth_m):
            raise PerceptionError(f"invalid depth range [{self.min_depth_m}, {self.max_depth_m}] m")

    @classmethod
    def from_fov(cls, width: int, height: int, fovy_deg: float, **kw: float) -> CameraIntrinsics:
        """Square-pixel intrinsics from a vertical field of view [deg] (as MuJoCo cameras use)."""
        if not (isinstance(fovy_deg, (int, float, np.integer, np.floating)) and 0.0 < fovy_deg < 180.0):
            raise PerceptionError(f"the vertical field of view must be in (0, 180) deg, got {fovy_deg!r}")
        f = 0.5 * height / np.tan(np.deg2rad(fovy_deg) / 2.0)
        return cls(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0, **kw)

    @property
    def fovy_deg(self) -> float:
        return float(np.rad2deg(2.0 * np.arctan(0.5 * self.height / self.fy)))

    @property
    def K(self) -> np.ndarray:
        """(3, 3) pinhole matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] [px]."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def to_array(self) -> np.ndarray:
        """(9,) float array [width, height, fx, fy, cx, cy, depth_scale, min_depth_m, max_depth_m] (for .npz)."""
        return np.array(
            [self.width, self.height, self.fx, self.fy, self.cx, self.cy, self.depth_scale,
             self.min_depth_m, self.max_depth_m], dtype=np.float64,
        )

    @classmethod
    def from_array(cls, values: np.ndarray) -> CameraIntrinsics:
        """Inverse of :meth:`to_array`."""
        v = np.asarray(values, dtype=np.float64).reshape(-1)
        if v.shape != (9,) or not np.isfinite(v).all():
            raise PerceptionError(f"intrinsics array must hold 9 finite numbers, got {v.tolist()}")
        return cls(int(v[0]), int(v[1]), *(float(x) for x in v[2:]))

    def scaled(self, width: int, height: int) -> CameraIntrinsics:
        """The same camera at another resolution (same field of view)."""
        sx, sy = width / self.width, height / self.height
        return CameraIntrinsics(
            width, height, self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5,
            (self.cy + 0.5) * sy - 0.5, self.depth_scale, self.min_depth_m, self.max_depth_m,
        )


# The presets are typical factory values, not a calibration: read the real ones from the device
# (RealSenseSource does) or from a recording. At 640×480 the D435i depth stream has fx ≈ 383 px
# (≈ 80°×64°; the 87°×58° datasheet figure is for 16:9), the D415 fx ≈ 604 px (≈ 56°×43°).
#: Typical factory calibration of an Intel RealSense D435i depth stream at 640×480 (87°×58° FOV class).
D435I_DEPTH_640x480 = CameraIntrinsics(640, 480, 383.0, 383.0, 319.5, 239.5)
#: Typical factory calibration of an Intel RealSense D415 depth stream at 640×480 (65°×40° FOV class).
D415_DEPTH_640x480 = CameraIntrinsics(640, 480, 604.0, 604.0, 319.5, 239.5, min_depth_m=0.16)


@dataclass(frozen=True)
class CameraFrame:
    """One RGB-D frame.

    Attributes:
        depth_m: (H, W) float32 depth along the optical axis [m]; 0 or NaN where invalid.
        intrinsics: the camera model (must match the image size).
        world_T_camera: (4, 4) camera pose in the world (optical frame: z forward, x right, y down).
        timestamp: acquisition time [s].
        rgb: (H, W, 3) uint8 colour aligned to depth, or None.
    """

    depth_m: np.ndarray
    intrinsics: CameraIntrinsics
    world_T_camera: np.ndarray
    timestamp: float
    rgb: np.ndarray | None = None
