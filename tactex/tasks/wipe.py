"""Visuo-tactile exploration of an unknown curvature by VA-UFIC (VA-UFIC §III–IV) in simulation.

The robot does not know the surface. It starts above it, out of contact and misaligned, and runs
the paper's wiping policy in the tool frame,

    f_d = [0, 0, 15, 0, 0, 0] N,
    x_d(t) = [0.04 sin 2t, 0.04 (cos 2t − 1) − 0.005 t, 0, 0, 0, 0] m,

with VA-UFIC and its energy tanks at 1 kHz, the F/T sensor at 1 kHz and the wrist camera's
surface estimate (normal, curvature, θ) at 30 Hz. The policy's increments are applied in the
current tool frame, so when VA-UFIC re-orients the tool to the surface the motion follows it
("regenerates the motion and force policy", §II-B).

The sponge slides with Coulomb friction, which holds a compliance controller back by μ·f_n/K
(6 mm at μ = 0.4, 15 N and Table I's K_max = 1000 N/m, already the paper's stiffness bound). By
default (``friction_compensation``) VA-UFIC feeds the tangential contact force the F/T sensor
measures forward through its impedance tank (:mod:`tactex.control.friction`); switched off, the
controller is the paper's.

The baseline (``baseline='cartesian'``) is what a user would otherwise run: a fixed-orientation
Cartesian impedance controller with a constant 15 N force command along the tool axis.

Outputs (:class:`WipeResult`): the metrics of §IV (MAE/RMSE of force and motion), the series of
Fig. 3 a–d, the trajectory against the true surface (Fig. 2) and the explored surface (contact
points with normals and curvature) as a cloud that the ergodic explorer can load.

Motion error (§IV, Fig. 3b "desired vs. actual motion in the base frame"): x − x_d per axis of the
base (world) frame, x the TCP and x_d the effective desired position (the policy plus the offset
VA-UFIC fed back while compliant). ``motion_mae_m``/``motion_rmse_m`` count the ticks in contact
with ρ_align = 1 (the tracking the controller commits to; while the contact monitor makes it
compliant it yields on purpose); ``motion_*_all_contact_m`` count every contact tick and
``motion_*_tool_m`` give the aligned errors in the tool frame. The paper's z is the base frame's,
not the tool's force axis: with the tool tilted up to 18° on the sine panel the two differ.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from tactex.config import param
from tactex.control.cartesian_impedance import CartesianImpedanceController
from tactex.control.friction import FrictionCompensator, FrictionCompensatorParams
from tactex.control.nullspace import NullspacePosture
from tactex.control.safety import MAX_FORCE_SET_POINT_N, SafetyLimits, check_force_set_point
from tactex.control.va_ufic import VaUficController, VaUficParams, desired_rotation_from_normal
from tactex.errors import ConfigError, PolicyFault, PolicyFileError, SurfaceNotFound, TactexError
from tactex.perception.estimate import SurfaceEstimate
from tactex.perception.estimator import SurfaceEstimatorConfig
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.pointcloud.voxel import voxel_indices
from tactex.robots.loop import ControlLoop
from tactex.sim.scene import SceneConfig
from tactex.tasks.explored_surface import ExploredSurface
from tactex.tasks.pass_learning import PassCorrection
from tactex.tasks.policies import ForceMotionPolicy, sinusoid_xy
from tactex.tasks.policies.guard import PolicyGuard
from tactex.tasks.progress import Progress
from tactex.tasks.recorder import Recorder
from tactex.tasks.robot import (
    ROBOT_STOPS,
    RealRobotParams,
    SurfaceVision,
    check_estimate_camera,
    end_on_robot,
    open_backend,
    open_vision,
    stop_reason,
)
from tactex.tasks.transit import PartShape, move_clear_of_part
from tactex.tasks.wipe_policy import (
    check_policy_call_time,
    check_sinusoid,
    check_wipe_policy,
    policy_segments,
    wipe_limits,
    wipe_policy,
    wipe_start_pose,
)
from tactex.tasks.wipe_references import WipeReferences
from tactex.tasks.world import SimWorldParams

__all__ = ["WIPE_BASELINES", "WipeConfig", "WipeResult", "run_wipe", "wiping_policy"]

WIPE_BASELINES = ("", "cartesian")
#: Lift-off along the tool axis after the policy [m].
LIFT_OFF_M = 0.03


def wiping_policy(t: float, amplitude_m: float = 0.04, omega: float = 2.0, drift_m_s: float = 0.005) -> tuple[
        np.ndarray, np.ndarray]:
    """VA-UFIC §III-A position policy in the tool frame: x_d(t) [m] and its rate [m/s] (3,) each."""
    x0, x1, v0, v1 = sinusoid_xy(t, amplitude_m, omega, drift_m_s)
    return np.array([x0, x1, 0.0]), np.array([v0, v1, 0.0])


#: ρ_align from which a tick counts as aligned: VA-UFIC committed to tracking its reference (eq. 20–21 clip at 1).
ALIGNED_RHO = 1.0 - 1e-9
#: Spacing of the surface the live page draws [m].
LIVE_SPACING_M = 0.004


@dataclass(frozen=True)
class WipeConfig(SimWorldParams):
    """Parameters of ``tactex wipe`` (VA-UFIC §III and Table I)."""

    object_name: str = param("sine_panel", "the unknown surface (VA-UFIC §III: sine_panel)", option="object",
                             aliases=("--object-name",))
    duration_s: float = param(20.0, "duration of the wiping policy [s]")
    force_n: float = param(15.0, f"commanded force along the tool axis f_d,z, at most {MAX_FORCE_SET_POINT_N:g}: "
                                 "contact peaks reach twice it, and the safety layer retreats at "
                                 f"{SafetyLimits.max_contact_force:g} [N]")
    amplitude_m: float = param(0.04, "circle radius of the policy [m]")
    omega_rad_s: float = param(2.0, "angular rate of the policy circle [rad/s]")
    drift_m_s: float = param(0.005, "drift of the policy along −y of the tool [m/s]")
    start_y_m: float = param(0.08, "start position along the panel's y axis, object frame [m]")
    start_height_m: float = param(0.015, "start height of the TCP above the surface (no contact) [m]")
    start_tilt_deg: float = param(12.0, "initial misalignment: tool tilt about the world x axis [deg]")
    contact_threshold_n: float = param(1.0, "measured normal force that counts as contact [N]")
    approach_depth_m: float = param(
        0.03, "before the first contact, the run ends (SurfaceNotFound, data kept) once the TCP is this far past "
        "where the surface should be, along the start tool axis: no surface is there [m]")
    tanks_enabled: bool = param(True, "VA-UFIC energy tanks on")
    friction_compensation: bool = param(
        True, "VA-UFIC feeds the measured tangential contact force forward through its impedance tank "
        "(tactex.control.friction); off: the paper's law, which lags the policy by μ·f_n/K_max")
    friction_gain: float = param(0.9, "fraction of the measured tangential force fed forward, in [0, 1] [-]")
    friction_cutoff_hz: float = param(10.0, "low-pass cut-off on the measured tangential force [Hz]")
    baseline: str = param("", "'' (VA-UFIC) or 'cartesian' (fixed-orientation impedance, constant force)")
    camera_rate_hz: float = param(30.0, "wrist camera rate [Hz]")
    policy: str = param("", "force-motion policy file (.toml: segments of sinusoid, line, zigzag, spiral, circle, "
                            "figure8, samples; tactex.tasks.policies.policy_file), checked before the arm moves; "
                            "'' runs the §III sinusoid (amplitude_m, omega_rad_s, drift_m_s at force_n). The run "
                            "ends at the policy's end or at duration_s, whichever comes first")
    policy_max_speed_m_s: float = param(0.15, "fastest in-plane speed a policy may command [m/s]")
    policy_max_accel_m_s2: float = param(1.0, "largest in-plane acceleration a policy may command [m/s²]")
    replan_from: str = param(
        "", "run folder of an earlier wipe of the same part and policy: its explored surface puts the motion "
        "reference on the part and feeds the normal ahead to the controller, and the start is aligned with it "
        "(tactex.tasks.explored_surface); '' plans in the tangent plane at the tool", option="replan-from")
    replan_lead_s: float = param(0.25, "how far ahead along the reference the re-plan's normal is taken [s]")
    replan_learn_gain: float = param(
        0.8, "share of the first pass's force and in-plane errors a re-plan corrects in advance at the same policy "
        "time (one step of iterative learning control, tactex.tasks.pass_learning); 0: the surface only [-]")
    policy_waits_for_alignment: bool = param(
        False, "hold the policy at its start, pressing with its first set point, until VA-UFIC has aligned "
        "(ρ_align = 1; at most align_wait_max_s), then run it whole, the run that much longer: a policy that moves "
        "while the controller is still compliant drags a tool it cannot yet carry round a strongly curved part "
        "(the cup's wall) until it slips; VA-UFIC only")
    align_wait_max_s: float = param(12.0, "longest the policy waits for the alignment [s]")
    compliant_below: float = param(
        VaUficParams().compliant_below, "ρ_align under which VA-UFIC counts as compliant: it feeds the tool's position "
        "back as the desired one and re-orients the tool to the camera's normal (VaUficParams.compliant_below); above "
        "it the variable stiffness ρ_align·K_max holds the tool, which on a convex part (the cup's wall) is too weak "
        "for the pull of a tilted tool's pressing force until ρ_align is a good share of 1 [-]")
    passes: int = param(
        1, "1: the policy once; 2: once, then once more planned on the surface the first pass explored (as "
        "--replan-from it; the result is the second pass's, with the first's figures in its metrics' replan)")

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.baseline not in WIPE_BASELINES:
            raise ConfigError(f"unknown baseline '{self.baseline}'; valid: cartesian (or none)")
        if self.policy_waits_for_alignment and self.baseline:
            raise ConfigError(f"--policy-waits-for-alignment holds the policy until VA-UFIC aligns; the "
                              f"{self.baseline} baseline has no alignment to wait for")
        if not (np.isfinite(self.compliant_below) and 0.0 <= self.compliant_below < 1.0):
            raise ConfigError(f"compliant_below must be a share of ρ_align in [0, 1), got {self.compliant_below!r}")
        for name in ("duration_s", "force_n", "camera_rate_hz", "align_wait_max_s"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be a positive number, got {getattr(self, name)!r}")
        check_force_set_point("force_n", self.force_n)
        for name in ("amplitude_m", "drift_m_s", "start_height_m", "omega_rad_s", "contact_threshold_n",
                     "approach_depth_m"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v >= 0):
                raise ConfigError(f"{name} must be a finite number ≥ 0, got {getattr(self, name)!r}")
        for name in ("start_y_m", "start_tilt_deg"):
            v = float(getattr(self, name))
            if not np.isfinite(v):
                raise ConfigError(f"{name} must be a finite number, got {getattr(self, name)!r}")
        if abs(self.start_tilt_deg) >= 60.0:
            raise ConfigError(f"start_tilt_deg must lie within ±60° (the camera must still see the surface), "
                              f"got {self.start_tilt_deg}")
        self.friction_params()  # validates friction_gain and friction_cutoff_hz
        for name in ("policy_max_speed_m_s", "policy_max_accel_m_s2"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be a positive number, got {getattr(self, name)!r}")
        if not isinstance(self.replan_from, str):
            raise ConfigError(f"replan_from must be the path of a wipe's run folder, got {self.replan_from!r:.40}")
        if self.passes not in (1, 2) or isinstance(self.passes, bool):
            raise ConfigError(f"passes must be 1 or 2, got {self.passes!r}")
        if self.passes == 2 and (self.replan_from or self.baseline):
            raise ConfigError("passes = 2 re-plans the second pass on the first's surface for VA-UFIC: drop "
                              + ("--replan-from (the first pass is this run's own)" if self.replan_from
                                 else "--baseline"))
        if self.replan_from:
            _check_replan_from(self)
        v = float(self.replan_lead_s)
        if not (np.isfinite(v) and 0.0 <= v <= 2.0):
            raise ConfigError(f"replan_lead_s must lie in [0, 2] s, got {self.replan_lead_s!r}")
        v = float(self.replan_learn_gain)
        if not (np.isfinite(v) and 0.0 <= v <= 1.0):
            raise ConfigError(f"replan_learn_gain must lie in [0, 1], got {self.replan_learn_gain!r}")
        if not isinstance(self.policy, str):
            raise ConfigError(f"policy must be the path of a .toml policy file, got {self.policy!r:.40}")
        if self.policy:  # a bad file is refused before anything starts
            loaded = wipe_policy(self)
            try:
                check_wipe_policy(self, loaded)
            except ConfigError as exc:
                raise PolicyFileError(f"policy file '{self.policy}': {exc}") from None
        else:  # the §III sinusoid: the limits a policy file has
            check_sinusoid(self)

    def friction_params(self) -> FrictionCompensatorParams:
        return FrictionCompensatorParams(gain=self.friction_gain, cutoff_hz=self.friction_cutoff_hz)

    def scene(self) -> SceneConfig:
        return super().scene(camera_rate_hz=self.camera_rate_hz)


def _check_replan_from(cfg: WipeConfig) -> None:
    """The re-plan's run folder exists, holds an explored surface, and wiped the same part."""
    run = Path(cfg.replan_from).expanduser()
    problem = ExploredSurface.folder_problem(run)
    if problem:
        raise ConfigError(problem)
    if cfg.baseline:
        raise ConfigError(f"--replan-from feeds VA-UFIC's alignment; the {cfg.baseline} baseline has none: drop "
                          "--baseline")
    first = ExploredSurface.run_object(run)
    if first is not None and first != cfg.object_name:
        raise ConfigError(f"--replan-from {run} explored '{first}', this wipe is on '{cfg.object_name}': re-plan "
                          "from a wipe of the same part")


