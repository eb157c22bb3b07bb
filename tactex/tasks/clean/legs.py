"""The legs of a cleaning run in contact: what the agent follows from a touch-down (a straight stroke
through a small island, the planned first sweep, or the path source) and what comes after a stroke, the
path figures summed over the legs, and the wear model fed tick by tick."""

from __future__ import annotations

import warnings

import numpy as np

from tactex.ergodic.command import ExplorationCommand
from tactex.ergodic.explorer import HedacExplorer
from tactex.ergodic.relocation import RelocationCommand
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.tasks.clean.config import SWEEP_GOAL, CleanConfig
from tactex.tasks.clean.sweep_plan import SweepPlan, dirt_island, plan_sweep, stroke_like
from tactex.tasks.path_source import PathSource, start
from tactex.tasks.raster import WaypointPath
from tactex.tasks.stroke import MAX_PASSES, IslandStroke, plan_stroke
from tactex.tasks.wear_model import WearModel

#: A sweep of at most this many legs is searched first; one of up to ``CleanConfig.sweep_corners`` only when none
#: of these reaches the goal [-].
FEW_CORNERS = 5

__all__ = ["FEW_CORNERS", "MAX_HOLD_STEPS", "RASTER_SKIP_M", "SWEEP_MIN_SHARE", "plan_stroke", "plan_sweep",
           "skip_along"]

#: A raster whose touch-down is out of the arm's reach goes on along its path this far before trying again [m].
RASTER_SKIP_M = 0.02


def skip_along(path: PathSource, point_m: np.ndarray, name: str) -> ExplorationCommand | RelocationCommand | None:
    """Past a touch-down ``point_m`` (3,) [m] whose hover is out of reach: the next command of a raster's ``path``
    at least :data:`RASTER_SKIP_M` from it, or its next flight, whichever comes first; None when the path ends
    before. Either is said in a warning naming the raster (``name``)."""
    out = np.round(point_m, 3).tolist()
    while not path.done:
        cmd = path.step()
        if isinstance(cmd, RelocationCommand) or np.linalg.norm(cmd.point - point_m) >= RASTER_SKIP_M:
            warnings.warn(f"clean: no hover pose over {out} m within reach; the {name} goes on at "
                          f"{np.round(cmd.point, 3).tolist()} m", RuntimeWarning, stacklevel=4)
            return cmd
    warnings.warn(f"clean: no hover pose over {out} m within reach and the {name} ends there; ending the program",
                  RuntimeWarning, stacklevel=4)
    return None

#: Most exploration steps in a row the agent waits for a lagging or dragged tool (CleanConfig.max_lag_m,
#: CleanConfig.hold_force_ratio): a point the tool cannot reach must not hold the program [-].
MAX_HOLD_STEPS = 10
#: The planned sweep is made when the island of dirt at the touch-down (dirt joined within two pad radii) holds at
#: least this share of the view's dirt [-].
SWEEP_MIN_SHARE = 0.95


class _Legs:
    """The path figures summed over the legs of the path source (each ``reset`` starts its path again); the
    explorer's own figures (flights, keep-out contacts) when ``explorer`` is the source."""

    def __init__(self, path: PathSource, explorer: HedacExplorer | None = None) -> None:
        self.path, self.explorer = path, explorer
        self.path_m = 0.0  # [m] the agent's path on the surface in the legs before the current one
        self.air_m = 0.0  # [m] and its relocations' flights
        self.relocations = 0
        self.keep_out_contacts = 0

    def restart(self, x0: np.ndarray) -> ExplorationCommand:
        """Close the current leg and start the next at ``x0`` [m]; its first command."""
        self.path_m += float(self.path.path_length)
        self.relocations += len(self.path.relocations)
        if self.explorer is not None:
            self.air_m += float(self.explorer.air_path_length)
            self.keep_out_contacts += int(self.explorer.keep_out_contacts)
        return start(self.path, x0)


class _WearTicks:
    """The contact work ∫F_n·v_t dt [N·m] of each control tick, handed to the wear model every
    ``every`` ticks (:meth:`WearModel.wipe`).

    A tick's resulting state is noted (:meth:`note`) and accounted by :meth:`settle`, which the task
    calls from the next tick's ``after_send`` (on a real robot: while the robot executes that command,
    outside the cycle's critical path) and before anything reads the model. The states and their
    order are those of accounting at once, so the model holds the same values whenever it is read.
    """

    def __init__(self, wear: WearModel, dt: float, every: int = 10) -> None:
        self.wear, self.dt, self.every = wear, dt, every
        self.restart()

    def restart(self) -> None:
        """A new contact phase: nothing carried over."""
        self.fv = 0.0
        self.ticks = 0
        self._pending: tuple | None = None

    def note(self, state, normal: np.ndarray) -> None:
        """The state a tick produced, with the normal line it was commanded along."""
        self._pending = (state, normal)

    def settle(self, _state=None) -> None:
        """Account the noted tick, if not done yet (usable as ``after_send``)."""
        if self._pending is None:
            return
        st, normal = self._pending
        self._pending = None
        fn = float(st.wrench_tool[2])
        if fn > self.wear.threshold:
            v = st.ee_twist[:3]
            vn = float(v @ normal)
            self.fv += fn * float(np.sqrt(max(float(v @ v) - vn * vn, 0.0))) * self.dt
        self.ticks += 1
        if self.ticks >= self.every:
            self.wear.wipe(st.ee_position, self.fv)
            self.fv, self.ticks = 0.0, 0



