"""Parameters of ``tactex clean`` (TEC §V-A3 and Table II where the paper gives them)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from tactex.config import param
from tactex.control.ga_line_force import GaLineForceParams
from tactex.control.safety import MAX_FORCE_SET_POINT_N, SafetyLimits, check_force_set_point
from tactex.ergodic.config import HedacConfig
from tactex.errors import ConfigError
from tactex.pointcloud.keep_out import DEFAULT_KEEP_OUT_THRESHOLD, check_keep_out_options
from tactex.pointcloud.markings import resolve_marking
from tactex.pointcloud.units import check_units
from tactex.sim.part import is_part_file, object_or_part, part_info, resolve_object_or_part
from tactex.sim.scene import SceneConfig
from tactex.spectral.eigen import check_eigensolver
from tactex.tasks.clean.sweep_plan import MAX_CORNERS
from tactex.tasks.world import SimWorldParams

__all__ = ["CLEAN_BASELINES", "CLEAN_EXPLORER", "CLEAN_OBJECTIVES", "DEFAULT_MARKING", "RASTER_BASELINES", "SWEEP_GOAL",
           "CleanConfig"]

CLEAN_BASELINES = ("", "raster", "region_raster", "no_feedback")
#: The dirt on a built-in object when no --marking is given.
DEFAULT_MARKING = "X"
#: The baselines that follow a planned raster instead of the explorer (no eigenbasis).
RASTER_BASELINES = ("raster", "region_raster")
#: What the HEDAC agent follows between camera views (see CleanConfig.objective).
CLEAN_OBJECTIVES = ("clean", "ergodic")
#: (CleanConfig.sweep_corners) [-]: above the 95 % mark, because the tool rounds the sweep's corners and turns
#: and wipes a little less than the plan.
SWEEP_GOAL = 0.97
#: The planned sweep is made when the island of dirt at the touch-down (dirt joined within two pad radii) holds at
#: The explorer of a robot in contact. The options alpha, agent_radius_m, max_velocity (which also bounds
#: the acceleration), cooling and seed of :class:`CleanConfig` replace its values; the run sets the rest
#: (the eigenpairs from the captured cloud, the step's duration from explorer_rate_hz, relocation).
CLEAN_EXPLORER = HedacConfig(
    alpha=10.0, agent_radius_m=0.02, max_velocity=1.0, max_acceleration=1.0, cooling=0.2,
    # No hops in contact: over a hole in the capture (the shadow behind a bowl's rim) the real surface is
    # unknown and the tool would drag over edges. Dirt beyond a hole is reached the safe way: lift,
    # re-measure, restart at the nearest remaining dirt.
    max_bridge_voxels=0.0,
    # Sliding along the capture's edges, not braking at them: braking at the edge of a capture with a hole
    # (a bowl's rim shadow) shakes the tool out of its force band and raises the force peaks.
    edge_braking=False,
    # the dirt is a distribution the wear model keeps updating (eq. 1–2), even on a uniformly marked
    # surface: the sweep source is explore's, for a whole surface passed over once
    source_mode="ergodic",
)
#: The fields of CLEAN_EXPLORER a CleanConfig option of the same name sets.
EXPLORER_OPTIONS = ("alpha", "agent_radius_m", "max_velocity", "cooling", "seed")


#: The rasters' lanes apart, in agent radii (CleanConfig.lane_spacing_m).
LANE_SPACING_RADII = 1.5
#: The largest value a length option may take [m]; beyond it the value is millimetres typed as metres (a sponge
#: 40 cm wide, a hover 30 cm up: the arm would clean nothing) [m].
LENGTH_TOPS_M = {"pad_radius_m": 0.2, "hover_height_m": 0.3, "approach_slow_m": 0.1, "capture_distance_m": 1.0,
                 "side_capture_distance_m": 1.0}
#: The Franka's lowest joint speed limit (joints 1-4; 5-7 allow 2.61) [rad/s].
FRANKA_JOINT_SPEED_RAD_S = 2.175


def _approach_too_weak(cfg: CleanConfig) -> bool:
    """True when the wrench PID (Kp = 0.5, integrator off until contact) would stall before the
    touch-down threshold: out of contact it pushes with Kp·(F − f), balancing at Kp·F/(1 + Kp)."""
    kp = GaLineForceParams().kp
    return kp * cfg.approach_force_n / (1.0 + kp) <= cfg.contact_threshold_n


@dataclass(frozen=True)
class CleanConfig(SimWorldParams):
    """Parameters of ``tactex clean`` (TEC §V-A3 and Table II where the paper gives them).

    ``explorer`` is the HEDAC explorer's configuration: :data:`CLEAN_EXPLORER` with this config's options of
    the same names (:data:`EXPLORER_OPTIONS`: the ones a user tunes, as flags, study parameters and keywords),
    made by the constructor."""

    object_name: str = param("plate", "object to clean: plate, bowl or cup (any registered object), or your part's "
                             "mesh or scan file (.stl/.obj/.ply/.pcd/.npz, in --units) as a height-field object whose "
                             "red marking (or stored target) is the dirt (docs/own_part.md)",
                             option="object", aliases=("--object-name",))
    marking: str = param("", "dirt pattern: X, RLI, blobs, shapes, full; default X on a built-in object, a part "
                             "file's own marking on --object FILE (not with --cloud, whose target is the dirt)",
                         unused_with=("cloud", "the cloud's target is the dirt"))
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
    alpha: float = param(CLEAN_EXPLORER.alpha, "diffusion scale α, δt = α h² (TEC eq. 21) [-]")
    agent_radius_m: float = param(CLEAN_EXPLORER.agent_radius_m,
                                  "agent footprint radius r_a, about the sponge radius [m]")
    voxel_size_m: float = param(0.003, "voxel grid of the captured cloud [m] (TEC: 3 mm)")
    max_velocity: float = param(CLEAN_EXPLORER.max_velocity, "agent speed limit [voxels/step] (Table II)")
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
        5e-3, "the wear model's estimate of the Preston coefficient k_p of the sponge on this dirt [1/(Pa·m)] (the "
        "simulated sponge's true value is --preston-coefficient of tactex twin and of the scene; calibrate the "
        "estimate on a real sponge: dirt level removed per pascal per metre slid)",
        option="preston_estimate", aliases=("--preston-coefficient",))
    dirt_preston_coefficient: float = param(
        SceneConfig().preston_coefficient, "in simulation, the simulated dirt's true Preston coefficient k_p "
        "[1/(Pa·m)] (what tactex twin --preston-coefficient sets on the twin): below --preston-estimate the dirt is "
        "tougher than the wear model thinks (a miscalibrated estimate); not read on a robot, whose dirt is real")
    pad_radius_m: float = param(0.025, "radius of the sponge's pressure disc for the wear model [m]")
    wear_margin: float = param(
        1.5, "predicted removal a point needs before the wear model calls it clean (1 = the model exactly; more "
        "tolerates a miscalibrated k_p or tracking error) [-]")
    model_update_steps: int = param(10, "exploration steps between updates of the explorer's target from the "
                                        "wear model [-]")
    sweep_corners: int = param(
        8, "with --objective clean, the first stretch in contact is a planned sweep: a polyline of at most this "
        f"many straight legs from the touch-down that the wear model predicts takes {100 * SWEEP_GOAL:.0f} % of the "
        "island of dirt there off in the shortest slide (then the explorer goes on), searched with at most 5 legs "
        "first; none with a keep-out zone (a sweep knows none); 0 = none, the explorer from the touch-down [-]")
    model_stall_steps: int = param(
        60, "with --objective clean, back to the camera (or on to the next island of dirt) when the wear model "
        "predicts less than a tenth of what is left removed over this many exploration steps [-]")
    cooling: float = param(
        CLEAN_EXPLORER.cooling, "HEDAC heat loss β per exploration step (TEC eq. 4's −u term): the potential "
        "reaches about sqrt(alpha / cooling) voxels around the dirt, so the agent finishes a stroke before crossing "
        "to the next; 0 = none (the authors' code) [1/step]")
    stop_remaining: float = param(0.02, "stop when vision sees less than this fraction of the first target [-]")
    budget_s: float = param(
        120.0, "simulated time budget of the whole program; a final lift-off out of contact (the force unloaded in "
        "0.25 s, then 0.4 s of lift) comes on top [s]")
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
    load_check: bool = param(
        True, "at the first still hold in free space, measure a tool weight the robot's load setting misses and "
        "compensate it (tactex.control.load_error); off: the force loop's integrator alone removes it")
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
        0.28, "the commanded line's point runs this far ahead of the agent along its step (velocity "
        "feed-forward): the line impedance damps the tool's own speed, so a tool following a moving agent "
        "trails it by speed × D/K (tool x/y: 150/750 = 0.2 s, 1.2 cm at the agent's 6 cm/s), and the pad's "
        "sliding friction holds it back by μ·F/K more (5 mm at μ = 0.4 and 10 N: 0.09 s at 6 cm/s), which the "
        "default makes up for in most part (a larger lead swings the line's point further at each reversal); on "
        "a strongly curved wall the trail is an angle between the surface under the pad and the commanded "
        "line; 0 = the agent's point itself (TEC eq. 28) [s]")
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
    baseline: str = param("", "'' (HEDAC with vision feedback), 'raster' (the whole surface, in order), "
                              "'region_raster' (a plane-slicer raster over the captured dirt only, re-measured "
                              "and rastered again like tactex) or 'no_feedback' (HEDAC without re-measurement)")
    cloud: str = param("", "a coloured point cloud or mesh (.ply/.pcd/.npz/.stl/.obj) in the robot base frame [m] "
                           "whose red marking "
                           "(or stored target) is the dirt: no camera capture, no re-measurement (a robot without a "
                           "camera; TEC: markings annotated by an expert). Needed with --robot franka")
    units: str = param("m", "length unit of the --cloud and --object files: m, mm or in; their coordinates are "
                            "converted to metres as they are read")
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
    explorer: HedacConfig = field(init=False, repr=False, metadata={"cli": False})

    def __post_init__(self) -> None:
        part = is_part_file(self.object_name)
        if part and self.cloud and self.object_position is None:
            # the cloud is in the robot base frame, so is a part file given with it: the part stands where its
            # file has it (a scan and its marking are then one)
            check_units(self.units)
            info = part_info(object_or_part(resolve_object_or_part(self.object_name), self.units))
            object.__setattr__(self, "object_position", info.file_origin_m)
        super().__post_init__()
        if self.marking:
            object.__setattr__(self, "marking", resolve_marking(self.marking))  # 'x' is X
        elif not part:
            object.__setattr__(self, "marking", DEFAULT_MARKING)
        elif not self.cloud and not part_info(object_or_part(self.object_name, self.units)).has_target:
            raise ConfigError(f"--object '{self.object_name}' marks no dirt (no red faces or vertices, no 'target' "
                              "property): colour the dirt red in the file, or give --marking NAME or --cloud FILE")
        if self.baseline not in CLEAN_BASELINES:
            raise ConfigError(f"unknown baseline '{self.baseline}'; valid: "
                              f"{', '.join(b for b in CLEAN_BASELINES if b)} (or none)")
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
        for name, top_m in LENGTH_TOPS_M.items():
            if float(getattr(self, name)) > top_m:
                default = type(self).__dataclass_fields__[name].default
                raise ConfigError(f"{name} = {getattr(self, name)!r} m is over {top_m:g} m: it is in metres "
                                  f"(the default {default:g} m is {1e3 * default:g} mm)")
        if self.joint_speed_rad_s > FRANKA_JOINT_SPEED_RAD_S:
            raise ConfigError(f"joint_speed_rad_s = {self.joint_speed_rad_s:g} rad/s is over the Franka's "
                              f"{FRANKA_JOINT_SPEED_RAD_S} rad/s (its shoulder and elbow joints' limit)")
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
        check_units(self.units)
        if self.units != "m" and not self.cloud and not part:
            raise ConfigError(f"--units {self.units} is the unit of a --cloud or --object FILE: give one")
        if self.cloud and self.baseline == "no_feedback":
            raise ConfigError("--cloud already runs without vision feedback; drop --baseline no_feedback")
        check_eigensolver(self.eigensolver, self.eigen_tol)
        if self.objective not in CLEAN_OBJECTIVES:
            raise ConfigError(f"unknown objective '{self.objective}'; valid: {', '.join(CLEAN_OBJECTIVES)}")
        for name in ("preston_coefficient", "dirt_preston_coefficient", "pad_radius_m", "wear_margin"):
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
        if (self.keep_out_channel or self.keep_out_mask) and self.baseline in RASTER_BASELINES:
            raise ConfigError(f"the {self.baseline} baseline has no keep-out zones; drop --keep-out-* or "
                              f"--baseline {self.baseline}")
        explorer = replace(CLEAN_EXPLORER, **{name: getattr(self, name) for name in EXPLORER_OPTIONS},
                           max_acceleration=self.max_velocity)
        object.__setattr__(self, "explorer", explorer)

    def scene(self) -> SceneConfig:
        return super().scene(marking=self.marking, preston_coefficient=self.dirt_preston_coefficient)

    @property
    def lane_spacing_m(self) -> float:
        """The rasters' lane spacing [m]: 1.5 agent radii, as far apart as the explorer's footprints overlap
        on its passes; the stripe one pass of the pad wipes clean, the pad's effective width of the bound."""
        return LANE_SPACING_RADII * self.agent_radius_m