@dataclass
class WipeResult:
    """What a wiping run produced (see the module docstring)."""

    config: WipeConfig
    metrics: dict[str, Any]
    series: dict[str, np.ndarray]
    profile: dict[str, np.ndarray]
    explored: SurfaceCloud | None
    explored_curvature: np.ndarray
    events: list[Any] = field(default_factory=list)


def _errors(err: np.ndarray) -> tuple[list[float], list[float]]:
    if err.size == 0:
        return [float("nan")] * 3, [float("nan")] * 3
    return np.mean(np.abs(err), axis=0).tolist(), np.sqrt(np.mean(err**2, axis=0)).tolist()


def _exploration_accuracy(explored: SurfaceCloud, surface, obj_pos: np.ndarray, obj_rot: np.ndarray) -> dict:
    """How well the explored surface matches the true one (ground truth the robot never saw):
    the angle between each explored normal and the true normal under it [deg], the TCP depth below
    the surface (the sponge compression) [m], and the span of true surface inclinations the contact
    path traversed [deg] — the curvature actually explored."""
    pts_obj = (explored.points - obj_pos) @ obj_rot
    foot, n_true_obj = surface.project(pts_obj)
    n_true = n_true_obj @ obj_rot.T
    cos = np.clip(np.sum(explored.normals * n_true, axis=1), -1.0, 1.0)
    err_deg = np.rad2deg(np.arccos(cos))
    depth = np.sum((foot - pts_obj) * n_true_obj, axis=1)
    incline = np.rad2deg(np.arccos(np.clip(n_true[:, 2], -1.0, 1.0)))
    return {
        "explored_points": len(explored),
        "explored_normal_error_deg_median": float(np.median(err_deg)),
        "explored_normal_error_deg_p95": float(np.percentile(err_deg, 95)),
        "explored_depth_below_surface_m_median": float(np.median(depth)),
        "explored_inclination_span_deg": float(incline.max() - incline.min()),
    }



