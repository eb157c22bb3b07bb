"""The region raster (:mod:`.region_raster`) as a path a task follows (the ``PathSource`` of DESIGN.md).

It walks the plan's waypoints in contact at ``max_step_m`` per step, as :class:`~.raster.WaypointPath`
does, stops at the waypoint before each touch-down and then emits a
:class:`~tactex.ergodic.relocation.RelocationCommand` (lift off there, fly ``clearance_m`` above the
surface, touch down at the next segment), the way the explorer relocates. ``update_target`` plans again
over the dirt that is left, from where the tool is, as tactex does after a re-measurement.
"""

from __future__ import annotations

import numpy as np

from tactex.ergodic.command import ExplorationCommand
from tactex.ergodic.relocation import RelocationCommand, air_length
from tactex.errors import InputError
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.tasks.raster import WaypointPath, tangent_basis
from tactex.tasks.region_raster import WAYPOINT_TOUCH_DOWN, RegionRasterPlan, plan_region_raster

__all__ = ["RELOCATION_REASON", "RegionRasterPath"]

#: The reason the path's flights carry (one of the explorer's: the segment behind is done).
RELOCATION_REASON = "part_done"


class RegionRasterPath(WaypointPath):
    """Follows :func:`~.region_raster.plan_region_raster`'s plan over ``cloud``'s dirt.

    Args:
        cloud: the surface with normals and the captured dirt as target (cloud frame, [m]).
        pad_radius_m, line_spacing_m, gap_m: the plan's (see :func:`~.region_raster.plan_region_raster`) [m].
        max_step_m: the most the agent moves along the path per step [m].
        angle_step_deg: step between candidate line directions [deg].
        clearance_m: height of the flights above the surface [m].
        overrun_m: how far each line runs on past the dirt it covers [m] (default: the pad radius; see
            ``plan_region_raster``).
        start_m: where the tool is (3,) [m], for the order of the islands (default: the largest island's centre).

    Attributes:
        plan: the :class:`~.region_raster.RegionRasterPlan` being followed.
        path_length: the path in contact since the last ``reset`` [m] (also ``path_length_m``).
        air_path_length: the flights since the last ``reset`` [m].
        relocations: the :class:`RelocationCommand` s emitted since the last ``reset``.
    """

    def __init__(self, cloud: SurfaceCloud, pad_radius_m: float, line_spacing_m: float, gap_m: float,
                 max_step_m: float, *, angle_step_deg: float = 15.0, clearance_m: float = 0.02,
                 overrun_m: float | None = None, start_m: np.ndarray | None = None) -> None:
        self._options = dict(pad_radius_m=pad_radius_m, line_spacing_m=line_spacing_m, gap_m=gap_m,
                             angle_step_deg=angle_step_deg, clearance_m=clearance_m, overrun_m=overrun_m)
        self.clearance_m = float(clearance_m)
        self.target = np.array(cloud.target, dtype=float)
        plan = plan_region_raster(cloud, start_m=start_m, **self._options)
        super().__init__(cloud, plan.waypoints, max_step_m)
        self._use(plan, start_m)

    def _use(self, plan: RegionRasterPlan, start_m: np.ndarray | None = None) -> None:
        self.plan = plan
        self._start = None if start_m is None else np.array(start_m, dtype=float)
        self.waypoints = plan.waypoints
        self._k = 0
        self._x = self.waypoints[0].copy()
        self.path_length = 0.0
        self.air_path_length = 0.0
        self._relocations: list[RelocationCommand] = []

    def _replan(self, start_m: np.ndarray, from_start: bool) -> None:
        plan = plan_region_raster(self.cloud.with_target(self.target), start_m=start_m, from_start=from_start,
                                  **self._options)
        self._use(plan, start_m)

    @property
    def path_length_m(self) -> float:
        """The path in contact since the last ``reset`` [m]."""
        return self.path_length

    def reset(self, x0: np.ndarray | None = None) -> ExplorationCommand:
        """Start over at the plan's first waypoint, with the islands ordered from ``x0`` (3,) [m] when given (the
        plan is made again from there); the command there, at rest."""
        if x0 is not None and (self._start is None or not np.allclose(self._start, x0)):
            self._replan(np.asarray(x0, dtype=float), from_start=False)
        else:
            self._use(self.plan, self._start)
        return self._command(0, np.zeros(3))

    def update_target(self, mass: np.ndarray, keep_coverage: bool = False) -> None:
        """Plan again over the dirt ``mass`` (N,) ≥ 0 that is left, from where the agent is: the walk goes on from
        here, sliding or flying to the new plan's first segment (nothing left: the path is done).
        ``keep_coverage`` is the protocol's and changes nothing: a raster keeps no coverage."""
        mass = np.asarray(mass, dtype=float)
        if mass.shape != (len(self.cloud),) or not np.isfinite(mass).all() or mass.min(initial=0.0) < 0:
            raise InputError(f"the dirt left must be ({len(self.cloud)},) finite values ≥ 0, one per cloud point; "
                             f"got shape {mass.shape}")
        self.target = mass.copy()
        here = self._x.copy()
        if not np.any(mass > 0):
            self.waypoints = here[None]
            self._k = 0
            return
        path, air, relocations = self.path_length, self.air_path_length, self._relocations
        self._replan(here, from_start=True)
        self.path_length, self.air_path_length, self._relocations = path, air, relocations

    @property
    def relocations(self) -> list[RelocationCommand]:
        """The flights between islands and long gaps since the last ``reset``."""
        return self._relocations

    def step(self, measured_position: np.ndarray | None = None) -> ExplorationCommand | RelocationCommand:
        """The next command: a step of at most ``max_step_m`` along the path, or the flight to the next touch-down
        when the agent stands at the lift-off before it."""
        k = self._k
        if self.done:
            return self._walk(0.0, k)
        if self.plan.kind[k + 1] == WAYPOINT_TOUCH_DOWN:
            return self._fly(k)
        ahead = np.flatnonzero(self.plan.kind[k + 1:] == WAYPOINT_TOUCH_DOWN)
        last = k + int(ahead[0]) if ahead.size else len(self.waypoints) - 1
        return self._walk(self.max_step_m, last)

    def _fly(self, k: int) -> RelocationCommand:
        plan = self.plan
        up, down = plan.waypoints[k], plan.waypoints[k + 1]
        n_up, n_down = plan.normals[k], plan.normals[k + 1]
        air = air_length(up, n_up, down, n_down, self.clearance_m)
        u, v = tangent_basis(n_down)
        cmd = RelocationCommand(down.copy(), np.zeros(3), n_down.copy(), u, v, k + 1, 0, up.copy(), n_up.copy(),
                                self.clearance_m, air, RELOCATION_REASON)
        self._k = k + 1
        self._x = down.copy()
        self.air_path_length += air
        self._relocations.append(cmd)
        return cmd
