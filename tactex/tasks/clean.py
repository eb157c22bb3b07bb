"""Tactile ergodic cleaning (TEC §V-A, Fig. 3, Fig. 12) in simulation.

The state machine of TEC §V-A3:

1. **capture** — joint move to a capture pose, take an RGB-D frame, pre-process it (crop, voxel
   grid, outlier removal) and segment the dirt by colour: the target distribution;
2. **hover** — move above the surface while the Laplacian eigenbasis is computed; the first hover is over
   the dirt the arm reaches soonest from the capture pose (the raster's: its waypoint nearest the dirt
   nearest the camera);
3. **contact exploration** — each tick the GA line-and-force controller tracks the normal line of
   the HEDAC agent and presses with the set force; the agent steps at ``explorer_rate_hz``;
4. the robot returns to the capture pose, re-measures the remaining dirt and updates the target on
   the same points (no new basis), then goes back to contact. The run stops when vision sees less
   than ``stop_remaining`` of the initial dirt, or when the time budget ends.

When to return to the camera, and what the agent follows until then, is ``objective``:
``ergodic`` is TEC's loop (the captured dirt as the coverage target of eq. 2, a trip every
``vision_every_steps``, ~200 in TEC §VI-B); ``clean`` (the default, issue 21) makes the target the
captured dirt minus what the robot's own Preston wear model says it has removed
(:class:`~tactex.tasks.wear_model.WearModel`), so clean points stop attracting, and returns when
that model says the dirt is gone or stops falling. An island of dirt smaller than the pad gets a
straight stroke instead of the agent, and the robot slides in contact to the next island when that is
quicker than a lift-off (:mod:`tactex.tasks.stroke`). Each tick is accounted in a time breakdown
(:mod:`tactex.tasks.time_breakdown`).

Baselines (same controller, force and robot): ``raster`` — a boustrophedon path over the whole
surface; ``no_feedback`` — HEDAC on the first capture only, never re-measuring.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from tactex.config import param
from tactex.control.ga_line_force import GaLineForceController, GaLineForceParams
from tactex.control.nullspace import NullspacePosture
from tactex.control.references import LineForceReference
from tactex.control.safety import MAX_FORCE_SET_POINT_N, SafetyLimits, check_force_set_point
from tactex.ergodic import kernel
from tactex.ergodic.command import ExplorationCommand
from tactex.ergodic.config import HedacConfig
from tactex.ergodic.explorer import HedacExplorer
from tactex.ergodic.relocation import RelocationCommand
from tactex.errors import ConfigError, ExplorationError, InputError, SimulationError, SurfaceNotFound, TactexError
from tactex.geometry.so3 import rotate_towards
from tactex.perception.acquisition import AcquisitionConfig
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.pointcloud.keep_out import (
    DEFAULT_KEEP_OUT_THRESHOLD,
    check_keep_out_options,
    keep_out_on_voxels,
    raw_keep_out,
)
from tactex.pointcloud.markings import resolve_marking
from tactex.pointcloud.shapes import CylinderWallSurface
from tactex.sim.dirt import PrestonParams
from tactex.sim.scene import SceneConfig
from tactex.spectral.basis import build_basis
from tactex.spectral.eigen import check_eigensolver
from tactex.spectral.modes import auto_n_eigen
from tactex.tasks.clean_phases import CLEAN_PHASES
from tactex.tasks.line_reference import LineLead, ToolNormal, blend_normals
from tactex.tasks.progress import Progress
from tactex.tasks.raster import RasterPath, WaypointPath
from tactex.tasks.recorder import Recorder
from tactex.tasks.robot import ROBOT_STOPS, RealRobotParams, end_on_robot, open_backend, stop_reason
from tactex.tasks.runner import ControlLoop, tool_rotation_for_normal
from tactex.tasks.step_ahead import StepAhead
from tactex.tasks.step_hold import StepHold
from tactex.tasks.stroke import MAX_PASSES, IslandStroke, plan_stroke
from tactex.tasks.sweep_plan import MAX_CORNERS, SweepPlan, dirt_island, plan_sweep
from tactex.tasks.time_breakdown import TimeBreakdown, time_to_fraction_removed
from tactex.tasks.vision import capture_target_cloud, remeasure_target, workspace_crop
from tactex.tasks.wear_model import WearModel
from tactex.tasks.world import SimWorldParams

__all__ = ["CLEAN_BASELINES", "CLEAN_OBJECTIVES", "PHASES", "CleanConfig", "CleanResult", "run_clean"]

CLEAN_BASELINES = ("", "raster", "no_feedback")
#: What the HEDAC agent follows between camera views (see CleanConfig.objective).
CLEAN_OBJECTIVES = ("clean", "ergodic")
#: Phase codes recorded in the time series (shared with the report).
PHASES = CLEAN_PHASES
#: Lift-off distance along the tool axis before vision and at the end [m].
RETRACT_M = 0.05
#: Longest single step of a lift-off [m]: each step is one linearised joint move (ControlLoop.retract),
#: whose error grows with the square of its length; on the cup's wall one 5 cm step moved the tool up
#: the wall, dragging the pad, instead of out of it.
RETRACT_STEP_M = 0.025
#: Height of the waypoints above the hover pose on the way from the capture pose, and above the
#: retracted tool on the way back to it [m].
CLEARANCE_M = 0.08
#: Largest joint difference [rad] between the waypoint and the hover for the waypoint to be used.
WAYPOINT_MAX_JOINT_RAD = 0.5
#: Most exploration steps in a row the agent waits for a lagging or dragged tool (CleanConfig.max_lag_m,
#: CleanConfig.hold_force_ratio): a point the tool cannot reach must not hold the program [-].
MAX_HOLD_STEPS = 10
#: Settling after the joint move to the hover pose, before the approach [s].
HOVER_SETTLE_S = 0.1
#: How fast the commanded approach speed falls with the height above the captured surface [1/s]: it reaches
#: zero at CleanConfig.approach_slow_m over about 1 / APPROACH_GAIN_PER_S, time enough for the line's damping
#: (D_z = 50 N·s/m on a few kg of tool) to brake.
APPROACH_GAIN_PER_S = 10.0
#: ... and rises from rest no faster than this [m/s²]: a step of D_z·v in the push shakes the tool, whose inertia
#: the F/T reads as a force (~2 N), above the touch-down threshold at 0.2 m/s.
APPROACH_ACCEL_M_S2 = 1.0
#: Height of the table top the simulated objects stand on [m] (tactex.sim.scene): the capture's crop cuts the
#: table above it and the pad is kept above it.
SUPPORT_Z_M = 0.0
#: Share of the first island's dirt the wear model must predict off by the end of the planned sweep
#: (CleanConfig.sweep_corners) [-]: above the 95 % mark, because the tool rounds the sweep's corners and turns
#: and wipes a little less than the plan.
SWEEP_GOAL = 0.97
#: The planned sweep is made when the island of dirt at the touch-down (dirt joined within two pad radii) holds at
#: least this share of the view's dirt [-].
SWEEP_MIN_SHARE = 0.95
#: tactex's first touch-down (:func:`_quickest_touch_down`): candidates on the dirt one per cell of this grid
#: [m] (at most START_CANDIDATES, the grid widened until so), each a joint-move plan from the capture posture
#: (two IK solves, a few ms each).
START_SPACING_M = 0.01
START_CANDIDATES = 64
#: Their IK stops once its steps are below this [rad]: the planned duration then differs by ~1e-4 s from the
#: full search's (the steps shrink geometrically to a fixed point), far below the 10 ms the choice compares.
START_SETTLED_STEP_RAD = 1e-5
#: ... and gives up after this many steps: a reachable hover settles within ~100 (cup, bowl, plate); one at the
#: edge of the reach chatters for the full search's 500 (~35 ms each) before it is refused.
START_IK_STEPS = 150


def _approach_too_weak(cfg: CleanConfig) -> bool:
    """True when the wrench PID (Kp = 0.5, integrator off until contact) would stall before the
    touch-down threshold: out of contact it pushes with Kp·(F − f), balancing at Kp·F/(1 + Kp)."""
    kp = GaLineForceParams().kp
    return kp * cfg.approach_force_n / (1.0 + kp) <= cfg.contact_threshold_n


@dataclass(frozen=True)
class CleanConfig(SimWorldParams):
    """Parameters of ``tactex clean`` (TEC §V-A3 and Table II where the paper gives them)."""

    object_name: str = param("plate", "object to clean: plate, bowl or cup (any registered object)",
                             option="object", aliases=("--object-name",))
    marking: str = param("X", "dirt pattern: X, RLI, blobs, shapes, full (not with --cloud, whose target is the "
                              "dirt)", unused_with=("cloud", "the cloud's target is the dirt"))
    force_n: float = param(10.0, "pressing force set point along the tool axis, at most "
                                 f"{MAX_FORCE_SET_POINT_N:g}: contact peaks reach twice it, and the safety layer "
                                 f"retreats at {SafetyLimits.max_contact_force:g} [N]")
    n_eigen: int | None = param(
        None, "eigenpairs n_K of the spectral diffusion; default: one per 5 footprint areas of the captured "
        "surface, at least TEC's 200 (which small objects keep), at most 1000 [-]")
    eigensolver: str = param(
        "auto", "eigensolver of the Laplace basis: arpack (exact, the papers'), hierarchical (hierarchical subspace "
        "iteration, 2-6x faster, eigenvalues within about 1 %) or auto (hierarchical from 1000 points on)")
    eigen_tol: float = param(5e-3, "hierarchical eigensolver: bound on each pair's squared relative residual "
                                   "(≈ relative eigenvalue error) [-]")
    alpha: float = param(10.0, "diffusion scale α, δt = α h² (TEC eq. 21) [-]")
    agent_radius_m: float = param(0.02, "agent footprint radius r_a, about the sponge radius [m]")
    voxel_size_m: float = param(0.003, "voxel grid of the captured cloud [m] (TEC: 3 mm)")
    max_velocity: float = param(1.0, "agent speed limit [voxels/step] (Table II)")
    explorer_rate_hz: float = param(20.0, "exploration steps per second of robot time [Hz]")
    vision_every_steps: int = param(
        200, "exploration steps between visual re-measurements with --objective ergodic (TEC §VI-B) [-]")
    vision_max_steps: int = param(
        1200, "with --objective clean, the longest stretch of exploration steps between camera views; the wear "
        "model usually sends the robot back earlier, when it says the dirt is gone or stops falling [-]")
    objective: str = param(
        "clean", "what the agent follows between camera views: 'clean' = the captured dirt minus what the robot's "
        "own Preston wear model (force, slip, pad) says it has removed, so clean points stop attracting; "
        "'ergodic' = the captured dirt as TEC's coverage target (eq. 2)")
    preston_coefficient: float = param(
        5e-3, "Preston coefficient k_p of the sponge on this dirt for the wear model [1/(Pa·m)] (the simulated "
        "sponge's value; calibrate it on a real one: dirt level removed per pascal per metre slid)")
    pad_radius_m: float = param(0.025, "radius of the sponge's pressure disc for the wear model [m]")
    wear_margin: float = param(
        1.5, "predicted removal a point needs before the wear model calls it clean (1 = the model exactly; more "
        "tolerates a miscalibrated k_p or tracking error) [-]")
    model_update_steps: int = param(10, "exploration steps between updates of the explorer's target from the "
                                        "wear model [-]")
    sweep_corners: int = param(
        5, "with --objective clean, the first stretch in contact is a planned sweep: a polyline of at most this "
        f"many straight legs from the touch-down that the wear model predicts takes {100 * SWEEP_GOAL:.0f} % of the "
        "island of dirt there off in the shortest slide (then the explorer goes on); none with a keep-out zone "
        "(a sweep knows none); 0 = none, the explorer from the touch-down [-]")
    model_stall_steps: int = param(
        60, "with --objective clean, back to the camera (or on to the next island of dirt) when the wear model "
        "predicts less than a tenth of what is left removed over this many exploration steps [-]")
    cooling: float = param(
        0.2, "HEDAC heat loss β per exploration step (TEC eq. 4's −u term): the potential reaches about "
        "sqrt(alpha / cooling) voxels around the dirt, so the agent finishes a stroke before crossing to the next; "
        "0 = none (the authors' code) [1/step]")
    stop_remaining: float = param(0.02, "stop when vision sees less than this fraction of the first target [-]")
    budget_s: float = param(
        120.0, "simulated time budget of the whole program; a final 0.4 s lift-off out of contact comes on top [s]")
    capture_distance_m: float = param(0.45, "TCP distance from the object at the capture pose, looking down [m]")
    side_capture_distance_m: float = param(
        0.2, "TCP distance from a wall at the capture pose beside it (the cup) [m]: the arm cannot hold the "
        "horizontal camera 0.45 m out at the wall's mid-height")
    side_capture_elevation_deg: float = param(
        45.0, "elevation of the view onto a wall (the cup) above the horizontal [deg], 0–75: the camera looks down "
        "at the wall's mid-height from above the side the marking faces (a shorter swing of the shoulder from home)")
    hover_height_m: float = param(0.03, "hover above the surface before contact [m]")
    approach_speed_m_s: float = param(
        0.1, "speed of the approach along the normal while the tool is well above the captured surface (falling "
        "to zero at --approach-slow-m); 0 = the force loop's own slow approach (~3 cm/s at --approach-force-n 3) "
        "all the way down [m/s]")
    approach_slow_m: float = param(
        0.01, "height above the captured surface under which only the force loop's slow approach moves the tool "
        "(a margin for the capture's error) [m]")
    joint_speed_rad_s: float = param(
        1.5, "peak joint speed of the joint moves out of contact (to the camera, to a hover, between islands) "
        "[rad/s]; the Franka allows 2.2–2.6")
    approach_force_n: float = param(3.0, "force set point while approaching (slow, gentle touch-down) [N]")
    force_ramp_s: float = param(0.1, "ramp from the approach force to the set point after touch-down [s]")
    contact_threshold_n: float = param(
        0.5, "measured normal force that counts as contact [N]; below the force loop's approach equilibrium "
        "Kp·F_approach/(1 + Kp) = 1 N, so a touch-down is always detected")
    agent_feedback: bool = param(False, "use the measured TCP as the agent position (TEC eq. 22)")
    touch_down_boost: float = param(
        0.4, "after a touch-down the force command rises above the set point by up to this fraction of it, a "
        "smooth pulse peaking --touch-down-boost-s after the touch-down, so that the force loop's integrator "
        "(K_i = 5/s) charges in a few tenths of a second instead of most of a second; the force is judged "
        "against the set point; 0 = none [-]")
    touch_down_boost_s: float = param(0.25, "when the --touch-down-boost pulse peaks after the touch-down [s]")
    max_lag_m: float = param(
        0.0, "the agent waits (its step is put off) while the tool lags the commanded point by more than this "
        "along the surface; 0 = never waits [m]")
    line_lead_s: float = param(
        0.2, "the commanded line's point runs this far ahead of the agent along its step (velocity "
        "feed-forward): the line impedance damps the tool's own speed, so a tool following a moving agent "
        "trails it by speed × D/K (tool x/y: 150/750 = 0.2 s, 1.2 cm at the agent's 6 cm/s), on a strongly "
        "curved wall an angle between the surface under the pad and the commanded line; 0 = the agent's "
        "point itself (TEC eq. 28) [s]")
    line_normal_feedback: float = param(
        0.5, "how far the commanded line's direction leans from the agent's normal towards the captured "
        "surface's normal under the measured tool, 0–1: the tool presses along the surface where it is while "
        "the line, still through the agent point, pulls it along; no effect on a plane; 0 = the agent's "
        "normal (TEC eq. 28) [-]")
    hold_force_ratio: float = param(
        1.5, "the agent waits (its step is put off) while the measured contact force exceeds this multiple of "
        "the set point (the tool dragged against a wall by the line it follows); 0 = never waits [-]")
    max_normal_rate_deg_s: float = param(
        90.0,
        "fastest turn of the commanded normal line while in contact; on a sharp edge (a bowl's rim) the "
        "fitted normal jumps between the two faces from one exploration step to the next [deg/s]",
    )
    baseline: str = param("", "'' (HEDAC with vision feedback), 'raster' or 'no_feedback'")
    cloud: str = param("", "a coloured point cloud or mesh (.ply/.pcd/.npz/.stl/.obj) in the robot base frame [m] "
                           "whose red marking "
                           "(or stored target) is the dirt: no camera capture, no re-measurement (a robot without a "
                           "camera; TEC: markings annotated by an expert). Needed with --robot franka")
    camera_width: int = param(320, "capture image width [px]")
    camera_height: int = param(240, "capture image height [px]")
    seed: int = param(0, "seed of the sensor noise and of the explorer's random headings")
    keep_out_channel: str = param(
        "", "colour channel marking a keep-out zone the sponge must never touch: red, green or blue ('' = none); "
            "read on --cloud's points, else on the captured cloud")
    keep_out_threshold: float = param(DEFAULT_KEEP_OUT_THRESHOLD, "with --keep-out-channel: the channel level at or "
                                      "above which a point is kept out, 0–1 [-]")
    keep_out_mask: str = param(
        "", "a .npy file with one boolean per row of --cloud, rows with NaN coordinates included (True = keep out); "
        "needs --cloud, not a mesh (its points are samples)")

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "marking", resolve_marking(self.marking))  # 'x' is X
        if self.baseline not in CLEAN_BASELINES:
            raise ConfigError(f"unknown baseline '{self.baseline}'; valid: raster, no_feedback (or none)")
        for name in ("approach_speed_m_s", "approach_slow_m"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v >= 0):
                raise ConfigError(f"{name} must be a number ≥ 0, got {getattr(self, name)!r}")
        positive = ("force_n", "alpha", "agent_radius_m", "voxel_size_m", "max_velocity", "explorer_rate_hz",
                    "budget_s", "capture_distance_m", "side_capture_distance_m", "hover_height_m", "approach_force_n",
                    "max_normal_rate_deg_s", "joint_speed_rad_s")
        for name in positive:
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be a positive number, got {getattr(self, name)!r}")
        if self.max_normal_rate_deg_s / self.explorer_rate_hz >= 90.0:
            raise ConfigError(
                f"max_normal_rate_deg_s = {self.max_normal_rate_deg_s} turns the normal by 90° or more per "
                f"exploration step at explorer_rate_hz = {self.explorer_rate_hz}; keep it below "
                f"{90.0 * self.explorer_rate_hz:g} deg/s (an about-turn would blend through a zero normal)"
            )
        if isinstance(self.sweep_corners, bool) or not isinstance(self.sweep_corners, (int, np.integer)) \
                or not 0 <= self.sweep_corners <= MAX_CORNERS:
            raise ConfigError(f"--sweep-corners must be a whole number in 0–{MAX_CORNERS} (0 = no planned sweep), "
                              f"got {self.sweep_corners!r}")
        el = float(self.side_capture_elevation_deg)
        if not (np.isfinite(el) and 0.0 <= el <= 75.0):
            raise ConfigError(f"side_capture_elevation_deg must be within 0–75 deg (above 75 the camera no longer sees "
                              f"the wall), got {self.side_capture_elevation_deg!r}")
        check_force_set_point("force_n", self.force_n)
        if self.approach_force_n > self.force_n:
            raise ConfigError(f"approach_force_n ({self.approach_force_n}) must not exceed force_n ({self.force_n})")
        if not (np.isfinite(self.contact_threshold_n) and self.contact_threshold_n > 0):
            raise ConfigError(f"contact_threshold_n must be > 0 N, got {self.contact_threshold_n!r}")
        if not (np.isfinite(self.force_ramp_s) and self.force_ramp_s > 0):
            raise ConfigError(f"force_ramp_s must be > 0 s, got {self.force_ramp_s!r}")
        if _approach_too_weak(self):
            raise ConfigError(
                f"approach_force_n = {self.approach_force_n} N settles below contact_threshold_n = "
                f"{self.contact_threshold_n} N (out of contact the force loop balances at Kp·F/(1 + Kp) with the "
                "paper's Kp = 0.5): raise the first or lower the second"
            )
        if (self.vision_every_steps < 1 or self.vision_max_steps < 1
                or (self.n_eigen is not None and self.n_eigen < 1)):
            raise ConfigError(
                f"vision_every_steps, vision_max_steps and n_eigen must be ≥ 1, got {self.vision_every_steps}, "
                f"{self.vision_max_steps} and {self.n_eigen}")
        if self.cloud and not Path(self.cloud).is_file():
            raise ConfigError(f"--cloud '{self.cloud}' is not a file (give a .ply/.pcd/.npz in the robot base frame)")
        if self.cloud and self.baseline == "no_feedback":
            raise ConfigError("--cloud already runs without vision feedback; drop --baseline no_feedback")
        check_eigensolver(self.eigensolver, self.eigen_tol)
        if self.objective not in CLEAN_OBJECTIVES:
            raise ConfigError(f"unknown objective '{self.objective}'; valid: {', '.join(CLEAN_OBJECTIVES)}")
        for name in ("preston_coefficient", "pad_radius_m", "wear_margin"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be a positive number, got {getattr(self, name)!r}")
        if not (np.isfinite(self.touch_down_boost_s) and self.touch_down_boost_s > 0):
            raise ConfigError(f"--touch-down-boost-s must be > 0 s (e.g. 0.25), got {self.touch_down_boost_s!r}")
        if not (np.isfinite(self.max_lag_m) and self.max_lag_m >= 0):
            raise ConfigError(f"--max-lag-m must be a distance ≥ 0 m (0: never wait), got {self.max_lag_m!r}")
        if not (np.isfinite(self.line_lead_s) and 0 <= self.line_lead_s <= 1):
            raise ConfigError(f"--line-lead-s must be a time in [0, 1] s (e.g. 0.2, the line impedance's D/K; 0: no "
                              f"lead), got {self.line_lead_s!r}")
        if not (np.isfinite(self.line_normal_feedback) and 0 <= self.line_normal_feedback <= 1):
            raise ConfigError(f"--line-normal-feedback must be a weight in [0, 1] (e.g. 0.5; 0: the agent's normal), "
                              f"got {self.line_normal_feedback!r}")
        if not (np.isfinite(self.touch_down_boost) and 0 <= self.touch_down_boost <= 1):
            raise ConfigError(f"--touch-down-boost must be a fraction of the set point in [0, 1] (e.g. 0.4; 0: none), "
                              f"got {self.touch_down_boost!r}")
        if not (np.isfinite(self.hold_force_ratio) and (self.hold_force_ratio == 0 or self.hold_force_ratio > 1)):
            raise ConfigError(f"--hold-force-ratio must be 0 (never wait) or above 1 (e.g. 1.5): at or below 1 the "
                              f"agent would wait at the set point itself; got {self.hold_force_ratio!r}")
        if not (np.isfinite(self.cooling) and self.cooling >= 0):
            raise ConfigError(f"cooling must be a finite number ≥ 0 [1/step], got {self.cooling!r}")
        if self.model_update_steps < 1 or self.model_stall_steps < 1:
            raise ConfigError(f"model_update_steps and model_stall_steps must be ≥ 1, got {self.model_update_steps} "
                              f"and {self.model_stall_steps}")
        if not 0.0 <= self.stop_remaining < 1.0:
            raise ConfigError(f"stop_remaining must lie in [0, 1), got {self.stop_remaining}")
        check_keep_out_options(self.keep_out_channel, self.keep_out_threshold, self.keep_out_mask)
        if self.keep_out_mask and not self.cloud:
            raise ConfigError("--keep-out-mask marks points of --cloud FILE: give --cloud too (a captured cloud's "
                              "points are not known in advance; mark the zone by colour with --keep-out-channel)")
        if (self.keep_out_channel or self.keep_out_mask) and self.baseline == "raster":
            raise ConfigError("the raster baseline has no keep-out zones; drop --keep-out-* or --baseline raster")

    def scene(self) -> SceneConfig:
        return super().scene(marking=self.marking)


@dataclass
class CleanResult:
    """What a cleaning run produced."""

    config: CleanConfig
    metrics: dict[str, Any]
    series: dict[str, np.ndarray]
    cloud: SurfaceCloud
    fields: dict[str, np.ndarray]
    agent_path: np.ndarray
    tcp_path: np.ndarray
    events: list[Any] = field(default_factory=list)


class _Legs:
    """The explorer's path figures summed over its legs (each ``reset`` starts its path again)."""

    def __init__(self, source) -> None:
        self.source = source
        self.path_m = 0.0  # [m] the agent's path on the surface in the legs before the current one
        self.air_m = 0.0  # [m] and its relocations' flights
        self.relocations = 0
        self.keep_out_contacts = 0

    def restart(self, x0: np.ndarray) -> ExplorationCommand:
        """Close the current leg and start the next at ``x0`` [m]; its first command."""
        s = self.source
        self.path_m += float(getattr(s, "path_length", 0.0))
        self.air_m += float(getattr(s, "air_path_length", 0.0))
        self.relocations += len(getattr(s, "relocations", ()))
        self.keep_out_contacts += int(getattr(s, "keep_out_contacts", 0))
        cmd = s.reset(x0)
        return cmd[0] if isinstance(cmd, list) else cmd


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