class _Approach:
    """The policy's approach to a surface it has not touched yet: it gives up once the TCP is
    ``approach_depth_m`` past where the surface should be (``start_height_m`` below the start, along the
    start tool axis ``axis``), still without contact. A force-controlled tool pushing through free space
    accelerates until its force tank is dry, and on a real robot nothing stops it but a joint limit."""

    def __init__(self, cfg: WipeConfig, p_start: np.ndarray, axis: np.ndarray) -> None:
        self.cfg, self.p_start, self.axis = cfg, p_start, np.asarray(axis, dtype=float)
        self.limit_m = cfg.start_height_m + cfg.approach_depth_m
        self.searching = True
        self.depth_m = 0.0

    def gave_up(self, state) -> bool:
        """False, and the search ends, on contact; True once the TCP is past the limit without it."""
        if state.wrench_tool[2] >= self.cfg.contact_threshold_n:
            self.searching = False
            return False
        self.depth_m = float((state.ee_position - self.p_start) @ self.axis)
        return self.depth_m > self.limit_m

    def message(self) -> str:
        cfg = self.cfg
        return (f"no contact within {1e3 * self.limit_m:.0f} mm of the start along the tool axis ("
                f"{1e3 * cfg.start_height_m:.0f} mm to where the surface should be + {1e3 * cfg.approach_depth_m:.0f} "
                f"mm, approach_depth_m): the surface is not where expected (object moved, or not there?)")


