"""The cleaning program of TEC §V-A3 on one robot backend, a method per phase: capture, plan, approach,
explore, remeasure, finish (see :mod:`tactex.tasks.clean`)."""

from __future__ import annotations

import time
import warnings
from dataclasses import replace

import numpy as np
from scipy.spatial import cKDTree

from tactex.control.ga_line_force import GaLineForceController, GaLineForceParams
from tactex.control.load_error import LoadError, LoadErrorEstimator
from tactex.control.nullspace import NullspacePosture
from tactex.control.references import LineForceReference
from tactex.ergodic import kernel
from tactex.ergodic.explorer import HedacExplorer
from tactex.ergodic.relocation import RelocationCommand
from tactex.errors import ConfigError, ExplorationError, SimulationError, SurfaceNotFound, TactexError
from tactex.geometry.so3 import rotate_towards
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.pointcloud.keep_out import raw_keep_out
from tactex.pointcloud.shapes import CylinderWallSurface
from tactex.robots.loop import ControlLoop
from tactex.sim.dirt import PrestonParams
from tactex.sim.scene import SceneConfig
from tactex.spectral.basis import build_basis
from tactex.spectral.modes import auto_n_eigen
from tactex.tasks.clean import legs, motion
from tactex.tasks.clean.bound import CleanBound
from tactex.tasks.clean.config import RASTER_BASELINES, CleanConfig
from tactex.tasks.clean.legs import MAX_HOLD_STEPS, _after_stroke, _Legs, _WearTicks
from tactex.tasks.clean.line_reference import LineLead, ToolNormal, blend_normals
from tactex.tasks.clean.metrics import clean_metrics
from tactex.tasks.clean.motion import (
    APPROACH_ACCEL_M_S2,
    HOVER_SETTLE_S,
    RETRACT_M,
    SUPPORT_Z_M,
    _acquisition,
    _approach_speed,
    _capture_pose,
    _cloud_capture_pose,
    _lag_m,
    _lift_off,
    _pad_over_support,
    _touchable,
)
from tactex.tasks.clean.records import CleanResult, Started, TickLog
from tactex.tasks.clean.robot_camera import RobotCapture
from tactex.tasks.clean.step_ahead import StepAhead
from tactex.tasks.clean.sweep_plan import SweepPlan
from tactex.tasks.clean.target import _dirt_from_cloud, load_target_cloud_keep_out
from tactex.tasks.path_source import PathSource, start
from tactex.tasks.progress import Progress
from tactex.tasks.raster import RasterPath
from tactex.tasks.region_raster_path import RegionRasterPath
from tactex.tasks.robot import (
    ROBOT_STOPS,
    RealRobotParams,
    end_on_robot,
    open_backend,
    open_capture_camera,
    stop_reason,
)
from tactex.tasks.step_hold import StepHold
from tactex.tasks.stroke import IslandStroke
from tactex.tasks.vision import capture_target_cloud, remeasure_target
from tactex.tasks.wear_model import WearModel

__all__ = ["CleanProgram", "run_clean"]

#: Time of a trip to the camera and back [s] (retract, lift, transit, capture) before the first one is measured.
VISION_TRIP_GUESS_S = 5.0
#: Time of a lift-off, move and touch-down at the next island [s] before the first one is measured.
ISLAND_MOVE_GUESS_S = 3.5
#: Settling after the lift before the IK of the way back to the camera, on a robot [s].
ROBOT_SETTLE_S = 0.2
#: Longest approach along the normal before the captured surface counts as missing [s].
APPROACH_TIMEOUT_S = 6.0
#: The region raster slides to its next line when it is closer than this, and lifts off to fly there when
#: it is farther [m]: a lift-off, move and touch-down take seconds (ISLAND_MOVE_GUESS_S before the first is
#: measured), in which the sponge slides this far at the clean's speeds.
REGION_RASTER_GAP_M = 0.2


def run_clean(config: CleanConfig | None = None, *, progress: bool = True,
              robot: RealRobotParams | None = None, live=None) -> CleanResult:
    """Run the cleaning program in simulation, or on a real Franka (``robot``, with ``config.cloud``),
    and return its metrics, series and fields.

    A libfranka error, a lost sensor or Ctrl-C ends the program early: torque control stops and the
    result holds what was recorded, ``aborted`` naming the cause in its metrics. ``live``: a
    :class:`~tactex.tasks.live_feed.LiveFeed` the run shows itself on (``--view``), or None."""
    cfg = config or CleanConfig()
    if robot is not None and not cfg.cloud and robot.camera not in ("twin", "realsense"):
        raise ConfigError("clean on a robot captures its target with --camera realsense (or --camera twin on tactex "
                          f"twin), or takes it from --cloud FILE (a coloured cloud in the robot base frame); got "
                          f"--camera {robot.camera}")
    scene_cfg = cfg.scene()
    opened: list = []  # the backend, once connected: the camera's frames are posed by its tool pose
    # the camera first: a recording that is not one, or a missing pyrealsense2, is named before the robot moves
    camera = (open_capture_camera(robot, scene_cfg, lambda: opened[0].state().ee_pose)
              if robot is not None and not cfg.cloud else None)
    try:
        backend = open_backend(scene_cfg, robot, announce=progress)
    except BaseException:
        if camera is not None:
            camera.close()
        raise
    opened.append(backend)
    started = Started()
    try:
        return CleanProgram(cfg, backend, scene_cfg, robot, progress, started, camera=camera, live=live).run()
    except TactexError as exc:  # a RobotError, a SensorFault, SurfaceNotFound, a failure of ours
        # on a robot, a stop outside the program's loop (the moves before its first touch-down, the final
        # lift-off) keeps what was recorded too; the loop's own stops are kept inside it
        result = started.stopped(cfg, exc) if robot is not None else None
        if result is None:
            raise
        return result
    finally:
        if camera is not None:
            camera.close()
        backend.close()


