"""Depth frame + tool pose → :class:`SurfaceEstimate` (VA-UFIC §II-B, eq. 14–16, 22).

What one call does, in two stages (the two threads of the paper's pipeline):

``prepare`` (acquisition / pre-processing)
    1. validate the depth image (shape, dtype, units) and the poses;
    2. express the tool axis (a line through the TCP along z_tool) in the camera frame;
    3. march along that line through the depth image to find where it first meets the surface
       (t_hit, distance from the TCP along the axis);
    4. region of interest: the cylinder of radius ``roi_radius_m`` around the axis, between
       t_hit ∓ ``depth_window_m`` (and never behind ``axis_start_m``, which cuts the tool body
       away); its image bounding box is found by projecting samples of the cylinder;
    5. back-project only that box, every ``stride``-th pixel; the stride grows until the box
       holds at most ``max_grid_cells`` cells (documented sub-sampling: the point budget is
       bounded whatever the distance to the surface).

``estimate_prepared`` (surface estimation)
    6. per-point normals and curvature from a window of radius ``normal_radius_m`` on the
       image grid (integral images, closed-form 3×3 eigenpairs) — or k-NN for ``knn``;
    7. region growing on normals (smoothness angle, curvature threshold, cluster size);
    8. the segment under the tool: the one holding the point nearest to the axis, if that
       point is within ``capture_radius_m``;
    9. PCA of the segment → n_s^c, e1, e2, l_s (eq. 16), θ (eq. 15) and the world-frame
       quantities (eq. 22: n_s^0 = R_c^0 n_s^c).

Nothing invalid is passed on: a frame without a usable segment gives
``SurfaceEstimate.invalid(reason=...)``; malformed input raises a :mod:`tactex.errors` type.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from tactex.config import param
from tactex.errors import CloudError, ConfigError, PerceptionError
from tactex.perception.axis_normal import normal_at_axis
from tactex.perception.depth import check_pose, depth_in_meters
from tactex.perception.estimate import SurfaceEstimate
from tactex.perception.frame import CameraFrame, CameraIntrinsics
from tactex.perception.normals import NormalField, grid_normals, knn_normals
from tactex.perception.pca import orientation_error, segment_pca
from tactex.perception.region_growing import RegionGrowingParams, grid_edges, knn_edges, region_growing

__all__ = ["PreparedPatch", "SurfaceEstimator", "SurfaceEstimatorConfig"]


_AXIS_WINDOW_PX = 3  # half-width of the window read where the tool axis crosses the image


@dataclass(frozen=True)
class SurfaceEstimatorConfig:
    """Parameters of the surface estimator (VA-UFIC gives none; these suit a D435i on a wrist)."""

    roi_radius_m: float = param(0.03, "radius of the region of interest around the tool axis [m]")
    depth_window_m: float = param(0.06, "ROI extent before/behind the axis-surface hit along the axis [m]")
    axis_start_m: float = param(-0.005, "ROI starts this far along the tool axis from the TCP (cuts the tool body) [m]")
    capture_radius_m: float = param(0.01, "the chosen segment must come this close to the tool axis [m]")
    stride: int = param(2, "smallest pixel stride of the ROI sub-sampling [px]")
    max_grid_cells: int = param(6000, "the stride grows until the ROI box holds at most this many cells")
    normal_radius_m: float = param(0.008, "half-width of the normal-estimation window [m]")
    max_normal_radius_px: int = param(6, "cap on the normal window half-width [grid cells]")
    min_window_points: int = param(5, "fewest valid points in a normal window")
    edge_gate: float = param(3.0, "grid neighbours farther apart than this × the pixel footprint are not linked")
    neighbourhood: str = param("grid", "normals and region growing on the image 'grid' or on 'knn'")
    knn_k: int = param(16, "neighbours for the knn neighbourhood")
    smoothness_angle_deg: float = param(10.0, "region growing: max angle between neighbouring normals [deg]")
    curvature_threshold: float = param(0.05, "region growing: max curvature of a growing point [-]")
    min_cluster_size: int = param(50, "region growing: smallest segment [points]")
    max_cluster_size: int = param(1_000_000, "region growing: largest segment [points]")
    normal_at_axis: bool = param(
        False, "the normal where the tool axis meets the segment, from a quadric fitted to it "
        "(tactex.perception.axis_normal); False: PCA's normal, the paper's, which on a curved part is the normal "
        "near the segment's centroid, off the axis on the side the camera sees")

    def __post_init__(self) -> None:
        for name in ("roi_radius_m", "depth_window_m", "capture_radius_m", "normal_radius_m", "edge_gate"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ConfigError(f"SurfaceEstimatorConfig.{name} must be a positive number, got {value!r}")
        if not np.isfinite(self.axis_start_m):
            raise ConfigError(f"SurfaceEstimatorConfig.axis_start_m must be finite, got {self.axis_start_m!r}")
        for name in ("stride", "max_grid_cells", "max_normal_radius_px", "min_window_points", "knn_k"):
            value = getattr(self, name)
            if int(value) != value or value < 1:
                raise ConfigError(f"SurfaceEstimatorConfig.{name} must be a positive integer, got {value!r}")
        if self.neighbourhood not in ("grid", "knn"):
            raise ConfigError(f"unknown neighbourhood '{self.neighbourhood}'; valid: grid, knn")
        if self.knn_k < 3:
            raise ConfigError(f"knn_k must be ≥ 3, got {self.knn_k}")
        self.region_growing()  # validates those fields

    def region_growing(self) -> RegionGrowingParams:
        return RegionGrowingParams(
            self.smoothness_angle_deg, self.curvature_threshold, self.min_cluster_size, self.max_cluster_size
        )


class PreparedPatch(NamedTuple):
    """The region of interest of one frame, ready for normal estimation (camera frame).

    Attributes:
        timestamp: frame time [s].
        world_T_camera: (4, 4).
        axis_origin, axis_dir: the tool axis in the camera frame (TCP [m], unit z_tool).
        points_grid: (h, w, 3) back-projected ROI grid [m] (garbage where not ``valid``).
        valid: (h, w) valid depth inside the ROI cylinder.
        stride: pixel stride used.
        focal_px: min(fx, fy) [px].
        reason: non-empty when the frame cannot give an estimate (e.g. the axis meets no surface).
    """

    timestamp: float
    world_T_camera: np.ndarray
    axis_origin: np.ndarray
    axis_dir: np.ndarray
    points_grid: np.ndarray
    valid: np.ndarray
    stride: int
    focal_px: float
    reason: str = ""

    @property
    def n_valid(self) -> int:
        return int(np.count_nonzero(self.valid))


def _project(intr: CameraIntrinsics, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(column u, row v) of camera-frame points (z > 0)."""
    return intr.fx * q[:, 0] / q[:, 2] + intr.cx, intr.fy * q[:, 1] / q[:, 2] + intr.cy