class _WipeLog:
    """The wipe's per-tick bookkeeping: force and motion errors, tank energies, contact points, the
    recorded series.

    A tick's figures need the state its torque produced, so each tick is completed one tick later,
    in :meth:`sent` while the next command executes (``ControlLoop.tick``'s ``after_send``): on a real
    robot none of this runs between reading a state and answering it. What the controller holds
    after its torque (telemetry, the position offset, the friction feed-forward) is noted in the same
    call, before the next torque overwrites it. Set :attr:`pos_ref` and :attr:`estimate` before each
    tick.
    """

    def __init__(self, cfg: WipeConfig, inner, compensator: FrictionCompensator | None, dt: float,
                 rec: Recorder, bar: Progress, t0: float, obj_pos: np.ndarray, obj_rot: np.ndarray) -> None:
        self.cfg, self.inner, self.compensator, self.dt = cfg, inner, compensator, dt
        self._obj_pos, self._obj_rot = obj_pos, obj_rot
        self.rec, self.bar, self.t0 = rec, bar, t0
        self.va = isinstance(inner, VaUficController)
        self.pos_ref = np.zeros(3)
        self.estimate: SurfaceEstimate | None = None
        # the policy's set point [N], segment and in-plane offset (u, v) [m] of the tick about to be sent
        self.force_set_n, self.segment, self.uv = cfg.force_n, 0, (0.0, 0.0)
        self.force_sets: list[float] = []
        self.segments: list[int] = []
        self.aligned_force_sets: list[float] = []
        self.aligned_segments: list[int] = []
        self.n_ticks = self.n_contact = self.first_contact_tick = 0
        self.first_contact: float | None = None
        self.t_aligned: float | None = None
        self.comp_energy = 0.0
        self.max_force_norm = 0.0  # [N] the measured force's magnitude, every tick (what the safety layer judges)
        self.forces: list[float] = []
        self.errors_world: list[np.ndarray] = []
        self.aligned_errors: list[np.ndarray] = []
        self.aligned_errors_tool: list[np.ndarray] = []
        # the same with the part along the tool axis removed: the directions the policy gives a position in
        self.aligned_errors_tangent: list[np.ndarray] = []
        self.aligned_forces: list[float] = []
        self.contact_pts: list[np.ndarray] = []
        self.contact_normals: list[np.ndarray] = []
        self.contact_curv: list[float] = []
        self.tank_i: list[float] = []
        self.tank_f: list[float] = []
        self._pending: tuple | None = None
        self.live: _WipeLive | None = None  # the live page's part (--view)

    def sent(self, state_ctrl) -> None:
        """The torque computed from ``state_ctrl`` is on its way: complete the previous tick (whose
        result ``state_ctrl`` is), then note this tick's controller figures."""
        if self._pending is not None:
            self._complete(state_ctrl)
        tel = self.inner.tick_telemetry() if self.cfg.baseline == "" else {}
        comp_last = self.inner.port_wrench_last() if self.compensator is not None else None  # (6,) or None
        if comp_last is not None and "tank_i_valve" in tel:
            # power the compensation delivered through the impedance tank's port (σ_i scales it)
            self.comp_energy += self.dt * tel["tank_i_valve"] * float(
                (state_ctrl.ee_rotation.T @ state_ctrl.ee_twist[:3]) @ comp_last[:3])
        offset = self.inner.position_offset if self.va else np.zeros(3)
        friction = comp_last[:2] if comp_last is not None else np.zeros(2)
        self._pending = (state_ctrl, self.pos_ref + offset, tel, friction, self.estimate,
                         (self.force_set_n, self.segment, self.uv))

    def stopped_at(self, state) -> None:
        """A run that stopped before any tick came back (on the way to the start pose, or on the policy's first
        command): the state where the robot stopped is its one recorded row (no controller figures), so the run
        folder holds every series a report reads."""
        self._pending = (state, state.ee_position.copy(), {}, np.zeros(2), None,
                         (self.force_set_n, self.segment, self.uv))
        self._complete(state)
        self._pending = None

    def finish(self, state) -> None:
        """After the loop: complete the last tick sent, if the state it produced arrived; a run with no tick
        recorded gets :meth:`stopped_at`."""
        if self._pending is not None and state is not self._pending[0]:
            self._complete(state)
        self._pending = None
        if self.n_ticks == 0:
            self.stopped_at(state)

    def _complete(self, state) -> None:
        cfg = self.cfg
        _, desired, tel, friction, estimate, (f_set, segment, uv) = self._pending
        self.n_ticks += 1
        t = state.t - self.t0
        w = state.wrench_tool
        fz = float(w[2])
        self.max_force_norm = max(self.max_force_norm, math.sqrt(float(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])))
        in_contact = fz >= cfg.contact_threshold_n
        # x − x_d in the base frame, as the paper's Fig. 3b and its per-axis MAE/RMSE (§IV); the
        # tool-frame error is kept beside it
        err_world = state.ee_position - desired
        err_tool = state.ee_rotation.T @ err_world
        if "tank_i_energy_j" in tel:
            self.tank_i.append(tel["tank_i_energy_j"])
            self.tank_f.append(tel["tank_f_energy_j"])
        if in_contact:
            self.n_contact += 1
            if self.first_contact is None:
                self.first_contact, self.first_contact_tick = t, self.n_ticks
            self.forces.append(fz)
            self.force_sets.append(f_set)
            self.segments.append(segment)
            self.errors_world.append(err_world)
            if cfg.baseline or tel.get("rho_align", 0.0) >= ALIGNED_RHO:
                self.t_aligned = t if self.t_aligned is None else self.t_aligned
                self.aligned_errors.append(err_world)
                self.aligned_errors_tool.append(err_tool)
                axis = state.ee_rotation[:, 2]
                self.aligned_errors_tangent.append(err_world - float(err_world @ axis) * axis)
                self.aligned_forces.append(fz)
                self.aligned_force_sets.append(f_set)
                self.aligned_segments.append(segment)
            if self.n_contact % 10 == 0:
                self.contact_pts.append(state.ee_position.copy())
                if estimate is not None and estimate.valid:
                    self.contact_normals.append(np.asarray(estimate.normal_world, dtype=float))
                    self.contact_curv.append(float(estimate.curvature))
                else:
                    self.contact_normals.append(-state.ee_rotation[:, 2])
                    self.contact_curv.append(float("nan"))
        if self.rec.due():
            self.rec.add(
                t=t, q=state.q, tcp=state.ee_position, desired=desired, motion_error_world=err_world,
                motion_error_tool=err_tool, force_z_n=fz, wrench_tool=state.wrench_tool,
                friction_comp_tool=friction, force_set_n=f_set, segment=float(segment), policy_uv_m=uv,
                in_contact=float(in_contact),
                rho_align=tel.get("rho_align", np.nan), rho_frc=tel.get("rho_frc", np.nan),
                tank_i_energy_j=tel.get("tank_i_energy_j", np.nan), tank_f_energy_j=tel.get("tank_f_energy_j", np.nan),
                tcp_object=self._obj_rot.T @ (state.ee_position - self._obj_pos),
                theta_rad=estimate.theta_rad if estimate is not None and estimate.valid else np.nan,
            )
        else:
            self.rec.add()
        if self.n_ticks % 250 == 0:
            self.bar.update(t, force=fz, contact=self.n_contact / self.n_ticks)
        if self.live is not None and self.live.feed.due():
            self.live.show(self, state, t, fz, in_contact)


