"""Depth image → points: validation of frames and poses, pinhole back-projection.

Optical frame: z forward, x right, y down. A pixel (row v, column u) with depth z [m] along the
optical axis back-projects to ``x = (u − cx)·z/fx, y = (v − cy)·z/fy``. Invalid depth (0, NaN,
inf, outside [min_depth_m, max_depth_m]) is *dropped*, never turned into a point at the origin.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from tactex.errors import InputError, PerceptionError, UnitsError
from tactex.perception.frame import CameraFrame, CameraIntrinsics
from tactex.pointcloud.cloud import SurfaceCloud

__all__ = [
    "MAX_PLAUSIBLE_DEPTH_M",
    "DepthPoints",
    "check_pose",
    "deproject",
    "depth_in_meters",
    "frame_to_cloud",
    "validate_frame",
]

#: A float depth image whose median valid value exceeds this is taken to be in millimetres.
MAX_PLAUSIBLE_DEPTH_M = 20.0


def check_pose(T: object, name: str) -> np.ndarray:
    """Return a (4, 4) rigid transform as float64, or raise :class:`InputError` naming ``name``."""
    try:
        arr = np.asarray(T, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a (4, 4) homogeneous transform of numbers, got {T!r}") from exc
    if arr.shape != (4, 4):
        raise InputError(f"{name} must be a (4, 4) homogeneous transform, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise InputError(f"{name} holds NaN/inf values: {arr.tolist()}")
    if not np.allclose(arr[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise InputError(f"{name} last row must be [0, 0, 0, 1], got {arr[3].tolist()}")
    rot = arr[:3, :3]
    err = float(np.abs(rot.T @ rot - np.eye(3)).max())
    if err > 1e-6 or np.linalg.det(rot) < 0:
        raise InputError(
            f"{name} rotation block is not a proper rotation (|RᵀR − I|max = {err:.2g}, "
            f"det = {np.linalg.det(rot):.3g}); orthonormalise it"
        )
    return arr


def depth_in_meters(depth: object, intrinsics: CameraIntrinsics) -> np.ndarray:
    """Validate a depth image and return it as float32 metres (invalid pixels kept, as 0/NaN).

    Accepts float32/float64 metres or uint16 raw units (× ``intrinsics.depth_scale``).
    Raises :class:`PerceptionError` for a wrong shape or dtype and :class:`UnitsError` when the
    depth in metres is implausible (a float image in millimetres, or a wrong ``depth_scale``).
    """
    if not isinstance(depth, np.ndarray):
        raise PerceptionError(f"depth must be a numpy array, got {type(depth).__name__}")
    if depth.ndim != 2:
        raise PerceptionError(f"depth must be a 2-D (H, W) image, got shape {depth.shape}")
    if depth.shape != (intrinsics.height, intrinsics.width):
        raise PerceptionError(
            f"depth image is {depth.shape[1]}×{depth.shape[0]} (W×H) but the intrinsics describe "
            f"{intrinsics.width}×{intrinsics.height}; use intrinsics.scaled({depth.shape[1]}, {depth.shape[0]}) "
            "or the stream's own intrinsics"
        )
    if depth.dtype == np.uint16:
        out = depth.astype(np.float32) * np.float32(intrinsics.depth_scale)
        hint = (f"the uint16 image times depth_scale={intrinsics.depth_scale:g} m/unit gives it: check "
                "depth_scale (RealSense z16: 0.001, or the device's own depth scale)")
    elif depth.dtype in (np.float32, np.float64):
        out = depth.astype(np.float32, copy=False)
        hint = ("float depth must be in metres; it looks like millimetres: pass depth_mm * 1e-3, or the raw "
                "uint16 image with intrinsics.depth_scale")
    else:
        raise PerceptionError(
            f"depth dtype {depth.dtype} is not supported: pass float32/float64 metres or uint16 raw units"
        )
    sample = out[::7, ::7]
    sample = sample[np.isfinite(sample) & (sample > 0)]
    if sample.size and float(np.median(sample)) > MAX_PLAUSIBLE_DEPTH_M:
        raise UnitsError(
            f"depth median is {float(np.median(sample)):.4g} m (> {MAX_PLAUSIBLE_DEPTH_M:g} m is implausible "
            f"for a wrist camera); {hint}"
        )
    return out


def validate_frame(frame: CameraFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Check a :class:`CameraFrame`; return (depth float32 [m], world_T_camera (4, 4), rgb float32 [0, 1] or None)."""
    if not isinstance(frame, CameraFrame):
        raise PerceptionError(f"expected a CameraFrame, got {type(frame).__name__}")
    if not np.isfinite(frame.timestamp):
        raise PerceptionError(f"frame timestamp must be finite, got {frame.timestamp!r}")
    depth = depth_in_meters(frame.depth_m, frame.intrinsics)
    pose = check_pose(frame.world_T_camera, "frame.world_T_camera")
    rgb = None
    if frame.rgb is not None:
        img = np.asarray(frame.rgb)
        if img.shape != (*depth.shape, 3):
            raise PerceptionError(f"rgb must have shape {(*depth.shape, 3)} to match the depth, got {img.shape}")
        if img.dtype == np.uint8:
            rgb = img.astype(np.float32) / np.float32(255.0)
        elif img.dtype in (np.float32, np.float64):
            if not np.isfinite(img).all() or img.min() < 0 or img.max() > 1:
                raise PerceptionError("float rgb must be finite and lie in [0, 1] (or pass uint8)")
            rgb = img.astype(np.float32, copy=False)
        else:
            raise PerceptionError(f"rgb dtype {img.dtype} is not supported: pass uint8 or float in [0, 1]")
    return depth, pose, rgb


