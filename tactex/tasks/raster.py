"""Boustrophedon (raster) coverage of a point cloud: the classic baseline for surface cleaning.

Lanes run across the cloud's principal plane (PCA), ``lane_spacing_m`` apart, along the direction in
which the surface bends (a cup's arc; spaced along its straight direction, so the spacing holds on the
surface); the path walks them in alternating directions in steps of ``step_m`` and is snapped to the
cloud (nearest point and its normal). It ignores the target: it cleans everything, in order.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from tactex.ergodic.command import ExplorationCommand
from tactex.errors import ConfigError, InputError
from tactex.pointcloud.cloud import SurfaceCloud

__all__ = ["RasterPath", "WaypointPath", "boustrophedon", "tangent_basis"]

#: How much more the normals tilt along the second principal axis than along the first before the lanes
#: run along the second (see :func:`boustrophedon`) [-].
BEND_SWAP_RATIO = 1.5


def boustrophedon(cloud: SurfaceCloud, lane_spacing_m: float, step_m: float) -> np.ndarray:
    """Waypoints (M, 3) [m] of a raster over the cloud, on the cloud (nearest points dropped where
    the surface is absent, e.g. outside a round plate)."""
    if not (lane_spacing_m > 0 and step_m > 0):
        raise ConfigError(f"lane spacing and step must be > 0 m, got {lane_spacing_m} and {step_m}")
    pts = cloud.points
    centre = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - centre, full_matrices=False)
    axes = vt[:2]
    if cloud.normals is not None:
        # Lanes run along the direction in which the surface bends and are spaced along the one in which
        # it stays straight, so the spacing holds on the surface: on a half cylinder (the cup) lanes spaced
        # across the arc would be 1/cos(angle) farther apart on the surface towards its sides, and the
        # pad would miss strips there. A surface bending about alike both ways keeps the principal order.
        bend = np.mean((cloud.normals @ axes.T) ** 2, axis=0)
        if bend[1] > BEND_SWAP_RATIO * bend[0]:
            axes = axes[::-1]
    uv = (pts - centre) @ axes.T
    (u0, v0), (u1, v1) = uv.min(axis=0), uv.max(axis=0)
    tree2d = cKDTree(uv)
    waypoints = []
    # as many lanes as it takes to be at most lane_spacing_m apart, spread evenly: the first and the last
    # half a spacing or less from the edges (at a fixed spacing from one edge, the other edge's strip
    # could be up to a whole spacing from the last lane, out of the pad's reach)
    n_lanes = max(int(np.ceil((v1 - v0) / lane_spacing_m - 1e-9)), 1)
    lanes = v0 + (np.arange(n_lanes) + 0.5) * (v1 - v0) / n_lanes
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


def tangent_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An orthonormal tangent basis (u, v) (3,) each of the unit ``normal`` (3,), (u, v, normal) right-handed."""
    u = np.cross(normal, [0.0, 1.0, 0.0] if abs(normal[0]) > 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    return u, np.cross(normal, u)


class WaypointPath:
    """Serves a path of waypoints on a cloud as :class:`ExplorationCommand`s, like the explorer does (a
    :class:`~tactex.tasks.path_source.PathSource`), moving at most ``max_step_m`` per step along them; each
    command's normal is that of the cloud point nearest to it. It ignores the target and never leaves the
    surface.

    ``tree``: a KD-tree of ``cloud.points`` built already (the wear model's): a path planned while the
    robot is in contact (a stroke) must not spend milliseconds building its own."""

    def __init__(self, cloud: SurfaceCloud, waypoints: np.ndarray, max_step_m: float,
                 tree: cKDTree | None = None) -> None:
        if cloud.normals is None:
            raise InputError("a path on the surface needs a cloud with normals")
        if not max_step_m > 0:
            raise ConfigError(f"the path's step must be > 0 m, got {max_step_m}")
        waypoints = np.asarray(waypoints, dtype=float).reshape(-1, 3)
        if len(waypoints) == 0:
            raise InputError("a path needs at least one waypoint")
        self.cloud = cloud
        self.max_step_m = float(max_step_m)
        self.waypoints = waypoints
        if tree is not None and tree.n != len(cloud.points):
            raise InputError(f"the KD-tree holds {tree.n} points, the cloud {len(cloud.points)}: "
                             "build it on this cloud's points")
        self._tree = cKDTree(cloud.points) if tree is None else tree
        self._k = 0
        self.path_length = 0.0
        self._x = self.waypoints[0].copy()

    @property
    def done(self) -> bool:
        return self._k >= len(self.waypoints) - 1

    @property
    def relocations(self) -> tuple:
        """None: a waypoint path slides from one waypoint to the next on the surface."""
        return ()

    def update_target(self, mass: np.ndarray, keep_coverage: bool = False) -> None:
        """Nothing changes: the path goes over its waypoints whatever the target."""

    @property
    def tree(self) -> cKDTree:
        """KD-tree of the cloud's points (the normal of each command comes from its nearest point)."""
        return self._tree

    def _command(self, step: int, velocity: np.ndarray) -> ExplorationCommand:
        n = self.cloud.normals[int(self._tree.query(self._x)[1])]
        u, v = tangent_basis(n)
        return ExplorationCommand(self._x.copy(), velocity, n.copy(), u, v, step, 0)

    def reset(self, x0: np.ndarray | None = None) -> ExplorationCommand:
        """Start at the waypoint nearest ``x0`` (default: the first) and walk on from there, wrapping
        around to the beginning."""
        self._k = 0 if x0 is None else int(np.argmin(np.linalg.norm(self.waypoints - np.asarray(x0), axis=1)))
        self.waypoints = np.concatenate([self.waypoints[self._k:], self.waypoints[: self._k]])
        self._k = 0
        self._x = self.waypoints[0].copy()
        self.path_length = 0.0
        return self._command(0, np.zeros(3))

    def extend(self, waypoints: np.ndarray) -> None:
        """Append waypoints (M, 3) [m] to the path (the walk goes on through them)."""
        self.waypoints = np.concatenate([self.waypoints, np.asarray(waypoints, dtype=float).reshape(-1, 3)])

    def step(self, measured_position: np.ndarray | None = None) -> ExplorationCommand:
        return self._walk(self.max_step_m, len(self.waypoints) - 1)

    def _walk(self, budget_m: float, last: int) -> ExplorationCommand:
        """Move on along the waypoints by at most ``budget_m`` [m], stopping at waypoint index ``last``; the
        command there (a path with lift-offs stops at the waypoint before each)."""
        start = self._x.copy()
        while budget_m > 1e-12 and self._k < last:
            nxt = self.waypoints[self._k + 1]
            d = float(np.linalg.norm(nxt - self._x))
            if d <= budget_m:
                self._x = nxt.copy()
                self._k += 1
                budget_m -= d
            else:
                self._x = self._x + (nxt - self._x) * (budget_m / d)
                budget_m = 0.0
        self.path_length += float(np.linalg.norm(self._x - start))
        return self._command(self._k, self._x - start)


class RasterPath(WaypointPath):
    """The boustrophedon of :func:`boustrophedon` as a path (``lane_spacing_m`` apart, ``max_step_m`` per
    step)."""

    def __init__(self, cloud: SurfaceCloud, lane_spacing_m: float, max_step_m: float) -> None:
        if cloud.normals is None:
            raise InputError("the raster baseline needs a cloud with normals")
        super().__init__(cloud, boustrophedon(cloud, lane_spacing_m, max_step_m), max_step_m)