def _lag_m(tcp_m: np.ndarray, cmd: ExplorationCommand) -> float:
    """How far the tool at ``tcp_m`` (3,) [m] is from the commanded point along the surface (its offset
    along the normal left out) [m]."""
    d = np.asarray(tcp_m, dtype=float) - cmd.point
    d = d - float(d @ cmd.normal) * cmd.normal
    return float(np.sqrt(d @ d))


def _first_leg(cloud: SurfaceCloud, wear: WearModel, here_m: np.ndarray, from_m: np.ndarray, cfg: CleanConfig,
               step_m: float, support_z_m: float | None) -> tuple[IslandStroke | None, SweepPlan | None]:
    """The first leg in contact from the touch-down ``here_m`` (3,) [m], planned while the arm holds at the capture
    pose: ``(stroke, plan)``. When the wear model's island of dirt there is smaller than the pad, its straight
    stroke (coming from ``from_m`` (3,) [m]) and None. Else, with ``cfg.sweep_corners`` > 0, the planned sweep over
    that island (dirt joined within two pad radii) as a stroke, and its plan; but (None, None), the explorer from
    the touch-down, when the island holds less than :data:`SWEEP_MIN_SHARE` of the view's dirt (after a sweep of one
    island among several the explorer's route over the others is longer than from its own start) or no polyline of
    ``cfg.sweep_corners`` legs reaches :data:`SWEEP_GOAL` within the camera's steps of ``step_m`` [m].
    ``support_z_m`` [m]: the plane the object stands on (None: none)."""
    stroke = plan_stroke(cloud, wear.tree, wear, here_m, from_m, cfg.pad_radius_m, step_m)
    if stroke is not None or cfg.sweep_corners == 0:
        return stroke, None
    view_dirt = wear.remaining()
    island = dirt_island(cloud.points, view_dirt, here_m, 2.0 * cfg.pad_radius_m, spacing_m=cloud.spacing)
    if float(view_dirt[island].sum()) < SWEEP_MIN_SHARE * float(view_dirt.sum()):
        return None, None
    plan = plan_sweep(cloud, wear.tree, view_dirt * island, here_m, cfg.pad_radius_m,
                      cfg.preston_coefficient * cfg.force_n / (np.pi * cfg.pad_radius_m**2), step_m, goal=SWEEP_GOAL,
                      max_corners=cfg.sweep_corners, support_z_m=support_z_m,
                      max_length_m=cfg.vision_max_steps * step_m, seed=cfg.seed)
    if plan is None:
        return None, None
    # the whole view's dirt is its island: not clean when the sweep ends, so the explorer goes on from there
    sweep = IslandStroke(WaypointPath(cloud, plan.waypoints, step_m, tree=wear.tree), np.flatnonzero(wear.dirty()),
                         plan.waypoints[0], plan.waypoints[-1], passes=MAX_PASSES)
    return sweep, plan


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