class _WipeLive:
    """What the wipe shows on its live page (``--view``, :class:`~tactex.tasks.live_feed.LiveFeed`): the object's
    surface (red where the pad has not been, green where it has), the TCP, the tool, the force against its set
    point and where the time went. Called from :meth:`_WipeLog._complete`, while a command executes."""

    def __init__(self, feed, surface, obj_pos: np.ndarray, obj_rot: np.ndarray, pad_radius_m: float,
                 run_s: float) -> None:
        from scipy.spatial import cKDTree

        pts = obj_pos + surface.sample(LIVE_SPACING_M).points @ obj_rot.T
        self.feed, self.radius, self.run_s = feed, float(pad_radius_m), float(run_s)
        self.left = np.ones(len(pts))  # 1 where the pad has not been yet
        self.tree = cKDTree(pts)
        feed.set_cloud(pts, None, np.ones(len(pts)))

    def show(self, log: _WipeLog, state, t: float, fz: float, in_contact: bool) -> None:
        if in_contact:
            self.left[self.tree.query_ball_point(state.ee_position, self.radius)] = 0.0
        approach = log.first_contact if log.first_contact is not None else t
        contact = log.n_contact * log.dt
        self.feed.publish(
            t, phase="approach" if log.first_contact is None else "wipe", force_n=fz, set_point_n=log.force_set_n,
            tcp_m=state.ee_position, world_R_tool=state.ee_rotation, progress=t / self.run_s, field=self.left,
            breakdown_s={"approach": approach, "contact": contact, "no_contact_after_touch": max(0.0, t - approach -
                                                                                               contact)},
            figures={"surface touched [-]": 1.0 - float(self.left.mean())})