class _Contact:
    """One contact phase (3b): the commanded line between two exploration steps and what ends the phase."""

    def __init__(self, cmd, now_s: float, max_turn_rad: float, done_level: float) -> None:
        self.prev = cmd  # the command the line comes from
        self.n_prev = self.n_next = cmd.normal.copy()  # the commanded normal line, turned at a bounded rate
        self.max_turn = max_turn_rad
        self.next_step = now_s  # [s] when the next exploration step is due
        self.steps = 0  # exploration steps since the last camera view
        self.covered = False  # the phase ends after this tick: the dirt is gone by the model (or the coverage)
        self.relocation: RelocationCommand | None = None  # the explorer's flight that ends the phase
        self.relocate_to: np.ndarray | None = None  # the island [m] a lift-off goes to
        self.t_phase = now_s
        self.predicted_left: list[float] = []  # the wear model's remaining fraction at each update
        # done when the model says the camera would stop (see CleanProgram._contact)
        self.done_level = done_level
        self.hold = StepHold(MAX_HOLD_STEPS)
        self.ahead: StepAhead | None = None


class CleanProgram:
    """TEC §V-A3's state machine on ``backend``: :meth:`run` calls :meth:`capture` and :meth:`plan` once, then
    :meth:`approach`, :meth:`explore` and :meth:`remeasure` until the dirt is gone or the budget ends, and
    :meth:`finish`.

    ``path`` is what the agent follows between touch-downs (:class:`~tactex.tasks.path_source.PathSource`: the
    explorer, or the raster baseline's boustrophedon); ``explorer`` the same object when it is the HEDAC
    explorer (its fields and figures go into the result), else None. A stroke through a small island
    (:class:`~tactex.tasks.stroke.IslandStroke`) drives the agent instead of ``path`` while it lasts.
    """

    def __init__(self, cfg: CleanConfig, backend, scene_cfg: SceneConfig, robot: RealRobotParams | None,
                 progress: bool, started: Started | None = None, camera=None, live=None) -> None:
        self.cfg, self.backend, self.scene_cfg, self.robot = cfg, backend, scene_cfg, robot
        # the robot's wrist camera, None in simulation and with --cloud
        self.camera = None if camera is None else RobotCapture(camera, robot)
        self.wall0 = time.perf_counter()
        self.log = log = TickLog(backend, cfg)
        log.live = self.live = live
        self.loop = ControlLoop(backend, on_tick=log, max_joint_speed=cfg.joint_speed_rad_s)
        self.bar = Progress(cfg.budget_s, f"clean {cfg.baseline or 'tactex'}", enabled=progress)
        self.given, self.keep_out = (load_target_cloud_keep_out(cfg.cloud, cfg.voxel_size_m, cfg.keep_out_channel,
                                                                cfg.keep_out_threshold, cfg.keep_out_mask,
                                                                units=cfg.units)
                                     if cfg.cloud else (None, None))
        self.started = started
        if started is not None:
            started.log, started.loop, started.cloud, started.camera = log, self.loop, self.given, self.camera
        self.acq = replace(_acquisition(scene_cfg), voxel_size_m=cfg.voxel_size_m)
        self.cap_pos, self.cap_rot = (_capture_pose(scene_cfg, cfg) if self.given is None
                                      else _cloud_capture_pose(self.given, cfg))
        try:
            self.q_capture = backend.solve_ik(self.cap_pos, self.cap_rot)  # TEC's pre-recorded capture posture
        except SimulationError as exc:
            which = "side_capture_distance_m" if isinstance(scene_cfg.sim_object.surface, CylinderWallSurface) \
                else "capture_distance_m"
            raise ConfigError(f"the capture pose at {np.round(self.cap_pos, 3).tolist()} m is out of the arm's reach "
                              f"({exc}); lower {which} (now {getattr(cfg, which)} m)") from exc
        self.dirt = backend.dirt_remaining if log.truth else (lambda: float("nan"))
        if self.camera is not None and self.camera.knows_dirt:  # the twin's own count
            self.dirt = self.camera.dirt_remaining
        # [m] the table top the captured object stands on (the capture's crop cuts the table above it); a given
        # cloud's support is not known
        self.support_z = SUPPORT_Z_M if self.given is None else None
        self.t_end = cfg.budget_s
        self.load_error: LoadError | None = None  # what the load check measured (None: not made)
        self._load_checked = not cfg.load_check
        self.dt_step = 1.0 / cfg.explorer_rate_hz
        self.aborted = ""
        self.pressing: LineForceReference | None = None  # the contact's last reference, unloaded at a lift-off

    # -- the program ------------------------------------------------------------------------------------------
    def run(self) -> CleanResult:
        """The whole program; a stop of the robot (or Ctrl-C) ends it with what was recorded."""
        self.capture()
        self.plan()
        try:
            while self.loop.t < self.t_end:
                self._start_leg()
                touched = self.approach()
                if touched is None:
                    continue  # on to other dirt
                if not touched:
                    break
                if self.explore():
                    continue  # a flight or an island move: the next touch-down
                if not self.remeasure():
                    break
        except ROBOT_STOPS as exc:
            # torque control has ended (libfranka on its errors, the backend on ours): keep what was recorded
            self.aborted = stop_reason(exc)
            self.bar.note(f"stopped early: {self.aborted}")
        except TactexError as exc:
            if self.robot is None:  # in simulation an error of ours is raised; on a robot the run keeps its data
                raise
            self.aborted = end_on_robot(self.loop, exc)
            self.bar.note(f"stopped early: {self.aborted}")
        return self.finish()

    def _rise_to_capture(self) -> None:
        """From low over the object towards the capture pose: straight up, then along a line of IK waypoints (a
        single joint move from inside a bowl can swing the tool through its wall), ending near the capture posture."""
        motion.rise_to_capture(self.loop, self.cap_pos, self.cap_rot, self.q_capture,
                               ROBOT_SETTLE_S if self.robot is not None else 0.0)

    def _left(self) -> np.ndarray:
        """What the robot believes is left per cloud point (N,), in the target's units: the wear model's
        prediction, else the target no footprint has touched yet (the live page's colours)."""
        if self.wear is not None:
            return self.wear.remaining()
        if self.explorer is not None:
            return np.where(self.explorer.coverage > 0.0, 0.0, self.explorer.target)
        return self.cleanable_target

    def _view(self, lift: bool = False) -> SurfaceCloud:
        """To the capture pose (from contact: ``lift``) and the captured cloud (a given cloud as it is)."""
        loop = self.loop
        self.log.activity("move", "vision")
        if lift:
            self._rise_to_capture()
        check = self._load_check()
        loop.move_joints(self.q_capture, settle_s=0.3, load_check=check)
        self._compensate_load(check)
        self.log.activity("capture", "vision")
        if self.given is not None:
            return self.given
        if self.camera is None:
            return capture_target_cloud(self.backend.render_depth(), self.acq)
        return self.camera.capture(loop, self.acq)

    def _load_check(self) -> LoadErrorEstimator | None:
        """An estimator for the next still hold in free space, once per run (None: made, or turned off)."""
        return None if self._load_checked else LoadErrorEstimator()

    def _compensate_load(self, check: LoadErrorEstimator | None) -> None:
        """Act on the load check of the hold just made: a tool weight the robot misses is added to every
        command from now on, and said (an estimate from too few still ticks waits for the next hold)."""
        if check is None:
            return
        found = check.estimate()
        if found is None:
            return
        self._load_checked, self.load_error = True, found
        if found.accepted:
            self.loop.safety.compensate_load(found.wrench_world)
            self.bar.note(found.describe())
        elif found.force_n >= check.deadband_n:  # large enough to mention, not a weight
            self.bar.note(found.describe())

    # -- 1. capture -------------------------------------------------------------------------------------------
    def capture(self) -> None:
        """Capture and segment the dirt. A given cloud needs no capture: the basis and the explorer are made
        before the arm moves, since on a real robot nothing slow may run while torque control is on."""
        cfg = self.cfg
        self.cloud = cloud = self._view() if self.given is None else self.given
        if self.started is not None:  # a stop from here on keeps the capture
            self.started.cloud = cloud
        if self.given is None and cfg.keep_out_channel:
            self.keep_out = raw_keep_out(cloud, cfg.keep_out_channel, cfg.keep_out_threshold, "")
        # dirt under a keep-out zone is never cleaned: it counts neither in the start nor in what is left
        self.cleanable = np.ones(len(cloud), dtype=bool) if self.keep_out is None else ~self.keep_out
        self.n_target0 = int(np.count_nonzero(cloud.target[self.cleanable] > 0))
        if self.n_target0 == 0 and self.keep_out is not None and cloud.n_target > 0:
            raise ExplorationError("every dirty point the capture sees lies in the keep-out zone: nothing may be "
                                   "cleaned; check --keep-out-channel/--keep-out-threshold/--keep-out-mask")
        if self.n_target0 == 0:
            raise ExplorationError("the first capture sees no dirt: nothing to clean (check the marking and the view)")

    # -- 2. plan ----------------------------------------------------------------------------------------------
    def plan(self) -> None:
        """While the robot holds still (wall-clock work): the eigenbasis and the path source, the first
        touch-down, the wear model and the first leg in contact."""
        cfg, cloud = self.cfg, self.cloud
        self._build_path()
        x0 = self._first_touch_down()
        if self.given is not None:
            self.path.reset(x0)  # a first step here, not in the loop: numba loads the compiled step on first use
            self.path.step()
            self._view()  # to the capture posture, as the camera path did
        # the set-up below (the wear model, the planned sweep: up to about a second) runs between two ticks
        self.loop.pause()
        if self.live is not None:  # the live page's cloud (a file written while the robot holds itself)
            self.live.set_cloud(self.cloud.points, self.cloud.colors, self.cleanable_target, self.keep_out)
        self.cmd = start(self.path, x0)
        # the robot's own estimate of what it has wiped off since the last view (tactex only: the baselines
        # keep TEC's coverage target)
        self.wear = wear = (WearModel(cloud, cfg.preston_coefficient, cfg.pad_radius_m,
                                      PrestonParams().force_threshold_n, cfg.wear_margin)
                            if cfg.baseline == "" and cfg.objective == "clean" else None)
        if wear is not None:
            wear.reset(self.cleanable_target)  # dirt the robot may not touch is never predicted left: no goal
        self.target0 = float(self.cleanable_target.sum())
        self.lead = LineLead(cfg.line_lead_s, self.dt_step)
        self.surface_tree = wear.tree if wear is not None else cKDTree(cloud.points)  # the moves' clearance check
        self.tool_normal = ToolNormal(cloud, tree=self.surface_tree) if cfg.line_normal_feedback > 0 else None
        self.vision_steps = cfg.vision_every_steps if wear is None else cfg.vision_max_steps
        self.islands_tried: list[np.ndarray] = []  # [m] touch-down points of the relocations since the last view
        # those relocations; far moves from low over the object that went via the capture posture, or out first
        self.island_moves = self.moves_via_capture = self.moves_backed_off = 0
        # control ticks between wear-model updates (the pad moves well under a millimetre)
        self.wear_ticks = _WearTicks(wear, self.backend.dt, every=10) if wear is not None else None
        # the posture of the capture pose keeps the redundant elbow where it was planned
        self.ga = NullspacePosture(GaLineForceController(GaLineForceParams()), q_posture=self.q_capture)
        self.vision_updates = 0
        self.vision_times: list[float] = []  # [s] when each re-measurement was taken
        self.vision_trip_s = VISION_TRIP_GUESS_S  # the next trip's estimate, measured after the first trip
        self.legs = _Legs(self.path, self.explorer)
        # islands smaller than the pad get a straight stroke instead of the explorer (wear model only; a stroke
        # knows no keep-out zone)
        self.strokes = wear is not None and self.keep_out is None
        self.stroke: IslandStroke | None = None
        self.stroke_step_m = cfg.max_velocity * cloud.spacing  # the agent's speed limit
        self.hold_force_n = cfg.hold_force_ratio * cfg.force_n if cfg.hold_force_ratio > 0 else np.inf
        # [s] a lift-off, move and touch-down: first the move from the capture pose to the first touch-down (no
        # island is chosen before it), then each island move
        self.island_move_s = ISLAND_MOVE_GUESS_S
        self.t_move: float | None = self.loop.t  # when the move in progress started
        self.counted: IslandStroke | None = None  # the last stroke counted in n_strokes / n_transfers
        self.n_strokes = self.n_transfers = 0  # strokes through small islands; slides in contact to the next island
        self.new_leg = True  # the next touch-down starts a leg (the first, after an island move or a camera view)
        self.leg_from = self.cap_pos  # where the robot comes from to that leg
        self.remaining_seen = float("nan")  # the share of the dirt the last re-measure saw left: none yet
        self.agent_path: list[np.ndarray] = []
        self.ergodicity: list[tuple[float, float]] = []
        self.explore_time = 0.0
        self._plan_first_leg()
        self.log.live_left = self._left

    def _build_path(self) -> None:
        """The eigenbasis (not for the raster) and the path source: the raster or the HEDAC explorer."""
        cfg, cloud = self.cfg, self.cloud
        t_basis = time.perf_counter()
        self.basis = basis = None
        if cfg.baseline not in RASTER_BASELINES:
            n_eigen = cfg.n_eigen
            if n_eigen is None:  # each point of the voxelised capture stands for about h² of surface
                n_eigen = auto_n_eigen(len(cloud) * cloud.spacing**2, cfg.agent_radius_m, len(cloud))
            if n_eigen >= len(cloud):
                raise ConfigError(
                    f"n_eigen = {n_eigen} eigenpairs, but the captured cloud has only {len(cloud)} points: ask for "
                    f"fewer (TEC uses 100–200; e.g. {min(200, len(cloud) - 1)})"
                )
            self.basis = basis = build_basis(cloud, n_eigen=n_eigen, cache=False, eigensolver=cfg.eigensolver,
                                             eigen_tol=cfg.eigen_tol)
        self.basis_s = time.perf_counter() - t_basis
        self.explorer: HedacExplorer | None = None
        if cfg.baseline in RASTER_BASELINES:  # lanes as far apart as the explorer's footprints overlap on its passes
            step_m = cfg.max_velocity * cloud.spacing
            if cfg.baseline == "raster":
                self.path: PathSource = RasterPath(cloud, lane_spacing_m=cfg.lane_spacing_m, max_step_m=step_m)
            else:
                self.path = RegionRasterPath(cloud, cfg.pad_radius_m, cfg.lane_spacing_m, REGION_RASTER_GAP_M,
                                             step_m, start_m=self.cap_pos)
            return
        hcfg = replace(
            cfg.explorer, n_eigen=basis.evecs.shape[1], step_duration_s=self.dt_step,
            # with the wear model the task moves between islands itself, from what the model says is left (the
            # explorer's stall rule would fire at a small spot the cooled potential holds the agent on); the
            # explorer's relocation stays for keep-out zones, whose flights it plans around them
            relocate=self.keep_out is not None or not (cfg.baseline == "" and cfg.objective == "clean"),
        )
        if hcfg.compiled and kernel.compile_pending():
            self.bar.note("preparing the compiled exploration step (numba compiles it on a machine's first run, "
                          "~10–15 s; later runs load it)")
        self.path = self.explorer = HedacExplorer(cloud, basis, hcfg, keep_out=self.keep_out)

    def _first_touch_down(self) -> np.ndarray:
        """Where the cleaning may touch down (clear of keep-out zones) and where it first does [m]."""
        cfg, cloud, explorer = self.cfg, self.cloud, self.explorer
        # where the sponge may touch down, as the explorer's own relocations: a footprint radius (and half a voxel)
        # clear of every keep-out point (None: anywhere; a keep-out zone comes with the explorer, not the raster)
        self.touch_down_ok = explorer.clear_points if self.keep_out is not None and explorer is not None else None
        if self.touch_down_ok is not None:  # dirt that close to the zone is no goal of the explorer's: not cleanable
            self.cleanable &= self.touch_down_ok
            self.n_target0 = int(np.count_nonzero(cloud.target[self.cleanable] > 0))
        # dirty points the explorer leaves out of its target as too near a keep-out zone (counted before the wear
        # model's targets, which hold none of them)
        self.near_keep_out = int(explorer.target_near_keep_out) if explorer is not None else 0
        if self.near_keep_out:
            self.bar.note(f"{self.near_keep_out} dirty points lie within {explorer.keep_out_clearance_m * 1e3:.1f} "
                          "mm of the keep-out zone (agent radius + ½ voxel), where the sponge may not be centred: no "
                          "goal (a pass beside them may still brush them)")
        self.cleanable_target = np.where(self.cleanable, cloud.target, 0.0)
        if self.given is not None and self.log.truth:
            _dirt_from_cloud(self.backend, cloud.with_target(self.cleanable_target), self.scene_cfg.object_name)
        # where the sponge first touches down, on dirt it may touch
        targets = _touchable(np.flatnonzero((explorer.target if explorer is not None else cloud.target) > 0),
                             self.touch_down_ok)
        # the raster from its waypoint nearest the dirt nearest the camera; tactex where the arm gets soonest
        x0 = cloud.points[targets[np.argmin(np.linalg.norm(cloud.points[targets] - self.cap_pos, axis=1))]]
        t_plan = time.perf_counter()
        # wall-clock work while the robot holds, like the basis; a baseline plans it for the bound only
        quickest = motion._quickest_touch_down(self.loop, cloud, targets, self.q_capture, self.cap_pos,
                                               cfg.hover_height_m)
        if explorer is not None:
            x0 = x0 if quickest is None else quickest[0]
            self.start_plan_s = time.perf_counter() - t_plan
        else:
            self.start_plan_s = 0.0
        self.bound = CleanBound.of(cfg, cloud.with_target(self.cleanable_target), self.loop.t,
                                   0.0 if quickest is None else quickest[1])
        return x0

    def _plan_first_leg(self) -> None:
        """The first stretch in contact (a small island's stroke, the planned sweep or neither: the explorer),
        planned while the robot still holds at the capture pose (wall clock, counted with the choice of the
        touch-down)."""
        self.first_leg: IslandStroke | None = None
        self.first_plan: SweepPlan | None = None
        self.first_leg_choice = ""  # what it is and why (none planned: a raster, keep-out zones)
        if self.strokes:
            t_plan = time.perf_counter()
            self.first_leg, self.first_plan, self.first_leg_choice = legs._first_leg(
                self.cloud, self.wear, self.cmd.point, self.leg_from, self.cfg, self.stroke_step_m, self.support_z)
            self.start_plan_s += time.perf_counter() - t_plan
        self.first_sweep = self.first_leg if self.first_plan is not None else None
        self.first_leg_due = self.strokes  # the next leg is the first: its stroke is planned already

    # -- 3a. approach -----------------------------------------------------------------------------------------
    def _start_leg(self) -> None:
        """At a new leg's touch-down, a stroke instead of the path when the island there is small."""
        if self.new_leg and self.strokes:
            if self.first_leg_due:
                self.stroke, self.first_leg_due = self.first_leg, False
                if self.first_sweep is not None:
                    self.counted = self.first_sweep  # not an island stroke
            else:
                self.stroke = legs.plan_stroke(self.cloud, self.wear.tree, self.wear, self.cmd.point, self.leg_from,
                                               self.cfg.pad_radius_m, self.stroke_step_m)
            if self.stroke is not None:
                self.cmd = self.stroke.path.reset()
        self.new_leg = False

    def approach(self) -> bool | None:
        """Hover over the agent and approach along its normal line until the tool touches: True in contact,
        False when the program ends (the budget, nothing left in reach), None when the hover is out of reach and
        the program moves on to other dirt."""
        cfg, loop = self.cfg, self.loop
        self.log.activity("move", "transit")
        plan = self._hover_or_elsewhere()
        cmd = self.cmd  # the touch-down, raised where the pad's disc would meet the support (as in contact)
        if not plan:
            return plan
        q_above, q_hover, move_s = plan
        detour_s = motion._detour_via_capture(loop, q_hover if q_above is None else q_above, self.q_capture,
                                              self.surface_tree, cfg.pad_radius_m)
        if loop.t + move_s + (detour_s or 0.0) + HOVER_SETTLE_S >= self.t_end:
            return False  # the move alone would use up the budget
        if detour_s is not None:  # a far move from low over the object: up, then out, then via the capture posture
            way = motion.clear_of_the_object(
                loop, q_hover if q_above is None else q_above, self.cap_pos, self.cap_rot, self.q_capture,
                self.surface_tree, cfg.pad_radius_m, ROBOT_SETTLE_S if self.robot is not None else 0.0)
            self.moves_via_capture += way == "capture"
            self.moves_backed_off += way == "out"
        if q_above is not None:
            loop.move_joints(q_above, settle_s=0.0)
        check = self._load_check()
        loop.move_joints(q_hover, settle_s=HOVER_SETTLE_S, load_check=check)
        self._compensate_load(check)
        self.log.activity("approach", "touch_down")
        loop.use(self.ga)
        t_touch = None
        t_approach_start = loop.t
        t_approach_end = loop.t + APPROACH_TIMEOUT_S
        while loop.t < min(t_approach_end, self.t_end):
            v_approach = min(_approach_speed(loop.state.ee_position, cmd, cfg),
                             APPROACH_ACCEL_M_S2 * (loop.t - t_approach_start))
            s = loop.tick(LineForceReference(cmd.point, cmd.normal, cfg.approach_force_n, v_approach))
            if s.wrench_tool[2] >= cfg.contact_threshold_n:
                t_touch = loop.t
                break
        if t_touch is None and loop.t >= self.t_end:
            return False  # the time budget ended during the approach
        if self.t_move is not None and t_touch is not None:
            self.island_move_s, self.t_move = t_touch - self.t_move, None
        if t_touch is None:
            loop.pause()  # a real robot holds itself while the run's data is written
            raise SurfaceNotFound(
                f"no contact within {APPROACH_TIMEOUT_S:g} s of approach at {np.round(cmd.point, 3).tolist()}; the "
                "captured surface and the real one disagree (object moved?)"
            )
        self.t_touch = t_touch
        return True

    def _hover_or_elsewhere(self):
        """The joint moves to the hover over the current command (``motion._hover_plan``), or, out of the arm's
        reach (the far side of the cup), False with no other dirt the wear model knows of (TEC's loop has no
        other to offer: it raises) or None after a restart at the nearest other dirt."""
        cfg, cmd = self.cfg, self.cmd
        if self.support_z is not None:  # low on a wall the pad's rim would touch down on the table first
            cmd = self.cmd = cmd._replace(point=_pad_over_support(cmd.point, cmd.normal, self.support_z,
                                                                  cfg.pad_radius_m, motion.TOUCH_DOWN_CLEARANCE_M))
        try:
            return motion._hover_plan(self.loop, cmd.point, cmd.normal, self.q_capture, cfg.hover_height_m)
        except SimulationError:
            island = None
            if self.wear is not None:
                self.islands_tried.append(cmd.point.copy())
                island = self.wear.next_island(cmd.point, self.islands_tried, 2.0 * cfg.pad_radius_m,
                                               self.touch_down_ok)
            if self.wear is None:
                if cfg.baseline not in RASTER_BASELINES:
                    raise
                return self._skip_along_raster()
            if island is None:
                warnings.warn(f"clean: no hover pose over {np.round(cmd.point, 3).tolist()} m within reach and "
                              "no other dirt left to the wear model; ending the program", RuntimeWarning,
                              stacklevel=2)
                return False
            warnings.warn(f"clean: no hover pose over {np.round(cmd.point, 3).tolist()} m within reach; "
                          f"moving on to the dirt at {np.round(island, 3).tolist()} m", RuntimeWarning,
                          stacklevel=2)
            # a stroke planned there goes with it: the new island starts a leg of its own
            self.stroke, self.new_leg = None, True
            self.cmd = self.legs.restart(island)
            return None

    def _skip_along_raster(self) -> bool | None:
        """A raster's touch-down out of reach (a bowl's rim): on along its path (None), or False at its end."""
        cmd = legs.skip_along(self.path, self.cmd.point, self.cfg.baseline.replace("_", " "))
        if cmd is None:
            return False
        self.cmd, self.new_leg = cmd, True
        return None

    # -- 3b. explore ------------------------------------------------------------------------------------------
    def explore(self) -> bool:
        """Contact exploration: each tick the line-and-force controller tracks the agent's normal line. True
        when the program goes on with another touch-down (an explorer's flight, a lift-off to the next island),
        False when the phase ended for the camera (or the end)."""
        cfg, loop = self.cfg, self.loop
        self.log.activity("explore", "explore")
        c = self._contact()
        while loop.t < self.t_end:
            due = loop.t >= c.next_step - 1e-9
            if due and c.hold.hold(
                    (cfg.max_lag_m > 0 and _lag_m(loop.state.ee_position, self.cmd) > cfg.max_lag_m)
                    or float(np.linalg.norm(loop.state.wrench_tool[:3])) > self.hold_force_n):
                # the tool is behind, or dragged against a wall (a bowl's, climbing towards the rim): hold the
                # line at the agent's point while it catches up (for a few steps at most: a point it cannot
                # reach must not hold the program)
                c.prev, c.n_prev, c.next_step = self.cmd, c.n_next, c.next_step + self.dt_step
            elif due and not self._step(c):
                break
            if not self._tick(c):
                break
        if self.wear_ticks is not None:
            self.wear_ticks.settle()  # the phase's last tick
        self.explore_time += loop.t - c.t_phase
        if c.relocation is not None:
            # TEC §VI-B: lift off along the normal, then the hover and approach at the touch-down
            self.log.activity("retract", "transit")
            _lift_off(loop, max(c.relocation.clearance_m, cfg.hover_height_m), pressing=self.pressing)
            self.bar.note(f"relocating ({c.relocation.reason}): {c.relocation.air_length_m:.3f} m through the air")
            return True
        if c.relocate_to is not None:
            # to the next island through the air: lift off here, then the hover and approach
            self.log.activity("retract", "transit")
            _lift_off(loop, RETRACT_M, pressing=self.pressing)
            self.island_moves += 1
            self.leg_from, self.new_leg, self.t_move = self.cmd.point, True, loop.t
            self._end_stroke()
            self.cmd = self.legs.restart(c.relocate_to)
            return True
        return False

    def _contact(self) -> _Contact:
        """A new contact phase's state, with the step taken ahead of the tick that needs it."""
        cfg, wear = self.cfg, self.wear
        c = _Contact(self.cmd, self.loop.t, np.radians(cfg.max_normal_rate_deg_s) * self.dt_step, 0.0)
        if self.wear_ticks is not None:
            self.wear_ticks.restart()
        # done when the model says the camera would stop, and after a return for a remnant, once most of that
        # remnant is off: each trip back costs a touch-down and a trip to the camera
        c.done_level = (cfg.stop_remaining if wear is None
                        else min(cfg.stop_remaining, 0.2 * wear.remaining_fraction(self.target0)))
        self.lead.reset()
        c.ahead = StepAhead(self.path, self.backend.dt, wear=wear,
                            settle=self.wear_ticks.settle if self.wear_ticks else None,
                            agent_feedback=cfg.agent_feedback, read_residual=self.given is not None,
                            model_update_steps=cfg.model_update_steps, island_radius_m=2.0 * cfg.pad_radius_m,
                            explorer=self.explorer)
        return c

    def _step(self, c: _Contact) -> bool:
        """An exploration step due at this tick: the next command from the stroke or the path, and the decisions
        on what the wear model says. False: the phase ends before this tick (a flight, an island move, done)."""
        cfg, wear = self.cfg, self.wear
        c.prev = self.cmd
        measured = self.loop.state.ee_position if cfg.agent_feedback else None
        if self.stroke is not None:  # it ends where the wear model calls its island wiped, mid-pass if need be
            self.wear_ticks.settle()
        if self.stroke is not None and (self.stroke.path.done or self.stroke.wiped(wear)):
            if self.stroke.clean(wear) or not self.stroke.next_pass(self.stroke_step_m):
                self.stroke, c.relocate_to, c.covered = _after_stroke(
                    self.stroke, self.cmd, wear, cfg, self.cloud, self.target0, self.islands_tried, self.legs,
                    self.stroke_step_m, self.island_move_s * cfg.explorer_rate_hz * self.stroke_step_m, c.done_level,
                    self.touch_down_ok)
                if c.relocate_to is not None or c.covered:
                    return False
                if self.stroke is None:  # the explorer takes over here
                    self.legs.restart(self.cmd.point)
                    c.predicted_left.clear()
                    # from what the model says is left, not from its target of before the stroke (its own next
                    # model update is model_update_steps away); applied after this tick's send, so the first
                    # step, taken in this tick, still sees the old target
                    c.ahead.update_target_later(wear.remaining())
        stroke = self.stroke
        taken = c.ahead.take() if stroke is None else None
        if taken is not None:
            cmd, reads = taken
        elif stroke is not None:
            cmd = stroke.path.step()
            reads = c.ahead.read(cmd, c.steps + 1, model=False)
        else:
            cmd = self.path.step(measured)
            reads = c.ahead.read(cmd, c.steps + 1)
        self.cmd = cmd
        if stroke is not None and stroke is not self.counted:
            self.counted = stroke
            self.n_strokes += not stroke.transfer_only
            self.n_transfers += stroke.transfer
        if isinstance(cmd, RelocationCommand):
            c.relocation = cmd  # lift off here, fly, touch down at cmd.point (the next approach)
            return False
        n_goal = cmd.normal
        if self.tool_normal is not None:  # the line leans towards the surface the tool presses on
            n_goal = blend_normals(cmd.normal, self.tool_normal.at(self.loop.state.ee_position),
                                   cfg.line_normal_feedback)
        c.n_prev, c.n_next = c.n_next, rotate_towards(c.n_next, n_goal, c.max_turn)
        c.next_step += self.dt_step
        c.steps += 1
        self.agent_path.append(cmd.point)
        self.log.agent = cmd.point
        if "ergodicity" in reads:  # every ERGODICITY_EVERY_STEPS steps of the explorer
            self.ergodicity.append((self.loop.t, reads["ergodicity"]))
            c.covered = reads["residual"] is not None and reads["residual"] <= cfg.stop_remaining
        if "predicted" in reads:  # a wear-model update while the explorer drives the agent
            return self._model_update(c, reads["predicted"], reads["island_left"])
        return True

    def _model_update(self, c: _Contact, predicted: np.ndarray, island_left: bool) -> bool:
        """What the wear model's prediction decides: on (a new target for the explorer), a slide or a lift-off to
        the next island (False: the phase ends), or the camera (``covered``)."""
        cfg, wear, cmd = self.cfg, self.wear, self.cmd
        left = float(predicted.sum()) / self.target0
        c.predicted_left.append(left)
        back = cfg.model_stall_steps // cfg.model_update_steps
        # stalled: less than a tenth of what is left wiped off over the last model_stall_steps
        stalled = len(c.predicted_left) > back and c.predicted_left[-1 - back] - left < 0.1 * left
        # or the island under the agent is done while a far one holds a fair share (the cooled potential barely
        # reaches it): nothing the model calls dirty within two pad radii
        stalled = stalled or (left > 4 * cfg.stop_remaining and not island_left)
        if left > c.done_level and stalled:
            # dirt left, but not where the agent is: lift off and touch down at the nearest island the model calls
            # dirty, unless there is none it has not tried since the last view or it holds less than the camera's
            # stop level (then the camera judges: each touch-down costs force settling and time)
            island = wear.next_island(cmd.point, self.islands_tried, 2.0 * cfg.pad_radius_m, self.touch_down_ok)
            if island is None or wear.dirt_near(island, 2.0 * cfg.pad_radius_m) < cfg.stop_remaining * self.target0:
                c.covered = True
            else:
                self.islands_tried.append(island)
                transfer_max_m = self.island_move_s * cfg.explorer_rate_hz * self.stroke_step_m
                if self.strokes and float(np.linalg.norm(island - cmd.point)) < transfer_max_m:
                    self.stroke = legs.plan_stroke(self.cloud, wear.tree, wear, island, cmd.point, cfg.pad_radius_m,
                                                   self.stroke_step_m, transfer_from_m=cmd.point)
                if self.stroke is not None:
                    self.stroke.path.reset()  # slide there in contact from the next step on
                else:
                    c.relocate_to = island
                    return False
        elif left <= c.done_level:
            c.covered = True  # the model says the job is done: time for the camera to judge
        else:
            c.ahead.update_target_later(predicted)
        return True

    def _tick(self, c: _Contact) -> bool:
        """One control tick along the line between the last two steps; False: the phase ends after it."""
        cfg, loop, cmd = self.cfg, self.loop, self.cmd
        frac = min(max(1.0 - (c.next_step - loop.t) / self.dt_step, 0.0), 1.0)
        # velocity feed-forward: the line's point where the agent will be line_lead_s later
        point = (c.prev.point + frac * (cmd.point - c.prev.point)
                 + self.lead.offset(c.prev.point, cmd.point, self.backend.dt))
        normal = c.n_prev + frac * (c.n_next - c.n_prev)
        if self.support_z is not None:
            point = _pad_over_support(point, normal, self.support_z, cfg.pad_radius_m)
        ramp = min((loop.t - self.t_touch) / cfg.force_ramp_s, 1.0)
        force = cfg.approach_force_n + ramp * (cfg.force_n - cfg.approach_force_n)
        self.log.set_point = force  # the band is judged against the set point, never the boost below
        if cfg.touch_down_boost > 0:  # a smooth pulse from zero, peaking touch_down_boost_s after touch-down
            x = (loop.t - self.t_touch) / cfg.touch_down_boost_s
            force += cfg.touch_down_boost * cfg.force_n * x * float(np.exp(1.0 - x))
        # the phase ends after this tick: the wear model (or, for a given cloud, the coverage) says the dirt is
        # gone, or the camera is due
        ending = c.covered or (cfg.baseline == "" and self.given is None and c.steps >= self.vision_steps)
        # the explorer steps ahead only for a step it will take in this phase
        c.ahead.arm(c.next_step, c.steps + 1, enabled=self.stroke is None and not ending)
        self.pressing = LineForceReference(point, normal, force)
        state_next = loop.tick(self.pressing, after_send=c.ahead)
        if self.wear_ticks is not None:
            self.wear_ticks.note(state_next, normal)
        if int(loop.t * 1000) % 250 == 0:
            self.bar.update(loop.t, dirt=self.dirt(), vision=self.vision_updates)
        return not (ending or (cfg.baseline in RASTER_BASELINES and self.path.done and not c.ahead.pending))

    def _end_stroke(self) -> None:
        """A stroke cut short by a new leg: its path so far counts in the agent's."""
        if self.stroke is not None:
            self.legs.path_m += self.stroke.path.path_length
            self.stroke = None

    # -- 4. remeasure -----------------------------------------------------------------------------------------
    def remeasure(self) -> bool:
        """Back to the camera: re-measure the dirt on the same points and update the target (no new basis), then
        on from the dirt nearest to the robot. False when the program ends instead: no camera (a baseline, a
        given cloud), no time for the trip, the raster done, or the camera sees the dirt gone."""
        cfg, loop, cloud = self.cfg, self.loop, self.cloud
        if cfg.baseline == "raster" and self.path.done:
            return False
        if cfg.baseline not in ("", "region_raster") or self.given is not None \
                or loop.t + self.vision_trip_s >= self.t_end:
            return False  # (a re-measurement that would end after the budget could not be used)
        t_trip = loop.t
        self.log.activity("retract", "vision")
        _lift_off(loop, RETRACT_M, pressing=self.pressing)
        new_capture = self._view(lift=True)
        self.vision_trip_s = loop.t - t_trip  # the next trip's estimate
        self.vision_updates += 1
        self.vision_times.append(loop.t)
        mass = remeasure_target(cloud, new_capture)
        mass = np.where(self.cleanable, mass, 0.0)
        self.remaining_seen = float(np.count_nonzero(mass)) / self.n_target0
        self.bar.update(loop.t, dirt=self.dirt(), vision=self.vision_updates)
        if self.remaining_seen < cfg.stop_remaining or not np.any(mass > 0):
            return False
        self.path.update_target(mass)
        if self.wear is not None:
            self.wear.reset(mass)  # the camera's view replaces the prediction
            self.islands_tried.clear()
        # restart from the dirt nearest to where the robot is
        left = _touchable(np.flatnonzero(mass > 0), self.touch_down_ok)
        x0 = cloud.points[left[np.argmin(np.linalg.norm(cloud.points[left] - self.cmd.point, axis=1))]]
        self.leg_from, self.new_leg = self.cmd.point, True
        self._end_stroke()
        self.cmd = self.legs.restart(x0)
        return True

    # -- the end ----------------------------------------------------------------------------------------------
    def finish(self) -> CleanResult:
        """Lift off so that the final state is out of contact (0.4 s, on top of the budget) and hand back the
        result."""
        cfg, loop, log = self.cfg, self.loop, self.log
        if self.stroke is not None:  # the program ended during a stroke: its path so far is part of the agent's
            self.legs.path_m += self.stroke.path.path_length
        log.activity("retract", "lift_off")
        if not self.aborted and loop.state.wrench_tool[2] > cfg.contact_threshold_n:
            _lift_off(loop, RETRACT_M, pressing=self.pressing)
        if self.camera is not None:
            self.camera.refresh(final=True)
        left = self.dirt()  # the simulation's count, the twin's, or NaN on a robot (nobody counts its dirt)
        self.bar.close(f"dirt removed {100 * (1 - left):.1f} %" if np.isfinite(left) else "done (dirt not measured)")
        series = log.rec.arrays()
        fields = {"target_initial": self.cloud.target.copy()}
        if self.explorer is not None:
            ex = self.explorer
            fields.update(target=ex.target.copy(), coverage=ex.coverage.copy(), potential=ex.potential.copy())
        return CleanResult(
            config=cfg, metrics=clean_metrics(self, series), series=series, cloud=self.cloud, fields=fields,
            agent_path=np.asarray(self.agent_path).reshape(-1, 3), tcp_path=series.get("tcp", np.zeros((0, 3))),
            events=list(loop.safety.events),
        )