class _Log:
    """Per-tick bookkeeping: force statistics every tick, a time series at ``record_hz``."""

    def __init__(self, backend, cfg: CleanConfig) -> None:
        self.backend = backend
        self.truth = hasattr(backend, "dirt_remaining")  # a simulation knows the dirt; a real robot does not
        self.cfg = cfg
        self.rec = Recorder(every=max(1, round(1.0 / (cfg.record_hz * backend.dt))))
        self.t = 0.0  # time of the last tick [s]
        # every phase change as (t [s], phase id): the series samples at record_hz and misses short
        # phases (an approach of a few ms, a capture that takes no tick at all)
        self.phase_changes: list[tuple[float, int]] = [(0.0, PHASES["move"])]
        self.agent = np.full(3, np.nan)
        self.contact_ticks = 0
        self.within_ticks = 0
        self.over_2x_ticks = 0
        self.explore_contact_ticks = 0
        self.max_force = 0.0
        self.set_point = cfg.force_n
        self.time = TimeBreakdown(backend.dt, cfg.contact_threshold_n, self.truth)

    def activity(self, phase: str, activity: str) -> None:
        """Enter a phase of the state machine (:data:`PHASES`) doing ``activity`` (time breakdown)."""
        self.phase = PHASES[phase]
        self.time.set_activity(activity)

    @property
    def phase(self) -> int:
        return self.phase_changes[-1][1]

    @phase.setter
    def phase(self, value: int) -> None:
        if value != self.phase_changes[-1][1]:
            self.phase_changes.append((self.t, int(value)))

    def __call__(self, state, reference, controller) -> None:
        self.t = float(state.t)
        f = state.wrench_tool
        fn = float(f[2])
        fmag = float(np.sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]))
        self.max_force = max(self.max_force, fmag)
        self.time.tick(fn)
        if fn >= self.cfg.contact_threshold_n and self.phase == PHASES["explore"]:
            self.contact_ticks += 1
            if abs(fn - self.set_point) <= 0.2 * self.set_point:
                self.within_ticks += 1
            if fn > 2.0 * self.set_point:
                self.over_2x_ticks += 1
        if self.rec.due():
            dirt = self.backend.dirt_remaining() if self.truth else np.nan
            self.time.dirt(dirt)
            self.rec.add(
                t=state.t, phase=self.phase, q=state.q, tcp=state.ee_position, agent=self.agent, force_z_n=fn,
                force_norm_n=fmag, set_point_n=self.set_point if self.phase == PHASES["explore"] else 0.0,
                pad_force_n=self.backend.pad_contact()[0] if self.truth else np.nan,
                dirt_remaining=dirt,
            )
        else:
            self.rec.add()