def run_wipe(config: WipeConfig | None = None, *, progress: bool = True,
             robot: RealRobotParams | None = None, policy: ForceMotionPolicy | None = None,
             live=None) -> WipeResult:
    """Run the wiping exploration in simulation, or on a real Franka (``robot``); returns metrics, series
    and the explored surface.

    On a real robot the object's registry shape at ``object_position`` places the start above the
    surface (the controller never uses it), and a libfranka error, a lost sensor or Ctrl-C ends the
    policy early: torque control stops and the result holds what was recorded, with ``aborted``
    naming the cause in its metrics.

    ``policy`` (a :class:`~tactex.tasks.policies.ForceMotionPolicy`) replaces the config's policy; it is
    checked against the wipe's limits before anything starts. ``live``: a
    :class:`~tactex.tasks.live_feed.LiveFeed` the run shows itself on (``--view``), or None."""
    cfg = config or WipeConfig()
    wall0 = time.perf_counter()
    the_policy = wipe_policy(cfg, policy)
    if policy is not None:
        check_policy_call_time(check_wipe_policy(cfg, the_policy), robot is not None)
    explored = ExploredSurface.from_run(Path(cfg.replan_from).expanduser()) if cfg.replan_from else None
    learned = (PassCorrection.from_run(Path(cfg.replan_from).expanduser(), cfg.replan_learn_gain)
               if cfg.replan_from else None)
    if cfg.passes == 2:
        first = run_wipe(replace(cfg, passes=1), progress=progress, robot=robot, policy=policy, live=live)
        if first.metrics.get("aborted") or first.explored is None:
            return first  # stopped, or never touched: nothing to re-plan on, and the first pass says why
        explored = ExploredSurface(first.explored.points, first.explored.normals, first.explored_curvature,
                                   first.explored.spacing, source="the first pass", metrics=first.metrics)
        learned = PassCorrection.from_series(first.series, cfg.replan_learn_gain, "the first pass")
    check_estimate_camera(robot)
    scene_cfg = cfg.scene()
    backend = open_backend(scene_cfg, robot, announce=progress)
    try:
        # the vision process starts before the arm moves: nothing slow may run once torque control is on
        # the TCP is the uncompressed pad tip: in contact the surface lies up to the pad's maximum
        # compression behind it, so the region of interest must start that far back
        compression = scene_cfg.tool.max_compression_m
        estimator_cfg = SurfaceEstimatorConfig(max_grid_cells=2000, axis_start_m=-(compression + 0.005))
        vision = open_vision(backend, estimator_cfg, scene_cfg, robot, cfg.camera_rate_hz)
        try:
            return _run_wipe(cfg, backend, vision, scene_cfg, robot, progress, wall0, the_policy, live, explored,
                             learned)
        finally:
            vision.close()
    finally:
        backend.close()


def _to_start(loop: ControlLoop, p_start: np.ndarray, r_start: np.ndarray, scene_cfg: SceneConfig,
              robot: RealRobotParams | None) -> tuple[str, str]:
    """Move to the policy's start pose [m, rotation matrix], clear of the part (:func:`move_clear_of_part`):
    ``""`` when there, else why the robot stopped on the way (torque control ended, as :func:`end_on_robot`
    leaves it), and the way it took. In simulation an error of ours is raised."""
    obj_pos, obj_rot = scene_cfg.object_pose()
    part = PartShape(scene_cfg.sim_object.surface, obj_pos, obj_rot, scene_cfg.sim_object.base_thickness_m,
                     scene_cfg.object_position)
    try:
        return "", move_clear_of_part(loop, p_start, r_start, part, scene_cfg.tool)
    except ROBOT_STOPS as exc:
        return stop_reason(exc), ""
    except TactexError as exc:
        if robot is None:
            raise
        return end_on_robot(loop, exc), ""


#: The first pass's figures a re-planned wipe's metrics repeat beside its own.
FIRST_PASS_KEYS = ("force_mae_n", "force_within_20pct_fraction", "motion_mae_m", "motion_mae_tool_m",
                   "motion_mae_tangent_m", "motion_mae_all_contact_m", "aligned_at_s", "max_force_over_set_point",
                   "torque_rate_clip_ticks")


def _motion_figures(log: _WipeLog) -> dict[str, list[float]]:
    """The motion errors' MAE and RMSE per axis [m]: in the base frame and the tool's while aligned, over all
    contact, and per base axis without the part along the tool axis (where force control, not the policy, sets
    the position, and VA-UFIC keeps the desired position inside the surface, eq. 30)."""
    out = {}
    for key, errors in (("", log.aligned_errors), ("_tool", log.aligned_errors_tool),
                        ("_tangent", log.aligned_errors_tangent), ("_all_contact", log.errors_world)):
        out[f"motion_mae{key}_m"], out[f"motion_rmse{key}_m"] = _errors(np.asarray(errors).reshape(-1, 3))
    return out


def _replan_metrics(cfg: WipeConfig, explored: ExploredSurface, refs: WipeReferences,
                    learned: PassCorrection | None) -> dict:
    """What the re-plan used (the first pass's folder, or "the first pass" of this run's two, its contact points,
    the share of references it placed, what it learned from the first pass's errors) and the first pass's
    figures, for the side-by-side comparison."""
    first = {k: explored.metrics.get(k) for k in FIRST_PASS_KEYS} if explored.metrics else {}
    return {"from": cfg.replan_from or explored.source, "explored_points": len(explored),
            "on_explored_fraction": refs.on_explored / max(refs.advances, 1), "first_pass": first,
            "learned": learned.summary() if learned is not None else None}


def _profile(cfg: WipeConfig, surface) -> np.ndarray:
    """(256, 3) [m] the surface's profile along y at x = 0, in the object frame (the report's cut)."""
    ys = np.linspace(-0.255, 0.255, 256) if cfg.object_name == "sine_panel" else np.linspace(-0.1, 0.1, 256)
    return surface.project(np.column_stack([np.zeros_like(ys), ys, np.zeros_like(ys)]))[0]


def _controllers(cfg: WipeConfig) -> tuple[Any, FrictionCompensator | None]:
    """The wipe's controller (VA-UFIC, or the Cartesian impedance baseline) and its friction feed-forward."""
    if cfg.baseline == "cartesian":
        return CartesianImpedanceController(), None
    compensator = FrictionCompensator(cfg.friction_params()) if cfg.friction_compensation else None
    return VaUficController(VaUficParams(tanks_enabled=cfg.tanks_enabled, compliant_below=cfg.compliant_below),
                            port_feedforward=compensator), compensator


