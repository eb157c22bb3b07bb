"""Boustrophedon (raster) coverage of a point cloud: the classic baseline for surface cleaning.

Lanes run across the cloud's principal plane (PCA), ``lane_spacing_m`` apart; the path walks them
in alternating directions in steps of ``step_m`` and is snapped to the cloud (nearest point and its
normal). It ignores the target: it cleans everything, in order.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from tactex.ergodic.command import ExplorationCommand
from tactex.errors import ConfigError, InputError
from tactex.pointcloud.cloud import SurfaceCloud

__all__ = ["RasterPath", "boustrophedon"]


def boustrophedon(cloud: SurfaceCloud, lane_spacing_m: float, step_m: float) -> np.ndarray:
    """Waypoints (M, 3) [m] of a raster over the cloud, on the cloud (nearest points dropped where
    the surface is absent, e.g. outside a round plate)."""
    if not (lane_spacing_m > 0 and step_m > 0):
        raise ConfigError(f"lane spacing and step must be > 0 m, got {lane_spacing_m} and {step_m}")
    pts = cloud.points
    centre = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - centre, full_matrices=False)
    uv = (pts - centre) @ vt[:2].T
    (u0, v0), (u1, v1) = uv.min(axis=0), uv.max(axis=0)
    tree2d = cKDTree(uv)
    waypoints = []
    lanes = np.arange(v0 + lane_spacing_m / 2, v1, lane_spacing_m)
    for k, v in enumerate(lanes):
        us = np.arange(u0, u1 + 1e-12, step_m)
        if k % 2:
            us = us[::-1]
        q = np.column_stack([us, np.full_like(us, v)])
        dist, idx = tree2d.query(q)
        keep = dist <= max(2.0 * cloud.spacing, step_m)
        waypoints.append(pts[idx[keep]])
    if not waypoints or sum(len(w) for w in waypoints) == 0:
        raise InputError("the cloud is too small for a raster with this lane spacing")
    return np.concatenate(waypoints)


class RasterPath:
    """Serves the raster as :class:`ExplorationCommand`s, like the explorer does (same interface:
    ``reset(x0)``, ``step()``), moving at most ``max_step_m`` per step along the waypoints."""

    def __init__(self, cloud: SurfaceCloud, lane_spacing_m: float, max_step_m: float) -> None:
        if cloud.normals is None:
            raise InputError("the raster baseline needs a cloud with normals")
        self.cloud = cloud
        self.max_step_m = float(max_step_m)
        self.waypoints = boustrophedon(cloud, lane_spacing_m, max_step_m)
        self._tree = cKDTree(cloud.points)
        self._k = 0
        self.path_length = 0.0
        self._x = self.waypoints[0].copy()

    @property
    def done(self) -> bool:
        return self._k >= len(self.waypoints) - 1

    def _command(self, step: int, velocity: np.ndarray) -> ExplorationCommand:
        n = self.cloud.normals[int(self._tree.query(self._x)[1])]
        u = np.cross(n, [0.0, 1.0, 0.0] if abs(n[0]) > 0.9 else [1.0, 0.0, 0.0])
        u /= np.linalg.norm(u)
        return ExplorationCommand(self._x.copy(), velocity, n.copy(), u, np.cross(n, u), step, 0)

    def reset(self, x0: np.ndarray | None = None) -> ExplorationCommand:
        """Start at the waypoint nearest ``x0`` (default: the first)."""
        self._k = 0 if x0 is None else int(np.argmin(np.linalg.norm(self.waypoints - np.asarray(x0), axis=1)))
        # walk the lanes from where we start, wrapping around to the beginning
        self.waypoints = np.concatenate([self.waypoints[self._k:], self.waypoints[: self._k]])
        self._k = 0
        self._x = self.waypoints[0].copy()
        self.path_length = 0.0
        return self._command(0, np.zeros(3))

    def step(self, measured_position: np.ndarray | None = None) -> ExplorationCommand:
        budget = self.max_step_m
        start = self._x.copy()
        while budget > 1e-12 and not self.done:
            nxt = self.waypoints[self._k + 1]
            d = float(np.linalg.norm(nxt - self._x))
            if d <= budget:
                self._x = nxt.copy()
                self._k += 1
                budget -= d
            else:
                self._x = self._x + (nxt - self._x) * (budget / d)
                budget = 0.0
        self.path_length += float(np.linalg.norm(self._x - start))
        return self._command(self._k, self._x - start)