def _capture_pose(scene: SceneConfig, cfg: CleanConfig) -> tuple[np.ndarray, np.ndarray]:
    """Where the robot looks from: above a height field, beside a cylinder wall (camera ⟂ surface)."""
    pos, rot = scene.object_pose()
    surface = scene.sim_object.surface
    if isinstance(surface, CylinderWallSurface):
        out = rot @ np.array([0.0, -1.0, 0.0])  # the side the cup's marking faces
        centre = pos + rot @ np.array([0.0, 0.0, surface.height_m / 2])
        up = rot @ np.array([0.0, 0.0, 1.0])
        el = np.radians(cfg.side_capture_elevation_deg)
        view = np.cos(el) * out + np.sin(el) * up  # from the wall's mid-height towards the camera
        return (centre + out * surface.radius_m + view * cfg.side_capture_distance_m,
                tool_rotation_for_normal(view))
    top = pos + rot @ np.array([0.0, 0.0, float(surface.bounds_m[1, 2])])
    return top + np.array([0.0, 0.0, cfg.capture_distance_m]), tool_rotation_for_normal(np.array([0.0, 0.0, 1.0]))


def _hover_plan(loop: ControlLoop, point_m: np.ndarray, normal: np.ndarray, q_seed: np.ndarray,
                hover_height_m: float, q_from: np.ndarray | None = None, q_hover: np.ndarray | None = None,
                settled_step_rad: float | None = None, max_iter: int | None = None,
                ) -> tuple[np.ndarray | None, np.ndarray, float]:
    """The joint moves from ``q_from`` (default: the current posture) to the hover ``hover_height_m`` [m] above
    ``point_m`` along ``normal``: ``(q_above, q_hover, move_s)``, ``q_above`` the waypoint :data:`CLEARANCE_M`
    straight above the hover (None when it is not a short step from it) and ``move_s`` [s] the moves'
    duration. IK is searched from ``q_seed`` (``q_hover``: the hover's posture when already solved;
    ``settled_step_rad``: :meth:`ControlLoop.solve_pose`'s, ``max_iter`` its for the hover). Raises
    SimulationError when the hover is out of the arm's reach."""
    rot = tool_rotation_for_normal(normal)
    hover = np.asarray(point_m, dtype=float) + hover_height_m * np.asarray(normal, dtype=float)
    if q_hover is None:
        q_hover = loop.solve_pose(hover, rot, q_seed=q_seed, settled_step_rad=settled_step_rad, max_iter=max_iter)
    # Through a waypoint straight above the hover pose: a joint move from the high capture pose down to a
    # hover inside a bowl can swing the tool through the rim on the way. The waypoint is solved from the hover
    # (same IK branch) and dropped when it is not a short step from it.
    try:
        # never cut short by max_iter: a waypoint given up on would make the plan the (quicker) direct move
        q_above: np.ndarray | None = loop.solve_pose(hover + np.array([0.0, 0.0, CLEARANCE_M]), rot, q_seed=q_hover,
                                                     settled_step_rad=settled_step_rad)
    except SimulationError:
        q_above = None
    if q_above is not None and float(np.max(np.abs(q_above - q_hover))) > WAYPOINT_MAX_JOINT_RAD:
        q_above = None
    if q_above is None:
        return None, q_hover, loop.joint_move_duration(q_hover, q_from=q_from)
    return q_above, q_hover, (loop.joint_move_duration(q_above, q_from=q_from)
                              + loop.joint_move_duration(q_hover, q_from=q_above))


def _quickest_touch_down(loop: ControlLoop, cloud: SurfaceCloud, targets: np.ndarray, q_capture: np.ndarray,
                         cap_pos: np.ndarray, hover_height_m: float) -> np.ndarray | None:
    """tactex's first touch-down [m]: of the dirty points ``targets`` (indices into ``cloud``), one per cell of a
    grid (:data:`START_SPACING_M`, coarser until at most :data:`START_CANDIDATES` are left), the one whose hover
    the arm reaches soonest from the capture posture ``q_capture`` (the moves :func:`_hover_plan` plans), and of
    those equally quick (to 10 ms) the nearest to the camera at ``cap_pos`` [m]. None when the cloud has no
    normals or no candidate's hover is within reach.

    It is wall-clock work while the robot holds at the capture pose, so it is kept cheap: each candidate's hover
    posture is solved once (the IK stops when its steps settle, :data:`START_SETTLED_STEP_RAD`, and gives up
    after :data:`START_IK_STEPS`), and the direct joint move to it, a lower bound on the planned moves (the
    min-jerk duration is subadditive), orders the candidates; the waypoint above the hover is solved only while
    that bound can still beat the best plan."""
    if cloud.normals is None or targets.size == 0:
        return None
    pts = cloud.points[targets]
    spacing = START_SPACING_M
    while True:
        _, first = np.unique(np.floor(pts / spacing).astype(np.int64), axis=0, return_index=True)
        if first.size <= START_CANDIDATES:
            break
        spacing *= 1.5
    bounded: list[tuple[tuple[float, float], int, np.ndarray]] = []
    for j in np.sort(first):
        normal = cloud.normals[targets[j]]
        hover = pts[j] + hover_height_m * normal
        try:
            q_hover = loop.solve_pose(hover, tool_rotation_for_normal(normal), q_seed=q_capture,
                                      settled_step_rad=START_SETTLED_STEP_RAD, max_iter=START_IK_STEPS)
        except SimulationError:
            continue
        bound_s = loop.joint_move_duration(q_hover, q_from=q_capture)
        bounded.append(((round(bound_s, 2), float(np.linalg.norm(pts[j] - cap_pos))), int(j), q_hover))
    bounded.sort(key=lambda c: (c[0], c[1]))
    best: tuple[float, float] | None = None
    chosen = None
    for bound_key, j, q_hover in bounded:
        if best is not None and bound_key > best:
            break  # this and every later candidate takes at least as long as the best plan
        move_s = _hover_plan(loop, pts[j], cloud.normals[targets[j]], q_capture, hover_height_m, q_from=q_capture,
                             q_hover=q_hover, settled_step_rad=START_SETTLED_STEP_RAD)[2]
        key = (round(move_s, 2), bound_key[1])
        if best is None or key < best:
            best, chosen = key, pts[j].copy()
    return chosen


def _approach_speed(tcp_m: np.ndarray, cmd: ExplorationCommand, cfg: CleanConfig) -> float:
    """The approach speed [m/s] commanded with the tool at ``tcp_m`` (3,) [m] over ``cmd``'s point: falling
    in proportion to the height above the captured surface (:data:`APPROACH_GAIN_PER_S`) from
    ``cfg.approach_speed_m_s`` to zero at ``cfg.approach_slow_m``, below which the force loop's own slow
    approach touches down."""
    height_m = float((np.asarray(tcp_m, dtype=float) - cmd.point) @ cmd.normal)
    return float(np.clip(APPROACH_GAIN_PER_S * (height_m - cfg.approach_slow_m), 0.0, cfg.approach_speed_m_s))


def _pad_over_support(point_m: np.ndarray, normal: np.ndarray, support_z_m: float, pad_radius_m: float) -> np.ndarray:
    """The commanded line's point ``point_m`` (3,) [m], raised along world z where needed so that the pad, a disc
    of ``pad_radius_m`` [m] centred there and ⟂ ``normal`` (3,), stays above the support plane z = ``support_z_m``
    [m]: at the foot of a wall (the cup's) the line through the lowest captured ring pressed the pad's rim into the
    table, the tool held 2.5 cm up by it and dragged sideways by the line (tangential forces past 2× the set
    point)."""
    n = np.asarray(normal, dtype=float)
    n_z2 = float(n[2] * n[2]) / max(float(n @ n), 1e-12)
    low = support_z_m + pad_radius_m * float(np.sqrt(max(1.0 - n_z2, 0.0)))
    if point_m[2] >= low:
        return point_m
    out = np.array(point_m, dtype=float)
    out[2] = low
    return out


def _touchable(indices: np.ndarray, touch_down_ok: np.ndarray | None) -> np.ndarray:
    """The cloud points ``indices`` a touch-down may be at (``touch_down_ok`` (N,) bool; None: all), or all of
    them when none is (the dirt left lies only beside a keep-out zone)."""
    if touch_down_ok is not None and touch_down_ok[indices].any():
        return indices[touch_down_ok[indices]]
    return indices