def _references(cfg: WipeConfig, vision: SurfaceVision, p_start: np.ndarray, r_start: np.ndarray,
                the_policy: ForceMotionPolicy, explored: ExploredSurface | None, learned: PassCorrection | None,
                inner) -> WipeReferences:
    """The policy as the run follows it, held to its limits at every tick (:class:`PolicyGuard`: a fault of its own
    stops the run, its data kept), with the controller's offset and alignment where VA-UFIC has them."""
    return WipeReferences(cfg, vision, p_start, r_start, PolicyGuard(the_policy, wipe_limits(cfg)), explored,
                          (lambda: inner.position_offset) if isinstance(inner, VaUficController) else None, learned,
                          lambda: inner.tick_telemetry().get("rho_align", 0.0) >= ALIGNED_RHO)


def _run_wipe(cfg: WipeConfig, backend, vision: SurfaceVision, scene_cfg, robot: RealRobotParams | None,
              progress: bool, wall0: float, the_policy: ForceMotionPolicy, live=None,
              explored: ExploredSurface | None = None, learned: PassCorrection | None = None) -> WipeResult:
    loop = ControlLoop(backend)
    run_s = min(cfg.duration_s, the_policy.duration_s)
    surface = scene_cfg.sim_object.surface
    obj_pos, obj_rot = scene_cfg.object_pose()

    # start: above the surface at (0, start_y), tilted (not aligned), out of contact; a re-plan aligns the tool
    # with the surface the first pass explored below it
    p_start, r_start = wipe_start_pose(cfg, surface, obj_pos, obj_rot)
    if explored is not None:
        r_start = desired_rotation_from_normal(r_start, -explored.near(p_start).normal)
    # the live page's surface is made before torque control starts (sampling it takes milliseconds)
    shown = (_WipeLive(live, surface, obj_pos, obj_rot, scene_cfg.tool.pad_radius_m, run_s) if live is not None
             else None)
    inner, compensator = _controllers(cfg)
    # made before the arm moves: the policy's first point (and a fault there) comes before any motion
    policy = _references(cfg, vision, p_start, r_start, the_policy, explored, learned, inner)
    # a stop on the way to the start ends the run like one during the policy: the robot's data are kept
    aborted, transit = _to_start(loop, p_start, r_start, scene_cfg, robot)
    loop.use(NullspacePosture(inner, q_posture=loop.state.q.copy()))
    rec = Recorder(every=max(1, round(1.0 / (cfg.record_hz * backend.dt))))
    bar = Progress(run_s, f"wipe {cfg.baseline or 'tactex'}", enabled=progress)
    t0 = loop.t
    log = _WipeLog(cfg, inner, compensator, backend.dt, rec, bar, t0, obj_pos, obj_rot)
    log.live = shown
    approach = _Approach(cfg, p_start, r_start[:, 2])

    def advance(state, tau_t: float) -> None:  # the next tick's reference, at run time tau_t [s]
        # a policy's fault pauses the loop first: a real robot holds itself while the run's data is written
        try:
            policy.advance(state, tau_t)
        except PolicyFault:
            loop.pause()
            raise
        log.pos_ref, log.estimate = policy.pos_ref, policy.estimate
        log.force_set_n, log.segment, log.uv = policy.force_set_n, policy.segment, policy.uv

    def after_send(state_ctrl) -> None:  # while the robot executes the tick's command
        if approach.searching and approach.gave_up(state_ctrl):
            loop.pause()  # a real robot holds itself while the run's data is written
            raise SurfaceNotFound(approach.message())
        vision.publish(state_ctrl)
        log.sent(state_ctrl)
        # the next tick's reference, from this state: nothing of it is left between the next state
        # and its command
        advance(state_ctrl, state_ctrl.t + backend.dt - t0)

    try:
        if transit not in ("", "direct"):
            bar.note(f"to the start: {transit}")
        if aborted:  # log.finish keeps the state where the robot stopped as the run's one row
            bar.note(f"stopped on the way to the start pose: {aborted}")
        else:
            advance(loop.state, loop.t - t0)
        while not aborted and loop.t - t0 < run_s + policy.waited_s - 1e-9:
            loop.tick(policy.reference, after_send=after_send)
    except ROBOT_STOPS as exc:
        # the robot has stopped (libfranka ends torque control on its errors; close() on ours): keep the data
        aborted = stop_reason(exc)
        bar.note(f"stopped early: {aborted}")
    except TactexError as exc:
        if robot is None:  # in simulation an error of ours is raised; on a robot the run keeps its data
            raise
        aborted = end_on_robot(loop, exc)
        bar.note(f"stopped early: {aborted}")
    log.finish(loop.state)
    n_ticks, n_contact = log.n_ticks, log.n_contact
    forces, first_contact, t_aligned = log.forces, log.first_contact, log.t_aligned
    bar.close(f"contact {100 * n_contact / max(n_ticks, 1):.0f} % of the time")
    t_end = loop.t
    if not aborted and loop.state.wrench_tool[2] >= cfg.contact_threshold_n:
        # lift off, so the next run (or a sensor tare) starts out of contact; not part of the policy
        try:
            loop.retract(LIFT_OFF_M, duration_s=0.4)
        except ROBOT_STOPS as exc:
            aborted = f"during the lift-off: {stop_reason(exc)}"

    f_set = np.asarray(log.force_sets)
    f_err = np.asarray(forces) - f_set
    f_err_al = np.asarray(log.aligned_forces) - np.asarray(log.aligned_force_sets)
    after_first = n_ticks - log.first_contact_tick + 1 if first_contact is not None else 0  # ticks from the touch on
    va_params = VaUficParams()
    metrics: dict[str, Any] = {
        "force_mae_n": float(np.mean(np.abs(f_err))) if f_err.size else float("nan"),
        # share of the contact ticks whose force is within ±20 % of the set point (the clean reports the same)
        "force_within_20pct_fraction": float(np.mean(np.abs(f_err) <= 0.2 * f_set)) if f_err.size else 0.0,
        "force_rmse_n": float(np.sqrt(np.mean(f_err**2))) if f_err.size else float("nan"),
        **_motion_figures(log),
        "force_mae_aligned_n": float(np.mean(np.abs(f_err_al))) if f_err_al.size else float("nan"),
        "force_rmse_aligned_n": float(np.sqrt(np.mean(f_err_al**2))) if f_err_al.size else float("nan"),
        "aligned_at_s": t_aligned,
        # [s] how long the policy waited for the alignment before it started (policy_waits_for_alignment)
        "policy_waited_s": policy.waited_s,
        "tank_impedance_energy_j": {"min": min(log.tank_i, default=float("nan")),
                                    "max": max(log.tank_i, default=float("nan"))},
        "tank_force_energy_j": {"min": min(log.tank_f, default=float("nan")),
                                "max": max(log.tank_f, default=float("nan"))},
        "tank_impedance_limits_j": [va_params.tank_i_lower, va_params.tank_i_upper],
        "tank_force_limits_j": [va_params.tank_f_lower, va_params.tank_f_upper],
        "contact_fraction": n_contact / max(n_ticks, 1),
        "contact_fraction_after_first_contact": n_contact / max(after_first, 1),
        "first_contact_s": first_contact,
        # time spent exploring in contact: from the first touch to the end of the policy
        "explore_time_s": (run_s + policy.waited_s - first_contact) if first_contact is not None else None,
        "max_force_n": float(max(forces, default=0.0)),
        # [N] the peak magnitude of the measured force over every tick of the run (normal and friction, in contact
        # or not; the move to the start and the lift-off included, which the safety layer watches as it does the
        # policy)
        "max_force_norm_n": float(max(log.max_force_norm, loop.safety.peak_force_n)),
        # the highest contact force as a multiple of the policy's set point at its tick
        "max_force_over_set_point": float(np.max(np.asarray(forces) / f_set)) if f_set.size else float("nan"),
        "policy": {"file": cfg.policy, "duration_s": run_s, "segments": policy_segments(the_policy, run_s, log),
                   # [s] the policy's own length (inf: the sinusoid, which the run's duration ends)
                   "own_duration_s": float(the_policy.duration_s)},
        "friction_compensation": compensator is not None,
        "friction_compensation_energy_j": log.comp_energy if compensator is not None else float("nan"),
        "vision_valid_fraction": policy.estimates_valid / max(policy.estimates_total, 1),
        "vision_estimates": policy.estimates_total,
        "sim_time_s": t_end,
        "wall_time_s": time.perf_counter() - wall0,
        "controller": inner.name,
        "baseline": cfg.baseline or "va_ufic",
        "safety_events": len(loop.safety.events),
        # per kind: events (force_limit: one per retreat), ticks for nan_wrench and the torque and rate limits
        "safety_counts": dict(loop.safety.counts),
        "safety_limits": {"max_contact_force_n": loop.safety.limits.max_contact_force,
                          "tau_rate_max_n_m_s": loop.safety.limits.tau_rate_max},
        # every tick the torque-rate limiter changed the command (an event marks only where a run of them starts)
        "torque_rate_clip_ticks": loop.safety.counts.get("torque_rate_limit", 0),
        "robot": "franka" if robot is not None else "sim",
        "aborted": aborted,
        "partial": bool(aborted),  # the program stopped before its end (Ctrl-C or the robot): aborted says why
        "start_transit": transit,  # "direct", or how the move to the start went round the part
        **vision.stats(),
    }
    if explored is not None:
        metrics["replan"] = _replan_metrics(cfg, explored, policy, learned)
    if robot is not None:
        metrics.update(backend.loop_metrics())
    prof_pts = _profile(cfg, surface)
    found, curv = _explored_cloud(log)
    if found is not None:
        metrics.update(_exploration_accuracy(found, surface, obj_pos, obj_rot))
    return WipeResult(
        config=cfg, metrics=metrics, series=log.rec.arrays(), profile={"y_m": prof_pts[:, 1], "z_m": prof_pts[:, 2]},
        explored=found, explored_curvature=curv, events=list(loop.safety.events),
    )


def _explored_cloud(log: _WipeLog) -> tuple[SurfaceCloud | None, np.ndarray]:
    """The contact points of a run, one per 3 mm voxel, with their normals, and their curvatures l_s (None and
    none with fewer than two)."""
    if len(log.contact_pts) < 2:
        return None, np.zeros(0)
    pts = np.asarray(log.contact_pts)
    inv, counts = voxel_indices(pts, 0.003)
    first = np.full(counts.size, -1)
    first[inv[::-1]] = np.arange(inv.size)[::-1]  # the first contact point in each voxel
    cloud = SurfaceCloud(points=pts[first], normals=np.asarray(log.contact_normals)[first], spacing=0.003)
    return cloud, np.asarray(log.contact_curv)[first]