class DepthPoints(NamedTuple):
    """Back-projected valid pixels.

    Attributes:
        points: (N, 3) positions in the camera optical frame [m].
        rows, cols: (N,) pixel coordinates of each point.
        colors: (N, 3) RGB in [0, 1], or None.
    """

    points: np.ndarray
    rows: np.ndarray
    cols: np.ndarray
    colors: np.ndarray | None


def deproject(
    depth_m: np.ndarray,
    intrinsics: CameraIntrinsics,
    *,
    stride: int = 1,
    bbox: tuple[int, int, int, int] | None = None,
    rgb: np.ndarray | None = None,
) -> DepthPoints:
    """Back-project the valid pixels of a (validated) depth image in metres.

    Args:
        stride: keep every ``stride``-th row and column (1 = all pixels).
        bbox: (row0, row1, col0, col1), half-open, to restrict to a region of interest.
    """
    if int(stride) != stride or stride < 1:
        raise PerceptionError(f"stride must be a positive integer, got {stride!r}")
    r0, r1, c0, c1 = bbox if bbox is not None else (0, depth_m.shape[0], 0, depth_m.shape[1])
    rows = np.arange(r0, r1, stride)
    cols = np.arange(c0, c1, stride)
    z = depth_m[r0:r1:stride, c0:c1:stride]
    valid = np.isfinite(z) & (z >= intrinsics.min_depth_m) & (z <= intrinsics.max_depth_m) & (z > 0)
    vi, ui = np.nonzero(valid)
    zv = z[vi, ui].astype(np.float64)
    rr, cc = rows[vi], cols[ui]
    pts = np.empty((zv.size, 3))
    pts[:, 0] = (cc - intrinsics.cx) * zv / intrinsics.fx
    pts[:, 1] = (rr - intrinsics.cy) * zv / intrinsics.fy
    pts[:, 2] = zv
    colors = None if rgb is None else rgb[rr, cc].astype(np.float64)
    return DepthPoints(pts, rr, cc, colors)


def frame_to_cloud(
    frame: CameraFrame, *, in_world: bool = True, stride: int = 1, with_colors: bool = True
) -> SurfaceCloud:
    """A :class:`SurfaceCloud` of the frame's valid pixels, in the world (default) or camera frame.

    Raises :class:`PerceptionError` when no pixel holds a valid depth.
    """
    depth, pose, rgb = validate_frame(frame)
    dp = deproject(depth, frame.intrinsics, stride=stride, rgb=rgb if with_colors else None)
    if dp.points.shape[0] == 0:
        raise PerceptionError(
            f"the depth frame at t={frame.timestamp} holds no valid depth in "
            f"[{frame.intrinsics.min_depth_m}, {frame.intrinsics.max_depth_m}] m"
        )
    # einsum, not ``@``: a (N, 3) @ (3, 3) product goes through threaded BLAS, whose threads wait for
    # cores on a loaded machine far longer than this small product takes on one.
    pts = np.einsum("ij,kj->ik", dp.points, pose[:3, :3]) + pose[:3, 3] if in_world else dp.points
    colors = None if dp.colors is None else np.clip(dp.colors, 0.0, 1.0)
    # The pixel footprint at the median depth: exact spacing of a fronto-parallel view, and it
    # spares a KD-tree over 300k points.
    spacing = stride * float(np.median(dp.points[:, 2])) / min(frame.intrinsics.fx, frame.intrinsics.fy)
    return SurfaceCloud(points=pts, colors=colors, spacing=spacing)