def _lift_off(loop: ControlLoop, distance_m: float, duration_s: float = 0.4) -> None:
    """Back along the tool axis by ``distance_m`` [m] in steps of at most :data:`RETRACT_STEP_M`, each
    re-linearised where the last ended, taking ``duration_s`` [s] at least."""
    n = max(int(np.ceil(distance_m / RETRACT_STEP_M - 1e-9)), 1)
    for _ in range(n):
        loop.retract(distance_m / n, duration_s=duration_s / n)


def _acquisition(scene: SceneConfig) -> AcquisitionConfig:
    pos, _ = scene.object_pose()
    surface = scene.sim_object.surface
    half = float(np.max(np.abs(surface.bounds_m[:, :2]))) + 0.01
    if isinstance(surface, CylinderWallSurface):
        # the wall only: a view from above the wall also sees the cup's top, which is not the surface to clean
        # (2 mm below it, as the table is cut 2 mm above the table top)
        lo, hi = workspace_crop(pos, half, table_z_m=SUPPORT_Z_M, height_m=surface.height_m - 0.002)
    else:
        lo, hi = workspace_crop(pos, half, table_z_m=SUPPORT_Z_M)
    return AcquisitionConfig(crop_min_m=lo, crop_max_m=hi, voxel_size_m=0.0, sor_mean_k=20, sor_std_mul=2.0)


def load_target_cloud(path: str | Path, voxel_size_m: float) -> SurfaceCloud:
    """A user's cloud (or mesh) in the robot base frame as the cleaning target: voxelised, its stored
    target or else its red marking (by hue and saturation: ``tactex explore --target auto``, white is
    not dirt), with normals estimated (16 neighbours, oriented up) where the file has none."""
    return load_target_cloud_keep_out(path, voxel_size_m)[0]


def load_target_cloud_keep_out(path: str | Path, voxel_size_m: float, keep_out_channel: str = "",
                               keep_out_threshold: float = DEFAULT_KEEP_OUT_THRESHOLD,
                               keep_out_mask: str = "") -> tuple[SurfaceCloud, np.ndarray | None]:
    """:func:`load_target_cloud` and its keep-out zone (a boolean per returned point, None without one;
    see :mod:`tactex.pointcloud.keep_out`)."""
    from tactex.perception.normals import knn_normals
    from tactex.pointcloud.io import read_cloud
    from tactex.pointcloud.target import TargetRule, file_target

    read = read_cloud(path, mesh_spacing_m=voxel_size_m)
    raw = read.cloud
    voxel_size_m = 0.0 if read.n_faces else voxel_size_m  # a mesh is sampled at the voxel spacing already
    keep_out = raw_keep_out(raw, keep_out_channel, keep_out_threshold, keep_out_mask, read)
    if raw.colors is None and raw.n_target == 0:
        raise InputError(f"--cloud '{path}' has neither a target nor colours: mark the dirt red (255, 0, 0)")
    cloud, _ = file_target(raw, voxel_size_m, TargetRule("auto"), str(path))
    if keep_out is not None and voxel_size_m > 0:
        keep_out = keep_out_on_voxels(raw.points, keep_out, voxel_size_m)
    if cloud.normals is None:
        field = knn_normals(cloud.points, 16, viewpoint=cloud.points.mean(axis=0) + np.array([0.0, 0.0, 1.0]))
        cloud = replace(cloud.subset(field.ok), normals=field.normals[field.ok], spacing=cloud.spacing)
        keep_out = None if keep_out is None else keep_out[field.ok]
    return cloud, keep_out


def _cloud_capture_pose(cloud: SurfaceCloud, cfg: CleanConfig) -> tuple[np.ndarray, np.ndarray]:
    """Above a user's cloud: its top, ``capture_distance_m`` higher, looking down."""
    lo, hi = cloud.points.min(axis=0), cloud.points.max(axis=0)
    top = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, hi[2]])
    return top + np.array([0.0, 0.0, cfg.capture_distance_m]), tool_rotation_for_normal(np.array([0.0, 0.0, 1.0]))


def run_clean(config: CleanConfig | None = None, *, progress: bool = True,
              robot: RealRobotParams | None = None) -> CleanResult:
    """Run the cleaning program in simulation, or on a real Franka (``robot``, with ``config.cloud``),
    and return its metrics, series and fields.

    A libfranka error, a lost sensor or Ctrl-C ends the program early: torque control stops and the
    result holds what was recorded, ``aborted`` naming the cause in its metrics."""
    cfg = config or CleanConfig()
    if robot is not None and not cfg.cloud:
        raise ConfigError("clean on a real robot takes its target from --cloud FILE (a coloured cloud in the robot "
                          "base frame); capturing it with the wrist camera is done in simulation only")
    scene_cfg = cfg.scene()
    backend = open_backend(scene_cfg, robot)
    started = _Started()
    try:
        return _run_clean(cfg, backend, scene_cfg, robot, progress, started)
    except TactexError as exc:  # a RobotError, a SensorFault, SurfaceNotFound, a failure of ours
        # on a robot, a stop outside the program's loop (the moves before its first touch-down, the final
        # lift-off) keeps what was recorded too; the loop's own stops are kept inside it
        result = started.stopped(cfg, exc) if robot is not None else None
        if result is None:
            raise
        return result
    finally:
        backend.close()


class _Started:
    """What :func:`_run_clean` has started, for a run on a robot that stops outside the program's loop."""

    def __init__(self) -> None:
        self.log: _Log | None = None
        self.loop: ControlLoop | None = None
        self.cloud: SurfaceCloud | None = None
        self.t0 = time.perf_counter()

    def stopped(self, cfg: CleanConfig, exc: BaseException) -> CleanResult | None:
        """The run so far (torque control ended, ``aborted`` naming ``exc``, the series recorded), or
        None when nothing was recorded yet."""
        log, loop, cloud = self.log, self.loop, self.cloud
        if log is None or loop is None or cloud is None:
            return None
        series = log.rec.arrays()
        if not len(series.get("t", ())):
            return None
        aborted = end_on_robot(loop, exc)
        backend = loop.backend
        metrics = {
            "aborted": aborted,
            "robot": "franka",
            "sim_time_s": loop.t,
            "wall_time_s": time.perf_counter() - self.t0,
            "force_within_20pct_fraction": log.within_ticks / max(log.contact_ticks, 1),
            "max_contact_force_n": log.max_force,
            "contact_time_s": log.contact_ticks * backend.dt,
            "force_set_point_n": cfg.force_n,
            "baseline": cfg.baseline or "tactex",
            "object": cfg.object_name,
            "marking": "cloud",
            "target_source": "cloud",
            "n_points": len(cloud),
            "safety_events": len(loop.safety.events),
            "torque_rate_clip_ticks": loop.safety.counts.get("torque_rate_limit", 0),
            "phase_changes": [[t, p] for t, p in log.phase_changes],
            **backend.loop_metrics(),
        }
        return CleanResult(config=cfg, metrics=metrics, series=series, cloud=cloud,
                           fields={"target_initial": cloud.target.copy()}, agent_path=np.zeros((0, 3)),
                           tcp_path=series.get("tcp", np.zeros((0, 3))), events=list(loop.safety.events))


#: Share of a --cloud's target off the simulated object above which the run warns [-].
OFF_SURFACE_WARN = 0.2


def _dirt_from_cloud(backend, cloud: SurfaceCloud, object_name: str) -> None:
    """In simulation with ``--cloud``, the dirt is the cloud's target, not the scene's ``--marking``: what the run
    reports as removed is then what the user marked (``cloud``'s target: the caller leaves out the dirt a keep-out
    zone and its clearance hold, which no footprint may touch). The cells within 0.71 voxel of a target point
    (the farthest a cell inside a marked area lies from the grid's points) are dirty."""
    from scipy.spatial import cKDTree

    pos, rot = backend.object_pose()
    target_obj = (cloud.points[cloud.target > 0] - pos) @ rot
    radius = cloud.spacing * np.sqrt(0.5)
    field = backend.dirt
    if field.paint(target_obj, radius) == 0:
        raise ConfigError(
            f"no point of --cloud's target lies on the simulated {object_name}'s surface (within {radius * 1e3:.1f} "
            "mm): the cloud must be in the robot base frame, with the object where the scene puts it (--object)")
    off = cKDTree(field.points[field.valid]).query(target_obj)[0] > radius
    if off.mean() > OFF_SURFACE_WARN:
        warnings.warn(f"clean: {off.mean():.0%} of --cloud's target lies farther than {radius * 1e3:.1f} mm from the "
                      f"simulated {object_name}'s surface and is not simulated as dirt (is the cloud in the robot "
                      "base frame?)", RuntimeWarning, stacklevel=2)