def _first_leg(cloud: SurfaceCloud, wear: WearModel, here_m: np.ndarray, from_m: np.ndarray, cfg: CleanConfig,
               step_m: float, support_z_m: float | None) -> tuple[IslandStroke | None, SweepPlan | None, str]:
    """The first leg in contact from the touch-down ``here_m`` (3,) [m], planned while the arm holds at the capture
    pose: ``(stroke, plan, choice)``, ``choice`` one line saying what was chosen and why. When the wear model's
    island of dirt there is smaller than the pad, its straight stroke (coming from ``from_m`` (3,) [m]) and None.
    Else, with ``cfg.sweep_corners`` > 0 and an island of strokes (:func:`stroke_like`), the planned sweep over that
    island (dirt joined within two pad radii) as a stroke, and its plan; but no stroke and no plan (the explorer
    from the touch-down) when the model sees no dirt, when the island is a blob as wide as the pad (passes side by
    side: the explorer's feedback does as well), holds less than :data:`SWEEP_MIN_SHARE` of the view's dirt (after
    a sweep of one island among several the explorer's route over the others is longer than from its own start)
    or no polyline of ``cfg.sweep_corners`` legs (:data:`FEW_CORNERS` tried first) reaches :data:`SWEEP_GOAL` within
    the camera's steps of ``step_m`` [m]. ``support_z_m`` [m]: the plane the object stands on (None: none)."""
    stroke = plan_stroke(cloud, wear.tree, wear, here_m, from_m, cfg.pad_radius_m, step_m)
    if stroke is not None:
        return stroke, None, "a stroke over a small island"
    if cfg.sweep_corners == 0:
        return None, None, "the explorer (no planned sweep: sweep_corners = 0)"
    view_dirt = wear.remaining()
    if not float(view_dirt.sum()) > 0.0:
        return None, None, "the explorer (the wear model sees no dirt left)"
    island = dirt_island(cloud.points, view_dirt, here_m, 2.0 * cfg.pad_radius_m, spacing_m=cloud.spacing)
    share = float(view_dirt[island].sum()) / float(view_dirt.sum())
    if share < SWEEP_MIN_SHARE:
        return None, None, f"the explorer (the island there holds {100 * share:.0f} % of the dirt, one of several)"
    if not stroke_like(cloud.points, wear.tree, island, cfg.pad_radius_m, cloud.spacing):
        return None, None, "the explorer (the dirt is a blob as wide as the pad or wider)"
    # the fewest legs first: a search over more corners finds longer detours as easily as shorter sweeps, and
    # the tool rounds every corner the plan has
    for n_corners in sorted({min(FEW_CORNERS, cfg.sweep_corners), cfg.sweep_corners}):
        plan = plan_sweep(cloud, wear.tree, view_dirt * island, here_m, cfg.pad_radius_m,
                          cfg.preston_coefficient * cfg.force_n / (np.pi * cfg.pad_radius_m**2), step_m,
                          goal=SWEEP_GOAL, max_corners=n_corners, support_z_m=support_z_m,
                          max_length_m=cfg.vision_max_steps * step_m, seed=cfg.seed)
        if plan is not None:
            break
    if plan is None:
        return None, None, (f"the explorer (strokes, but no sweep of {cfg.sweep_corners} legs takes "
                            f"{100 * SWEEP_GOAL:.0f} % of them off)")
    # the whole view's dirt is its island: not clean when the sweep ends, so the explorer goes on from there
    sweep = IslandStroke(WaypointPath(cloud, plan.waypoints, step_m, tree=wear.tree), np.flatnonzero(wear.dirty()),
                         plan.waypoints[0], plan.waypoints[-1], passes=MAX_PASSES)
    return sweep, plan, f"a planned sweep over strokes ({len(plan.corners) - 1} legs, {plan.length_m:.2f} m)"


def _after_stroke(stroke: IslandStroke, cmd: ExplorationCommand, wear: WearModel, cfg: CleanConfig,
                  cloud: SurfaceCloud, target0: float, islands_tried: list[np.ndarray], legs: _Legs,
                  step_m: float, transfer_max_m: float, done_level: float,
                  touch_down_ok: np.ndarray | None = None) -> tuple[IslandStroke | None, np.ndarray | None, bool]:
    """What follows a finished stroke: ``(stroke, relocate_to, covered)`` — a new stroke sliding in contact
    to the next small island when that is closer than ``transfer_max_m`` [m] (the path the pad slides in the
    time a lift-off, move and touch-down take), else a lift-off to the next island (``relocate_to``), the
    camera when the model calls the job done (``covered``), or the explorer (all None/False) when dirt is
    left here (a stroke that ran out of passes). ``done_level``: the model's remaining fraction of ``target0``
    at which the camera judges; ``touch_down_ok``: cloud points (N,) (bool) the next island's touch-down may be at
    (clear of keep-out zones), or None: all."""
    legs.path_m += stroke.path.path_length
    if stroke.transfer_only:
        return None, None, False
    if wear.remaining_fraction(target0) <= done_level:
        return None, None, True
    if not stroke.clean(wear):
        return None, None, False
    island = wear.next_island(cmd.point, islands_tried, 2.0 * cfg.pad_radius_m, touch_down_ok)
    if island is None or wear.dirt_near(island, 2.0 * cfg.pad_radius_m) < cfg.stop_remaining * target0:
        return None, None, not wear.island_left(cmd.point, 2.0 * cfg.pad_radius_m)
    islands_tried.append(island)
    if float(np.linalg.norm(island - cmd.point)) < transfer_max_m:
        nxt = plan_stroke(cloud, wear.tree, wear, island, cmd.point, cfg.pad_radius_m, step_m,
                          transfer_from_m=cmd.point)
        if nxt is not None:
            nxt.path.reset()
            return nxt, None, False
    return None, island, False
