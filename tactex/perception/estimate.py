"""The surface estimate the vision pipeline hands to VA-UFIC (VA-UFIC §II-B, eq. 14–16)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["SurfaceEstimate"]

_NAN3 = np.full(3, np.nan)


@dataclass(frozen=True)
class SurfaceEstimate:
    """Local surface in front of the tool.

    Attributes:
        valid: False when no usable segment was found; ``reason`` says why and the vectors are NaN.
        timestamp: time of the frame it came from [s].
        normal_camera: (3,) unit surface normal n_s^c in the camera frame, pointing to the camera.
        normal_world: (3,) the same in the world frame.
        e1_world, e2_world: (3,) principal in-plane directions of the segment (PCA).
        centroid_world: (3,) segment centroid [m].
        curvature: l_s = |λ3 / tr Σ| (eq. 16), dimensionless, 0 for a plane, ≤ 1/3.
        theta_rad: orientation error θ (eq. 15) [rad] in [0, π]: the angle between the tool z axis
            and the inward normal −n_s, so 0 when the tool presses straight into the surface. With
            the paper's mount (camera z ∥ tool z) this is θ = |acos(n_s^cᵀ [0 0 1]ᵀ)| for the
            inward-pointing n_s^c (see tactex.perception.pca).
        segment_size: number of points in the segment.
        reason: why the estimate is invalid ("" when valid).
        e1_camera, e2_camera: (3,) the PCA edges in the camera frame.
        centroid_camera: (3,) segment centroid in the camera frame [m].
        eigenvalues: (3,) λ1 ≥ λ2 ≥ λ3 of the segment covariance Σ [m²].
        roi_points: number of valid points in the region of interest around the tool axis.
        planned: True when the normal is not a camera's but planned from a surface already explored (a
            re-planned wipe, tactex.tasks.wipe_references): VA-UFIC follows it while aligned as well
            (VaUficParams.follow_planned_rate).
    """

    valid: bool
    timestamp: float
    normal_camera: np.ndarray = field(default_factory=lambda: _NAN3.copy())
    normal_world: np.ndarray = field(default_factory=lambda: _NAN3.copy())
    e1_world: np.ndarray = field(default_factory=lambda: _NAN3.copy())
    e2_world: np.ndarray = field(default_factory=lambda: _NAN3.copy())
    centroid_world: np.ndarray = field(default_factory=lambda: _NAN3.copy())
    curvature: float = float("nan")
    theta_rad: float = float("nan")
    segment_size: int = 0
    reason: str = ""
    e1_camera: np.ndarray = field(default_factory=lambda: _NAN3.copy())
    e2_camera: np.ndarray = field(default_factory=lambda: _NAN3.copy())
    centroid_camera: np.ndarray = field(default_factory=lambda: _NAN3.copy())
    eigenvalues: np.ndarray = field(default_factory=lambda: _NAN3.copy())
    roi_points: int = 0
    planned: bool = False

    @classmethod
    def invalid(cls, timestamp: float, reason: str, roi_points: int = 0) -> SurfaceEstimate:
        """An estimate that must not be used, with the reason."""
        return cls(valid=False, timestamp=timestamp, reason=reason, roi_points=roi_points)

    @property
    def tool_z_world(self) -> np.ndarray:
        """(3,) the tool z axis that aligns the tool with the surface: −normal_world (VA-UFIC eq. 24
        with the tool axis pressing into the surface)."""
        return -self.normal_world