class SurfaceEstimator:
    """Stateless, deterministic surface estimator; see the module docstring for the steps."""

    def __init__(self, config: SurfaceEstimatorConfig | None = None) -> None:
        self.config = config or SurfaceEstimatorConfig()
        self._rg = self.config.region_growing()

    # ---------------------------------------------------------------- stage 1: pre-processing
    def prepare(self, frame: CameraFrame, world_T_tool: np.ndarray | None = None) -> PreparedPatch:
        """Validate the frame and cut the region of interest around the tool axis.

        Args:
            frame: the depth frame (RGB is not needed here).
            world_T_tool: (4, 4) tool pose (TCP, z_tool into the surface); None means the tool
                axis is the camera's optical axis (the paper's set-up).
        """
        cfg = self.config
        if not isinstance(frame, CameraFrame):
            raise PerceptionError(f"expected a CameraFrame, got {type(frame).__name__}")
        intr = frame.intrinsics
        depth = depth_in_meters(frame.depth_m, intr)
        w_T_c = check_pose(frame.world_T_camera, "frame.world_T_camera")
        if world_T_tool is None:
            origin, axis = np.zeros(3), np.array([0.0, 0.0, 1.0])
        else:
            w_T_t = check_pose(world_T_tool, "world_T_tool")
            rot_cw = w_T_c[:3, :3].T
            origin = rot_cw @ (w_T_t[:3, 3] - w_T_c[:3, 3])
            axis = rot_cw @ w_T_t[:3, 2]
        focal = float(min(intr.fx, intr.fy))

        def invalid(reason: str) -> PreparedPatch:
            return PreparedPatch(
                frame.timestamp, w_T_c, origin, axis, np.empty((0, 0, 3)), np.empty((0, 0), bool), 0, focal, reason
            )

        t_hit = self._axis_hit(depth, intr, origin, axis)
        if t_hit is None:
            return invalid(
                "the tool axis meets no valid depth in the image (surface out of view or out of "
                f"[{intr.min_depth_m}, {intr.max_depth_m}] m)"
            )
        t_lo = max(cfg.axis_start_m, t_hit - cfg.depth_window_m)
        t_hi = t_hit + cfg.depth_window_m
        bbox = self._roi_bbox(intr, origin, axis, t_lo, t_hi)
        if bbox is None:
            return invalid("the region of interest around the tool axis is outside the image")
        r0, r1, c0, c1 = bbox
        area = (r1 - r0) * (c1 - c0)
        stride = max(int(cfg.stride), int(np.ceil(np.sqrt(area / cfg.max_grid_cells))))
        z = depth[r0:r1:stride, c0:c1:stride].astype(np.float64)
        rows = np.arange(r0, r1, stride, dtype=np.float64)[:, None]
        cols = np.arange(c0, c1, stride, dtype=np.float64)[None, :]
        with np.errstate(invalid="ignore"):
            valid = np.isfinite(z) & (z >= intr.min_depth_m) & (z <= intr.max_depth_m) & (z > 0)
        z = np.where(valid, z, 0.0)
        grid = np.empty((*z.shape, 3))
        grid[..., 0] = (cols - intr.cx) * z / intr.fx
        grid[..., 1] = (rows - intr.cy) * z / intr.fy
        grid[..., 2] = z
        rel = grid - origin
        t = np.einsum("...i,i->...", rel, axis)
        radial2 = np.einsum("...i,...i->...", rel, rel) - t * t
        valid &= (radial2 <= cfg.roi_radius_m**2) & (t >= t_lo) & (t <= t_hi)
        return PreparedPatch(frame.timestamp, w_T_c, origin, axis, grid, valid, stride, focal)

    def _axis_hit(
        self, depth: np.ndarray, intr: CameraIntrinsics, origin: np.ndarray, axis: np.ndarray
    ) -> float | None:
        """Distance along the tool axis from the TCP to the first observed surface [m], or None."""
        t_max = 2.0 * intr.max_depth_m + float(np.linalg.norm(origin))
        t = self.config.axis_start_m + (t_max - self.config.axis_start_m) * np.linspace(0.0, 1.0, 512) ** 2
        q = origin + t[:, None] * axis
        ahead = q[:, 2] > 1e-6
        t, q = t[ahead], q[ahead]
        if t.size == 0:
            return None
        u, v = _project(intr, q)
        ui, vi = np.round(u).astype(np.int64), np.round(v).astype(np.int64)
        inside = (ui >= 0) & (ui < intr.width) & (vi >= 0) & (vi < intr.height)
        t, q, ui, vi = t[inside], q[inside], ui[inside], vi[inside]
        if t.size == 0:
            return None
        # Real depth has holes: read the median valid depth of a small window around each pixel
        # (once per distinct pixel; an axis parallel to the optical axis projects to one pixel).
        pix, inverse = np.unique(np.stack([vi, ui], axis=1), axis=0, return_inverse=True)
        w = _AXIS_WINDOW_PX
        off = np.arange(-w, w + 1)
        rr = np.clip(pix[:, 0, None, None] + off[None, :, None], 0, intr.height - 1)
        cc = np.clip(pix[:, 1, None, None] + off[None, None, :], 0, intr.width - 1)
        win = depth[rr, cc].reshape(pix.shape[0], -1).astype(np.float64)
        with np.errstate(invalid="ignore"):
            good = np.isfinite(win) & (win >= intr.min_depth_m) & (win <= intr.max_depth_m)
        win[~good] = np.nan
        has = good.any(axis=1)
        med = np.full(pix.shape[0], np.nan)
        if has.any():
            med[has] = np.nanmedian(win[has], axis=1)
        d = med[inverse.reshape(-1)]
        ok = np.isfinite(d)
        t, q, d = t[ok], q[ok], d[ok]
        behind = q[:, 2] >= d
        if not behind.any():
            return None
        k = int(np.argmax(behind))
        if k == 0:
            return float(t[0])
        f0, f1 = q[k - 1, 2] - d[k - 1], q[k, 2] - d[k]
        return float(t[k - 1] + (t[k] - t[k - 1]) * (-f0) / (f1 - f0)) if f1 != f0 else float(t[k])

    def _roi_bbox(
        self, intr: CameraIntrinsics, origin: np.ndarray, axis: np.ndarray, t_lo: float, t_hi: float
    ) -> tuple[int, int, int, int] | None:
        """Image box (row0, row1, col0, col1) holding the projected ROI cylinder (sampled)."""
        helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e_u = np.cross(axis, helper)
        e_u /= np.linalg.norm(e_u)
        e_v = np.cross(axis, e_u)
        ang = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
        ring = self.config.roi_radius_m * (np.cos(ang)[:, None] * e_u + np.sin(ang)[:, None] * e_v)
        ts = np.linspace(t_lo, t_hi, 24)
        q = (origin + ts[:, None] * axis)[:, None, :] + ring[None, :, :]
        q = q.reshape(-1, 3)
        q = q[q[:, 2] >= max(intr.min_depth_m, 1e-6)]
        if q.shape[0] == 0:
            return None
        u, v = _project(intr, q)
        margin = 2
        r0 = int(np.clip(np.floor(v.min()) - margin, 0, intr.height))
        r1 = int(np.clip(np.ceil(v.max()) + margin + 1, 0, intr.height))
        c0 = int(np.clip(np.floor(u.min()) - margin, 0, intr.width))
        c1 = int(np.clip(np.ceil(u.max()) + margin + 1, 0, intr.width))
        if r1 <= r0 or c1 <= c0:
            return None
        return r0, r1, c0, c1

    # ---------------------------------------------------------------- stage 2: estimation
    def segment(self, patch: PreparedPatch) -> tuple[np.ndarray, NormalField, np.ndarray]:
        """Normals and region growing on a prepared patch's valid points.

        Returns:
            (points (N, 3) camera frame [m], normals/curvature, labels (N,) with −1 = noise).
        """
        cfg = self.config
        n_valid = patch.n_valid
        vi, ui = np.nonzero(patch.valid)
        points = patch.points_grid[vi, ui]
        if cfg.neighbourhood == "grid":
            z_med = float(np.median(points[:, 2])) if n_valid else 1.0
            radius_px = int(np.clip(round(cfg.normal_radius_m * patch.focal_px / (z_med * patch.stride)), 1,
                                    cfg.max_normal_radius_px))
            field: NormalField = grid_normals(patch.points_grid, patch.valid, radius_px,
                                              min_count=cfg.min_window_points)
            cell = np.full(patch.valid.shape, -1, dtype=np.int64)
            cell[vi, ui] = np.arange(n_valid)
            footprint = patch.stride * points[:, 2] / patch.focal_px
            edges = grid_edges(cell, points, cfg.edge_gate * np.sqrt(2.0) * footprint)
        else:
            field = knn_normals(points, cfg.knn_k)
            edges = knn_edges(points, cfg.knn_k)
        return points, field, region_growing(field.normals, field.curvature, edges, self._rg)

    def estimate_prepared(self, patch: PreparedPatch) -> SurfaceEstimate:
        """Normals, region growing and PCA on a prepared patch."""
        cfg = self.config
        ts = patch.timestamp
        if patch.reason:
            return SurfaceEstimate.invalid(ts, patch.reason)
        n_valid = patch.n_valid
        if n_valid < max(cfg.min_cluster_size, 3):
            return SurfaceEstimate.invalid(
                ts,
                f"only {n_valid} valid depth points in the region of interest (need ≥ {cfg.min_cluster_size}); "
                "the surface is too far, too small or not seen",
                n_valid,
            )
        if cfg.neighbourhood == "knn" and n_valid <= cfg.knn_k:
            return SurfaceEstimate.invalid(
                ts, f"{n_valid} points in the region of interest are too few for {cfg.knn_k} neighbours", n_valid
            )
        points, _, labels = self.segment(patch)
        labelled = np.flatnonzero(labels >= 0)
        if labelled.size == 0:
            return SurfaceEstimate.invalid(
                ts, "region growing found no smooth segment of at least "
                f"{cfg.min_cluster_size} points in the region of interest", n_valid
            )
        rel = points[labelled] - patch.axis_origin
        t = np.einsum("ij,j->i", rel, patch.axis_dir)
        dist = np.sqrt(np.maximum(np.einsum("ij,ij->i", rel, rel) - t * t, 0.0))
        nearest = int(np.argmin(dist))
        if dist[nearest] > cfg.capture_radius_m:
            return SurfaceEstimate.invalid(
                ts, f"no segment under the tool: the nearest segment is {dist[nearest] * 1e3:.1f} mm from the "
                f"tool axis (capture radius {cfg.capture_radius_m * 1e3:.1f} mm)", n_valid
            )
        seg = labels == labels[labelled[nearest]]
        try:
            pca = segment_pca(points[seg])
        except CloudError as exc:
            return SurfaceEstimate.invalid(ts, f"segment PCA failed: {exc}", n_valid)
        normal = normal_at_axis(points[seg], pca, patch.axis_origin, patch.axis_dir) if cfg.normal_at_axis \
            else pca.normal
        theta = orientation_error(normal, patch.axis_dir)
        rot, trans = patch.world_T_camera[:3, :3], patch.world_T_camera[:3, 3]
        est = SurfaceEstimate(
            valid=True,
            timestamp=ts,
            normal_camera=normal,
            normal_world=rot @ normal,
            e1_world=rot @ pca.e1,
            e2_world=rot @ pca.e2,
            centroid_world=rot @ pca.centroid + trans,
            curvature=pca.curvature,
            theta_rad=theta,
            segment_size=int(seg.sum()),
            e1_camera=pca.e1,
            e2_camera=pca.e2,
            centroid_camera=pca.centroid,
            eigenvalues=pca.eigenvalues,
            roi_points=n_valid,
        )
        vectors = (est.normal_camera, est.normal_world, est.e1_world, est.e2_world, est.centroid_world)
        if not (all(np.isfinite(v).all() for v in vectors) and np.isfinite(est.curvature) and np.isfinite(theta)):
            return SurfaceEstimate.invalid(ts, "the estimate is not finite (degenerate segment)", n_valid)
        return est

    def estimate(self, frame: CameraFrame, world_T_tool: np.ndarray | None = None) -> SurfaceEstimate:
        """Synchronous, deterministic estimate (for simulation): ``prepare`` then ``estimate_prepared``."""
        return self.estimate_prepared(self.prepare(frame, world_T_tool))