def _run_clean(cfg: CleanConfig, backend, scene_cfg: SceneConfig, robot: RealRobotParams | None,
               progress: bool, started: _Started | None = None) -> CleanResult:
    wall0 = time.perf_counter()
    log = _Log(backend, cfg)
    loop = ControlLoop(backend, on_tick=log, max_joint_speed=cfg.joint_speed_rad_s)
    bar = Progress(cfg.budget_s, f"clean {cfg.baseline or 'tactex'}", enabled=progress)
    given, keep_out = (load_target_cloud_keep_out(cfg.cloud, cfg.voxel_size_m, cfg.keep_out_channel,
                                                  cfg.keep_out_threshold, cfg.keep_out_mask)
                       if cfg.cloud else (None, None))
    if started is not None:
        started.log, started.loop, started.cloud = log, loop, given
    acq = replace(_acquisition(scene_cfg), voxel_size_m=cfg.voxel_size_m)
    cap_pos, cap_rot = _capture_pose(scene_cfg, cfg) if given is None else _cloud_capture_pose(given, cfg)
    try:
        q_capture = backend.solve_ik(cap_pos, cap_rot)  # TEC's pre-recorded capture posture
    except SimulationError as exc:
        which = "side_capture_distance_m" if isinstance(scene_cfg.sim_object.surface, CylinderWallSurface) \
            else "capture_distance_m"
        raise ConfigError(f"the capture pose at {np.round(cap_pos, 3).tolist()} m is out of the arm's reach ({exc}); "
                          f"lower {which} (now {getattr(cfg, which)} m)") from exc
    dirt = backend.dirt_remaining if log.truth else (lambda: float("nan"))
    # [m] the table top the captured object stands on (the capture's crop cuts the table above it); a given
    # cloud's support is not known
    support_z = SUPPORT_Z_M if given is None else None

    def capture(lift: bool = False) -> SurfaceCloud:
        log.activity("move", "vision")
        if lift:
            # From a retract inside a bowl a single joint move to the capture pose dipped the tool back
            # into the bowl (hits of up to 720 N, a force trip that aborted the move, and a camera that
            # then saw no object): straight up first, then along a line of IK waypoints.
            loop.retract(CLEARANCE_M, duration_s=0.4, direction_world=np.array([0.0, 0.0, 1.0]))
            try:
                loop.move_cartesian(cap_pos, cap_rot, settle_s=0.0, q_goal=q_capture)
            except SimulationError as exc:  # the joint move below is the fallback (it was the only way before)
                warnings.warn(f"clean: no straight way back to the camera ({exc}); moving in joint space",
                              RuntimeWarning, stacklevel=2)
        loop.move_joints(q_capture, settle_s=0.3)
        log.activity("capture", "vision")
        if given is not None:
            return given
        return capture_target_cloud(backend.render_depth(), acq)

    # 1. capture and segment the dirt. A given cloud needs no capture: the basis and the explorer are
    # made before the arm moves, since on a real robot nothing slow may run while torque control is on
    cloud = capture() if given is None else given
    if given is None and cfg.keep_out_channel:
        keep_out = raw_keep_out(cloud, cfg.keep_out_channel, cfg.keep_out_threshold, "")
    # dirt under a keep-out zone is never cleaned: it counts neither in the start nor in what is left
    cleanable = np.ones(len(cloud), dtype=bool) if keep_out is None else ~keep_out
    n_target0 = int(np.count_nonzero(cloud.target[cleanable] > 0))
    if n_target0 == 0 and keep_out is not None and cloud.n_target > 0:
        raise ExplorationError("every dirty point the capture sees lies in the keep-out zone: nothing may be "
                               "cleaned; check --keep-out-channel/--keep-out-threshold/--keep-out-mask")
    if n_target0 == 0:
        raise ExplorationError("the first capture sees no dirt: nothing to clean (check the marking and the view)")

    # 2. hover while the eigenbasis is computed (wall-clock work; the robot holds still)
    t_basis = time.perf_counter()
    basis = None
    if cfg.baseline != "raster":
        n_eigen = cfg.n_eigen
        if n_eigen is None:  # each point of the voxelised capture stands for about h² of surface
            n_eigen = auto_n_eigen(len(cloud) * cloud.spacing**2, cfg.agent_radius_m, len(cloud))
        if n_eigen >= len(cloud):
            raise ConfigError(
                f"n_eigen = {n_eigen} eigenpairs, but the captured cloud has only {len(cloud)} points: ask for "
                f"fewer (TEC uses 100–200; e.g. {min(200, len(cloud) - 1)})"
            )
        basis = build_basis(cloud, n_eigen=n_eigen, cache=False, eigensolver=cfg.eigensolver,
                            eigen_tol=cfg.eigen_tol)
    basis_s = time.perf_counter() - t_basis
    dt_step = 1.0 / cfg.explorer_rate_hz
    if cfg.baseline == "raster":
        step_m = cfg.max_velocity * cloud.spacing
        source: Any = RasterPath(cloud, lane_spacing_m=1.5 * cfg.agent_radius_m, max_step_m=step_m)
    else:
        hcfg = HedacConfig(
            alpha=cfg.alpha, n_eigen=basis.evecs.shape[1], agent_radius_m=cfg.agent_radius_m,
            max_velocity=cfg.max_velocity, max_acceleration=cfg.max_velocity, step_duration_s=dt_step, seed=cfg.seed,
            # No hops in contact: over a hole in the capture (the shadow behind a bowl's rim) the real
            # surface is unknown and the tool would drag over edges (bowl: 88 % of contact within
            # ±20 % and 20.4 N peaks with hops, 93.5 % and 18 N without). Dirt beyond a hole is
            # reached the safe way: lift, re-measure, restart at the nearest remaining dirt.
            max_bridge=0.0,
            # Sliding along the capture's edges, not braking at them: on the bowl, whose capture has a
            # hole in the rim's shadow, braking gave 87.9 % of contact within ±20 % and 21.0 N peaks,
            # sliding 93.5 % and 18.2 N (the plate: 92.9 % and 13.6 N against 93.0 % and 13.4 N).
            edge_braking=False,
            cooling=cfg.cooling,
            # the dirt is a distribution the wear model keeps updating (eq. 1–2), even on a uniformly marked
            # surface: the sweep source is explore's, for a whole surface passed over once
            source_mode="ergodic",
            # with the wear model the task moves between islands itself, from what the model says is left
            # (the explorer's stall rule fired at a 1 cm spot the cooled potential holds the agent on); the
            # explorer's relocation stays for keep-out zones, whose flights it plans around them
            relocate=keep_out is not None or not (cfg.baseline == "" and cfg.objective == "clean"),
        )
        if hcfg.compiled and kernel.compile_pending():
            bar.note("preparing the compiled exploration step (numba compiles it on a machine's first run, ~10–15 s; "
                     "later runs load it)")
        source = HedacExplorer(cloud, basis, hcfg, keep_out=keep_out)
    # where the sponge may touch down, as the explorer's own relocations: a footprint radius (and half a voxel)
    # clear of every keep-out point (None: anywhere; a keep-out zone comes with the explorer, not the raster)
    touch_down_ok = source.clear_points if keep_out is not None and isinstance(source, HedacExplorer) else None
    if touch_down_ok is not None:  # dirt that close to the zone is no goal of the explorer's either: not cleanable
        cleanable &= touch_down_ok
        n_target0 = int(np.count_nonzero(cloud.target[cleanable] > 0))
    # dirty points the explorer leaves out of its target as too near a keep-out zone (counted before the wear
    # model's targets, which hold none of them)
    near_keep_out = int(getattr(source, "target_near_keep_out", 0))
    if near_keep_out:
        bar.note(f"{near_keep_out} dirty points lie within {source.keep_out_clearance_m * 1e3:.1f} mm "
                 "of the keep-out zone (agent radius + ½ voxel), where the sponge may not be centred: no goal (a pass "
                 "beside them may still brush them)")
    cleanable_target = np.where(cleanable, cloud.target, 0.0)
    if given is not None and log.truth:
        _dirt_from_cloud(backend, cloud.with_target(cleanable_target), scene_cfg.object_name)
    # where the sponge first touches down, on dirt it may touch
    targets = _touchable(np.flatnonzero((source.target if isinstance(source, HedacExplorer) else cloud.target) > 0),
                         touch_down_ok)
    # the raster from its waypoint nearest the dirt nearest the camera; tactex where the arm gets soonest
    x0 = cloud.points[targets[np.argmin(np.linalg.norm(cloud.points[targets] - cap_pos, axis=1))]]
    t_plan = time.perf_counter()
    if isinstance(source, HedacExplorer):  # wall-clock work while the robot holds, like the basis
        quickest = _quickest_touch_down(loop, cloud, targets, q_capture, cap_pos, cfg.hover_height_m)
        x0 = x0 if quickest is None else quickest
    start_plan_s = time.perf_counter() - t_plan
    if given is not None:
        source.reset(x0)  # a first step here, not in the loop: numba loads the compiled step on first use
        source.step()
        capture()  # to the capture posture, as the camera path did
    # the set-up below (the wear model, the planned sweep: up to about a second) runs between two ticks
    loop.pause()
    cmd: ExplorationCommand = source.reset(x0)
    cmd = cmd[0] if isinstance(cmd, list) else cmd
    # the robot's own estimate of what it has wiped off since the last view (tactex only: the baselines
    # keep TEC's coverage target)
    wear = (WearModel(cloud, cfg.preston_coefficient, cfg.pad_radius_m, PrestonParams().force_threshold_n,
                      cfg.wear_margin) if cfg.baseline == "" and cfg.objective == "clean" else None)
    if wear is not None:
        wear.reset(cleanable_target)  # dirt the robot may not touch is never predicted left: it holds no goal
    target0 = float(cleanable_target.sum())
    lead = LineLead(cfg.line_lead_s, dt_step)
    tool_normal = (ToolNormal(cloud, tree=wear.tree if wear is not None else None)
                   if cfg.line_normal_feedback > 0 else None)
    vision_steps = cfg.vision_every_steps if wear is None else cfg.vision_max_steps
    islands_tried: list[np.ndarray] = []  # [m] touch-down points of the relocations since the last view
    island_moves = 0  # those relocations
    # control ticks between wear-model updates (the pad moves well under a millimetre)
    wear_ticks = _WearTicks(wear, backend.dt, every=10) if wear is not None else None

    # the posture of the capture pose keeps the redundant elbow where it was planned
    ga = NullspacePosture(GaLineForceController(GaLineForceParams()), q_posture=q_capture)
    t_end = cfg.budget_s
    vision_updates = 0
    vision_times: list[float] = []  # [s] when each re-measurement was taken
    vision_trip_s = 5.0  # [s] retract, lift, transit and capture (~4.5 s on the plate); measured after the first trip
    legs = _Legs(source)
    # islands smaller than the pad get a straight stroke instead of the explorer (wear model only; a stroke
    # knows no keep-out zone)
    strokes = wear is not None and keep_out is None
    stroke: IslandStroke | None = None
    stroke_step_m = cfg.max_velocity * cloud.spacing  # the agent's speed limit
    hold_force_n = cfg.hold_force_ratio * cfg.force_n if cfg.hold_force_ratio > 0 else np.inf
    island_move_s = 3.5  # [s] lift-off, move and touch-down at the next island; measured after the first
    t_move = None  # when the island move in progress started
    counted: IslandStroke | None = None  # the last stroke counted in n_strokes / n_transfers
    n_strokes = n_transfers = 0  # strokes through small islands; slides in contact to the next island
    new_leg = True  # the next touch-down starts a leg (the first, after an island move or a camera view)
    leg_from = cap_pos  # where the robot comes from to that leg
    remaining_seen = 1.0
    agent_path: list[np.ndarray] = []
    ergodicity: list[tuple[float, float]] = []
    explore_time = 0.0

    # the first stretch in contact (a small island's stroke, the planned sweep or neither: the explorer), planned
    # while the robot still holds at the capture pose (wall clock, counted with the choice of the touch-down)
    first_leg: IslandStroke | None = None
    first_plan: SweepPlan | None = None
    if strokes:
        t_plan = time.perf_counter()
        first_leg, first_plan = _first_leg(cloud, wear, cmd.point, leg_from, cfg, stroke_step_m, support_z)
        start_plan_s += time.perf_counter() - t_plan
    first_sweep = first_leg if first_plan is not None else None
    first_leg_due = strokes  # the next leg is the first: its stroke is planned already

    aborted = ""
    try:
        while loop.t < t_end:
            if new_leg and strokes:
                if first_leg_due:
                    stroke, first_leg_due = first_leg, False
                    if first_sweep is not None:
                        counted = first_sweep  # not an island stroke
                else:
                    stroke = plan_stroke(cloud, wear.tree, wear, cmd.point, leg_from, cfg.pad_radius_m,
                                         stroke_step_m)
                if stroke is not None:
                    cmd = stroke.path.reset()
            new_leg = False
            # 3a. hover over the agent and approach along its normal line
            log.activity("move", "transit")
            try:
                q_above, q_hover, move_s = _hover_plan(loop, cmd.point, cmd.normal, q_capture, cfg.hover_height_m)
            except SimulationError:
                # out of the arm's reach (the far side of the cup): the nearest other dirt the wear model
                # knows of, or the end of the program when there is none (TEC's loop has no other to offer)
                island = None
                if wear is not None:
                    islands_tried.append(cmd.point.copy())
                    island = wear.next_island(cmd.point, islands_tried, 2.0 * cfg.pad_radius_m, touch_down_ok)
                if wear is None:
                    raise
                if island is None:
                    warnings.warn(f"clean: no hover pose over {np.round(cmd.point, 3).tolist()} m within reach and "
                                  "no other dirt left to the wear model; ending the program", RuntimeWarning,
                                  stacklevel=2)
                    break
                warnings.warn(f"clean: no hover pose over {np.round(cmd.point, 3).tolist()} m within reach; "
                              f"moving on to the dirt at {np.round(island, 3).tolist()} m", RuntimeWarning,
                              stacklevel=2)
                # a stroke planned there goes with it: the new island starts a leg of its own
                stroke, new_leg = None, True
                cmd = legs.restart(island)
                continue
            if loop.t + move_s + HOVER_SETTLE_S >= t_end:
                break  # the move alone would use up the budget
            if q_above is not None:
                loop.move_joints(q_above, settle_s=0.0)
            loop.move_joints(q_hover, settle_s=HOVER_SETTLE_S)
            log.activity("approach", "touch_down")
            loop.use(ga)
            t_touch = None
            t_approach_start = loop.t
            t_approach_end = loop.t + 6.0
            while loop.t < min(t_approach_end, t_end):
                v_approach = min(_approach_speed(loop.state.ee_position, cmd, cfg),
                                 APPROACH_ACCEL_M_S2 * (loop.t - t_approach_start))
                s = loop.tick(LineForceReference(cmd.point, cmd.normal, cfg.approach_force_n, v_approach))
                if s.wrench_tool[2] >= cfg.contact_threshold_n:
                    t_touch = loop.t
                    break
            if t_touch is None and loop.t >= t_end:
                break  # the time budget ended during the approach
            if t_move is not None and t_touch is not None:
                island_move_s, t_move = t_touch - t_move, None
            if t_touch is None:
                loop.pause()  # a real robot holds itself while the run's data is written
                raise SurfaceNotFound(
                    f"no contact within 6 s of approach at {np.round(cmd.point, 3).tolist()}; the captured "
                    "surface and the real one disagree (object moved?)"
                )
            # 3b. contact exploration
            log.activity("explore", "explore")
            prev = cmd
            n_prev = n_next = cmd.normal.copy()  # the commanded normal line, turned at a bounded rate
            max_turn = np.radians(cfg.max_normal_rate_deg_s) * dt_step
            next_step = loop.t
            steps_since_vision = 0
            covered = False
            relocation = None
            t_phase = loop.t
            if wear_ticks is not None:
                wear_ticks.restart()
            predicted_left: list[float] = []  # the wear model's remaining fraction at each update
            # done when the model says the camera would stop, and after a return for a remnant, once most
            # of that remnant is off: each trip back costs a touch-down and a trip to the camera
            done_level = (cfg.stop_remaining if wear is None
                          else min(cfg.stop_remaining, 0.2 * wear.remaining_fraction(target0)))
            relocate_to = None
            hold = StepHold(MAX_HOLD_STEPS)
            lead.reset()
            ahead = StepAhead(source, backend.dt, wear=wear, settle=wear_ticks.settle if wear_ticks else None,
                              agent_feedback=cfg.agent_feedback, read_residual=given is not None,
                              model_update_steps=cfg.model_update_steps, island_radius_m=2.0 * cfg.pad_radius_m)
            while loop.t < t_end:
                due = loop.t >= next_step - 1e-9
                if due and hold.hold(
                        (cfg.max_lag_m > 0 and _lag_m(loop.state.ee_position, cmd) > cfg.max_lag_m)
                        or float(np.linalg.norm(loop.state.wrench_tool[:3])) > hold_force_n):
                    # the tool is behind, or dragged against a wall (a bowl's, climbing towards the rim): hold the
                    # line at the agent's point while it catches up (for a few steps at most: a point it cannot
                    # reach must not hold the program)
                    prev, n_prev, next_step = cmd, n_next, next_step + dt_step
                elif due:
                    prev = cmd
                    measured = loop.state.ee_position if cfg.agent_feedback else None
                    if stroke is not None and stroke.path.done:
                        wear_ticks.settle()
                        if stroke.clean(wear) or not stroke.next_pass(stroke_step_m):
                            stroke, relocate_to, covered = _after_stroke(
                                stroke, cmd, wear, cfg, cloud, target0, islands_tried, legs, stroke_step_m,
                                island_move_s * cfg.explorer_rate_hz * stroke_step_m, done_level, touch_down_ok)
                            if relocate_to is not None:
                                break
                            if covered:
                                break
                            if stroke is None:  # the explorer takes over here
                                legs.restart(cmd.point)
                                predicted_left.clear()
                                # from what the model says is left, not from its target of before the stroke
                                # (its own next model update is model_update_steps away); applied after this
                                # tick's send, so the first step, taken in this tick, still sees the old target
                                ahead.update_target_later(wear.remaining())
                    taken = ahead.take() if stroke is None else None
                    if taken is not None:
                        cmd, reads = taken
                    elif stroke is not None:
                        cmd = stroke.path.step()
                        reads = ahead.read(cmd, steps_since_vision + 1, model=False)
                    else:
                        cmd = source.step(measured)
                        reads = ahead.read(cmd, steps_since_vision + 1)
                    if stroke is not None and stroke is not counted:
                        counted = stroke
                        n_strokes += not stroke.transfer_only
                        n_transfers += stroke.transfer
                    if isinstance(cmd, RelocationCommand):
                        relocation = cmd  # lift off here, fly, touch down at cmd.point (3a below)
                        break
                    n_goal = cmd.normal
                    if tool_normal is not None:  # the line leans towards the surface the tool presses on
                        n_goal = blend_normals(cmd.normal, tool_normal.at(loop.state.ee_position),
                                               cfg.line_normal_feedback)
                    n_prev, n_next = n_next, rotate_towards(n_next, n_goal, max_turn)
                    next_step += dt_step
                    steps_since_vision += 1
                    agent_path.append(cmd.point)
                    log.agent = cmd.point
                    if "ergodicity" in reads:  # every ERGODICITY_EVERY_STEPS steps of the explorer
                        ergodicity.append((loop.t, reads["ergodicity"]))
                        covered = reads["residual"] is not None and reads["residual"] <= cfg.stop_remaining
                    if "predicted" in reads:  # a wear-model update while the explorer drives the agent
                        predicted = reads["predicted"]
                        left = float(predicted.sum()) / target0
                        predicted_left.append(left)
                        back = cfg.model_stall_steps // cfg.model_update_steps
                        # stalled: less than a tenth of what is left wiped off over the last model_stall_steps
                        stalled = len(predicted_left) > back and predicted_left[-1 - back] - left < 0.1 * left
                        # or the island under the agent is done while a far one holds a fair share (the cooled
                        # potential barely reaches it): nothing the model calls dirty within two pad radii
                        stalled = stalled or (left > 4 * cfg.stop_remaining and not reads["island_left"])
                        if left > done_level and stalled:
                            # dirt left, but not where the agent is: lift off and touch down at the nearest
                            # island the model calls dirty, unless there is none it has not tried since the
                            # last view or it holds less than the camera's stop level (then the camera judges:
                            # each touch-down costs about half a second of force settling and a second of time)
                            island = wear.next_island(cmd.point, islands_tried, 2.0 * cfg.pad_radius_m, touch_down_ok)
                            if (island is None
                                    or wear.dirt_near(island, 2.0 * cfg.pad_radius_m) < cfg.stop_remaining * target0):
                                covered = True
                            else:
                                islands_tried.append(island)
                                transfer_max_m = island_move_s * cfg.explorer_rate_hz * stroke_step_m
                                if strokes and float(np.linalg.norm(island - cmd.point)) < transfer_max_m:
                                    stroke = plan_stroke(cloud, wear.tree, wear, island, cmd.point, cfg.pad_radius_m,
                                                         stroke_step_m, transfer_from_m=cmd.point)
                                if stroke is not None:
                                    stroke.path.reset()  # slide there in contact from the next step on
                                else:
                                    relocate_to = island
                                    break
                        elif left <= done_level:
                            covered = True  # the model says the job is done: time for the camera to judge
                        else:
                            ahead.update_target_later(predicted)
                frac = min(max(1.0 - (next_step - loop.t) / dt_step, 0.0), 1.0)
                # velocity feed-forward: the line's point where the agent will be line_lead_s later
                point = prev.point + frac * (cmd.point - prev.point) + lead.offset(prev.point, cmd.point, backend.dt)
                normal = n_prev + frac * (n_next - n_prev)
                if support_z is not None:
                    point = _pad_over_support(point, normal, support_z, cfg.pad_radius_m)
                ramp = min((loop.t - t_touch) / cfg.force_ramp_s, 1.0)
                force = cfg.approach_force_n + ramp * (cfg.force_n - cfg.approach_force_n)
                log.set_point = force  # the band is judged against the set point, never the boost below
                if cfg.touch_down_boost > 0:  # a smooth pulse from zero, peaking touch_down_boost_s after touch-down
                    x = (loop.t - t_touch) / cfg.touch_down_boost_s
                    force += cfg.touch_down_boost * cfg.force_n * x * float(np.exp(1.0 - x))
                # the phase ends after this tick: the wear model (or, for a given cloud, the coverage) says the
                # dirt is gone, or the camera is due
                ending = covered or (cfg.baseline == "" and given is None and steps_since_vision >= vision_steps)
                # the explorer steps ahead only for a step it will take in this phase
                ahead.arm(next_step, steps_since_vision + 1, enabled=stroke is None and not ending)
                state_next = loop.tick(LineForceReference(point, normal, force), after_send=ahead)
                if wear_ticks is not None:
                    wear_ticks.note(state_next, normal)
                if int(loop.t * 1000) % 250 == 0:
                    bar.update(loop.t, dirt=dirt(), vision=vision_updates)
                if ending or (cfg.baseline == "raster" and source.done and not ahead.pending):
                    break
            if wear_ticks is not None:
                wear_ticks.settle()  # the phase's last tick
            explore_time += loop.t - t_phase
            if relocation is not None:
                # TEC §VI-B: lift off along the normal, then the hover and approach of 3a at the touch-down
                log.activity("retract", "transit")
                _lift_off(loop, max(relocation.clearance_m, cfg.hover_height_m))
                bar.note(f"relocating ({relocation.reason}): {relocation.air_length_m:.3f} m through the air")
                continue
            if relocate_to is not None:
                # to the next island through the air: lift off here, then the hover and approach of 3a
                log.activity("retract", "transit")
                _lift_off(loop, RETRACT_M)
                island_moves += 1
                leg_from, new_leg, t_move = cmd.point, True, loop.t
                if stroke is not None:
                    legs.path_m += stroke.path.path_length
                    stroke = None
                cmd = legs.restart(relocate_to)
                continue
            if cfg.baseline == "raster" and source.done:
                break
            if cfg.baseline != "" or given is not None or loop.t + vision_trip_s >= t_end:
                break  # (a re-measurement that would end after the budget could not be used)
            # 4. back to vision: re-measure the dirt on the same points, update the target
            t_trip = loop.t
            log.activity("retract", "vision")
            _lift_off(loop, RETRACT_M)
            new_capture = capture(lift=True)
            vision_trip_s = loop.t - t_trip  # the next trip's estimate
            vision_updates += 1
            vision_times.append(loop.t)
            mass = remeasure_target(cloud, new_capture)
            mass = np.where(cleanable, mass, 0.0)
            remaining_seen = float(np.count_nonzero(mass)) / n_target0
            bar.update(loop.t, dirt=dirt(), vision=vision_updates)
            if remaining_seen < cfg.stop_remaining or not np.any(mass > 0):
                break
            source.update_target(mass)
            if wear is not None:
                wear.reset(mass)  # the camera's view replaces the prediction
                islands_tried.clear()
            # restart from the dirt nearest to where the robot is
            left = _touchable(np.flatnonzero(mass > 0), touch_down_ok)
            x0 = cloud.points[left[np.argmin(np.linalg.norm(cloud.points[left] - cmd.point, axis=1))]]
            leg_from, new_leg = cmd.point, True
            if stroke is not None:
                legs.path_m += stroke.path.path_length
                stroke = None
            cmd = legs.restart(x0)
    except ROBOT_STOPS as exc:
        # torque control has ended (libfranka on its errors, the backend on ours): keep what was recorded
        aborted = stop_reason(exc)
        bar.note(f"stopped early: {aborted}")
    except TactexError as exc:
        if robot is None:  # in simulation an error of ours is raised; on a robot the run keeps its data
            raise
        aborted = end_on_robot(loop, exc)
        bar.note(f"stopped early: {aborted}")
    if stroke is not None:  # the program ended during a stroke: its path so far is part of the agent's
        legs.path_m += stroke.path.path_length

    # lift off at the end so the final state is out of contact (0.4 s, on top of the budget)
    log.activity("retract", "lift_off")
    if not aborted and loop.state.wrench_tool[2] > cfg.contact_threshold_n:
        _lift_off(loop, RETRACT_M)
    bar.close(f"dirt removed {100 * (1 - dirt()):.1f} %" if log.truth else "done (the dirt is not measured here)")

    series = log.rec.arrays()
    contact = max(log.contact_ticks, 1)
    t95 = (time_to_fraction_removed(series["t"], series["dirt_remaining"], 0.95)
           if log.truth and len(series.get("t", ())) else None)
    fields = {"target_initial": cloud.target.copy()}
    if isinstance(source, HedacExplorer):
        fields.update(target=source.target.copy(), coverage=source.coverage.copy(), potential=source.potential.copy())
    metrics = {
        "dirt_removed_fraction": 1.0 - dirt(),
        # the shares count the normal force while exploring in contact; the maximum is the force
        # magnitude over every phase (a transit's or a sideways hit's too)
        "force_within_20pct_fraction": log.within_ticks / contact,
        "max_contact_force_n": log.max_force,
        "force_over_2x_ticks": log.over_2x_ticks,
        "contact_time_s": log.contact_ticks * backend.dt,
        "sim_time_s": loop.t,
        "explore_time_s": explore_time,
        # issue 21: where the time went, and when 95 % of the marking was off (None: never, or no ground truth)
        "time_breakdown_s": log.time.seconds(),
        # the same up to the 95 % mark (None when it never came or the dirt is not known): the time to 95 % split
        "time_breakdown_to_95pct_s": log.time.seconds_to_mark(),
        "time_to_95pct_s": t95,
        "vision_updates": vision_updates,
        "island_relocations": island_moves,
        "island_strokes": n_strokes,
        # [m] slid along the planned first sweep (0: none, or its touch-down was out of reach) and its slide to
        # the goal as the wear model predicted it when planned (0: none planned)
        "first_sweep_m": 0.0 if first_sweep is None else first_sweep.path.path_length,
        "first_sweep_planned_m": 0.0 if first_plan is None else first_plan.length_m,
        "contact_transfers": n_transfers,
        "vision_update_times_s": vision_times,
        "phase_changes": [[t, p] for t, p in log.phase_changes],
        "vision_remaining_fraction": remaining_seen,
        "basis_time_s": basis_s,
        "start_plan_time_s": start_plan_s,  # [s] wall clock: choosing the first touch-down (IK per candidate)
        "n_eigen": 0 if basis is None else basis.n_eigen,
        "eigensolver": "" if basis is None else basis.eigensolver,
        "wall_time_s": time.perf_counter() - wall0,
        "n_points": len(cloud),
        "n_target_initial": n_target0,
        "agent_path_length_m": legs.path_m + float(getattr(source, "path_length", 0.0)),
        "air_path_length_m": legs.air_m + float(getattr(source, "air_path_length", 0.0)),
        "relocations": legs.relocations + len(getattr(source, "relocations", ())),
        "keep_out_points": int(keep_out.sum()) if keep_out is not None else 0,
        "keep_out_contacts": legs.keep_out_contacts + int(getattr(source, "keep_out_contacts", 0)),
        "target_near_keep_out": near_keep_out,
        "force_set_point_n": cfg.force_n,
        "baseline": cfg.baseline or "tactex",
        "object": cfg.object_name,
        "marking": "cloud" if cfg.cloud else cfg.marking,  # with --cloud the dirt is its target (simulated too)
        "safety_events": len(loop.safety.events),
        # per kind: events (force_limit: one per retreat), ticks for nan_wrench and the torque and rate limits
        "safety_counts": dict(loop.safety.counts),
        "safety_limits": {"max_contact_force_n": loop.safety.limits.max_contact_force,
                          "tau_rate_max_n_m_s": loop.safety.limits.tau_rate_max},
        # every tick the torque-rate limiter changed the command (an event marks only where a run of them starts)
        "torque_rate_clip_ticks": loop.safety.counts.get("torque_rate_limit", 0),
        "ergodicity": ergodicity,
        "robot": "franka" if robot is not None else "sim",
        "target_source": "cloud" if given is not None else "camera",
        "aborted": aborted,
        "partial": bool(aborted),  # the program stopped before its end (Ctrl-C or the robot): aborted says why
    }
    if robot is not None:
        metrics.update(backend.loop_metrics())
    return CleanResult(
        config=cfg, metrics=metrics, series=series, cloud=cloud, fields=fields,
        agent_path=np.asarray(agent_path).reshape(-1, 3), tcp_path=series.get("tcp", np.zeros((0, 3))),
        events=list(loop.safety.events),
    )
