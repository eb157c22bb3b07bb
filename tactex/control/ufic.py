"""Unified force-impedance control, VA-UFIC §II-A (eq. 1–13).

f = −K_C(t)·x̃ − D_C·ẋ (compliance, eq. 7–9) plus the PI force controller rotated into the base
frame (eq. 10–12), τ = Jᵀ(f_i + f_f) (eq. 13); gravity is compensated by the robot.

Sign of the force error: eq. 12 prints f̃ = f_ext − f_d, which is positive feedback when f_ext is
the contact force the robot applies (our ``wrench_tool``, f_z > 0 when pressing). We use
f̃ = f_d − f_meas, the negative-feedback reading, so the PI drives f_meas to f_d.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tactex.config import param
from tactex.control import joint_kernels
from tactex.control.controller import Controller
from tactex.control.damping import latency_shaped_torque
from tactex.control.references import PoseForceReference
from tactex.control.state import RobotState
from tactex.errors import ConfigError, ControllerFault
from tactex.geometry.so3 import rotation_error_world, rotation_error_world_rows

__all__ = ["UficController", "UficParams"]


@dataclass(frozen=True)
class UficParams:
    """Defaults from VA-UFIC Table I (K_max, damping ratio, K_p, K_i)."""

    stiffness_max: tuple[float, float, float, float, float, float] = param(
        (1000.0, 1000.0, 10.0, 200.0, 200.0, 200.0), "K_max, tool frame [N/m ×3, N·m/rad ×3]")
    damping_ratio: tuple[float, float, float, float, float, float] = param(
        (0.7, 0.7, 0.7, 1.0, 1.0, 1.0), "damping coefficient ζ per tool axis [-]")
    apparent_mass: tuple[float, float, float, float, float, float] = param(
        (3.0, 3.0, 3.0, 0.1, 0.1, 0.1), "nominal Cartesian inertia used to turn ζ into D_C [kg ×3, kg·m² ×3]")
    damping_reference_stiffness: tuple[float, float, float, float, float, float] = param(
        (1000.0, 1000.0, 1000.0, 200.0, 200.0, 200.0),
        "stiffness the damping is designed for, D = 2ζ√(m·k) [N/m, N·m/rad]; K_max,z = 10 N/m itself would leave "
        "the pressing direction almost undamped",
    )
    approach_damping_z: float = param(
        250.0,
        "damping along the tool axis while out of contact (|f_z| below contact_threshold_n) [N·s/m]: keeps the "
        "free approach under the force command near 0.1 m/s so the impact stays under 2× the set point, without "
        "slowing the force loop in contact",
    )
    contact_threshold_n: float = param(1.0, "measured pressing force above which the tool counts as in contact [N]")
    kp: float = param(0.6, "force PI proportional gain K_p [-]")
    ki: float = param(0.3, "force PI integral gain K_i [1/s]")
    force_axes: tuple[float, float, float, float, float, float] = param(
        (0.0, 0.0, 1.0, 0.0, 0.0, 0.0),
        "tool-frame wrench components whose force error is fed back (1) or not (0); f_d itself is fed forward "
        "on every axis (eq. 11). The paper's K_p, K_i are 6×6 identities, which with f_d = 0 tangentially "
        "would integrate friction against the stiffness",
    )
    integral_limit: float = param(30.0, "bound on |K_i ∫f̃| per component [N or N·m]")
    stiffness_scale: float = param(1.0, "translational stiffness scale ρ (time-varying K_C(t) = ρ·K_max,t) [-]")
    dt: float = param(1e-3, "nominal control period [s]")
    wrench_cutoff_hz: float = param(
        20.0, "first-order low-pass of the measured wrench the controller uses [Hz]: a sliding contact's "
        "stick-slip shows on the F/T as one-tick spikes, which K_p would pass straight to the joints")
    latency_horizon_ticks: float = param(
        3.0, "horizon h of the implicit impedance in control periods [-]: τ = M (M + h·B + h²·K)⁻¹ Jᵀf with "
        "D_C and K_max mapped to the joints (tactex.control.damping); 0: τ = Jᵀf as in eq. 13. Explicit, the "
        "rotational damping (2·√(0.1·200) ≈ 9 N·m·s/rad) on the light wrist rotation is unstable behind a "
        "one-tick command delay")
    damping_switch_s: float = param(
        0.02, "time constant of the change between the free and the contact damping along the tool axis [s]: "
        "switched in one tick at touch-down, the step of (D_free − D_contact)·v hit the torque-rate limit")

    def __post_init__(self) -> None:
        for name in ("stiffness_max", "damping_ratio", "apparent_mass", "damping_reference_stiffness", "force_axes"):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != (6,) or not np.isfinite(v).all() or (v < 0).any():
                raise ConfigError(f"UficParams.{name} must be 6 finite values ≥ 0, got {getattr(self, name)!r}")
        scalars = ("kp", "ki", "integral_limit", "dt", "stiffness_scale", "approach_damping_z", "contact_threshold_n",
                   "latency_horizon_ticks",
                   "wrench_cutoff_hz", "damping_switch_s")
        for name in scalars:
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0 or (name in ("dt", "wrench_cutoff_hz") and v == 0):
                raise ConfigError(f"UficParams.{name} must be finite and ≥ 0 (dt, wrench_cutoff_hz > 0), got {v!r}")

    def damping_tool(self, in_contact: bool = True) -> np.ndarray:
        """Diagonal of D_C in the tool frame [N·s/m ×3, N·m·s/rad ×3] (in contact or approaching)."""
        d = 2.0 * np.asarray(self.damping_ratio) * np.sqrt(
            np.asarray(self.apparent_mass) * np.asarray(self.damping_reference_stiffness))
        if not in_contact:
            d[2] = max(d[2], self.approach_damping_z)
        return d


class UficController(Controller):
    """Unified force-impedance control (eq. 1–13) on a :class:`PoseForceReference`."""

    name = "ufic"

    def __init__(self, params: UficParams | None = None) -> None:
        self.params = params or UficParams()
        self.stiffness_scale = self.params.stiffness_scale
        self._axes_f = tuple(float(a) for a in self.params.force_axes)
        self._d_contact = self.params.damping_tool(True)
        self._d_free = self.params.damping_tool(False)
        self._d_tool = self._d_contact
        self._d_contact_f = tuple(self._d_contact.tolist())  # the same diagonals as Python floats (hot path)
        self._d_free_f = tuple(self._d_free.tolist())
        self._d_tool_f = self._d_contact_f
        self._k_max = np.asarray(self.params.stiffness_max, dtype=float)
        self._neg_k_tool = -self._k_max
        self._neg_k_tool_f = tuple(self._neg_k_tool.tolist())
        self._neg_k_scale = float("nan")  # forces the first build of −K_C(t)
        self._integral = [0.0] * 6  # K_i ∫f̃ / K_i per tool axis, Python floats (1 kHz: no array per tick)
        self._ilim = self.params.integral_limit / self.params.ki if self.params.ki > 0 else 0.0
        self._t_prev: float | None = None
        self._last: dict[str, float] = {}
        self._tau_w = 1.0 / (2.0 * np.pi * self.params.wrench_cutoff_hz)
        self._w_filt: list[float] | None = None  # low-passed measured wrench, tool frame
        self._kernels = joint_kernels.kernels()  # compiled now, never inside a control loop

    def reset(self, state: RobotState) -> None:
        self._integral = [0.0] * 6
        self._t_prev = None
        self._w_filt = None
        self._d_tool, self._d_tool_f = self._d_contact, self._d_contact_f
        self.stiffness_scale = self.params.stiffness_scale
        self._last = {}

    # -- pieces shared with VA-UFIC -------------------------------------------------------
    def _dt(self, state: RobotState) -> float:
        tp = self._t_prev
        dt = state.t - tp if tp is not None and 0.0 < state.t - tp < 0.1 else self.params.dt
        self._t_prev = state.t
        return dt

    def _wrench_filtered(self, state: RobotState, dt: float) -> list[float]:
        """The measured wrench low-passed at ``wrench_cutoff_hz`` (6 Python floats, tool frame)."""
        raw = state.wrench_tool.tolist()
        w = self._w_filt
        if w is not None:
            a = dt / (dt + self._tau_w)
            raw = [x + a * (r - x) for x, r in zip(w, raw, strict=True)]
        self._w_filt = raw
        return raw

    def _select_damping(self, force_z: float, dt: float | None = None) -> None:
        """D_C for this tick from the measured pressing force ``force_z`` [N] (``wrench_tool[2]``): more
        damping along the tool axis while out of contact (damping of any size is passive, so changing
        it costs no energy). With ``dt`` [s] the tool-axis damping moves towards the new value with the
        time constant ``damping_switch_s``; without, it switches at once."""
        target = self._d_contact_f if force_z >= self.params.contact_threshold_n else self._d_free_f
        tau = self.params.damping_switch_s
        if dt is None or tau <= 0:
            self._d_tool_f = target
        else:
            d = self._d_tool_f
            dz = d[2] + dt / (dt + tau) * (target[2] - d[2])
            self._d_tool_f = (target[0], target[1], dz, target[3], target[4], target[5])
        self._d_tool = np.array(self._d_tool_f)

    @staticmethod
    def pose_error_world(state: RobotState, position_d: np.ndarray, rotation_d: np.ndarray) -> np.ndarray:
        """x̃ = x − x_d (eq. 7) in the world frame: [position [m]; rotation vector log(R R_dᵀ) [rad]]."""
        out = np.empty(6)
        out[:3] = state.ee_position - position_d
        out[3:] = rotation_error_world(state.ee_rotation, rotation_d)
        return out

    def force_wrench_tool(self, state: RobotState, wrench_des_tool, dt: float, integrate: bool = True,
                          wrench_meas_tool: list[float] | None = None) -> list[float]:
        """f_f of eq. 11 before the rotation R into the base frame: f_d + K_p f̃ + K_i ∫f̃, with
        f̃ = f_d − f_meas on the selected axes (tool frame); the feed-forward f_d acts on every axis,
        as eq. 11 writes it (``force_axes`` selects where the force error is fed back, not where
        f_d applies). ``wrench_des_tool``: 6 numbers [N, N·m];
        returns 6 Python floats (six-element arithmetic is cheaper on floats than per-call numpy at 1 kHz).
        ``wrench_meas_tool``: ``state.wrench_tool`` as Python floats when the caller has them already."""
        p = self.params
        kp, ki, lim = p.kp, p.ki, self._ilim
        integ = self._integral
        if wrench_meas_tool is None:
            wrench_meas_tool = state.wrench_tool.tolist()
        axes = self._axes_f
        out = [0.0] * 6
        for i in range(6):  # an index loop: zip(strict=True) alone costs more than the arithmetic
            a, fd = axes[i], wrench_des_tool[i]
            err = a * (fd - wrench_meas_tool[i])
            if integrate:  # clamp to ±lim; a NaN stays NaN, as with np.minimum/np.maximum
                s = integ[i] + err * dt
                integ[i] = lim if s > lim else (-lim if s < -lim else s)
            out[i] = fd + kp * err + ki * integ[i]
        return out

    # -- controller ------------------------------------------------------------------------
    def torque(self, state: RobotState, reference: PoseForceReference) -> np.ndarray:
        if not isinstance(reference, PoseForceReference):
            raise ControllerFault(f"{self.name} needs a PoseForceReference, got {type(reference).__name__}")
        # On Python floats, 6-vectors unpacked into locals: at 1 kHz a numpy call on a 3- or 6-vector
        # costs more than the float operations it replaces.
        dt = self._dt(state)
        rl = state.ee_rotation.tolist()
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rl
        # x̃ = [x − x_d; log(R R_dᵀ)] (world, eq. 7), then both halves to the tool frame: Rᵀx̃
        px, py, pz = state.ee_position.tolist()
        dx, dy, dz = reference.position_world.tolist()
        ex, ey, ez = px - dx, py - dy, pz - dz
        ox, oy, oz = rotation_error_world_rows(rl, reference.rotation_world.tolist())
        e0, e1, e2 = r00 * ex + r10 * ey + r20 * ez, r01 * ex + r11 * ey + r21 * ez, r02 * ex + r12 * ey + r22 * ez
        e3, e4, e5 = r00 * ox + r10 * oy + r20 * oz, r01 * ox + r11 * oy + r21 * oz, r02 * ox + r12 * oy + r22 * oz
        vx, vy, vz, wx, wy, wz = state.ee_twist.tolist()
        x0, x1, x2 = r00 * vx + r10 * vy + r20 * vz, r01 * vx + r11 * vy + r21 * vz, r02 * vx + r12 * vy + r22 * vz
        x3, x4, x5 = r00 * wx + r10 * wy + r20 * wz, r01 * wx + r11 * wy + r21 * wz, r02 * wx + r12 * wy + r22 * wz
        if self.stiffness_scale != self._neg_k_scale:  # −K_C(t) rebuilt only when ρ changes
            k_tool = self._k_max.copy()
            k_tool[:3] *= self.stiffness_scale
            self._neg_k_tool, self._neg_k_scale = -k_tool, self.stiffness_scale
            self._neg_k_tool_f = tuple(self._neg_k_tool.tolist())
        k0, k1, k2, k3, k4, k5 = self._neg_k_tool_f
        wd = reference.wrench_tool.tolist()
        wm = self._wrench_filtered(state, dt)
        self._select_damping(wm[2], dt)
        d0, d1, d2, d3, d4, d5 = self._d_tool_f
        f0, f1, f2, f3, f4, f5 = self.force_wrench_tool(state, wd, dt, True, wm)  # eq. 10–12
        # eq. 8, gains in tool axes, plus the force controller
        g0, g1, g2 = k0 * e0 - d0 * x0 + f0, k1 * e1 - d1 * x1 + f1, k2 * e2 - d2 * x2 + f2
        g3, g4, g5 = k3 * e3 - d3 * x3 + f3, k4 * e4 - d4 * x4 + f4, k5 * e5 - d5 * x5 + f5
        self._last = {"pose_error_m": math.sqrt(e0 * e0 + e1 * e1 + e2 * e2), "force_error_n": wd[2] - wm[2]}
        # eq. 9, 13: τ = Jᵀ [R f; R m], the rotation on floats, one (6,) · (6, 7) product
        f_world = (r00 * g0 + r01 * g1 + r02 * g2, r10 * g0 + r11 * g1 + r12 * g2, r20 * g0 + r21 * g1 + r22 * g2,
                   r00 * g3 + r01 * g4 + r02 * g5, r10 * g3 + r11 * g4 + r12 * g5, r20 * g3 + r21 * g4 + r22 * g5)
        return self.joint_torque(state, f_world)

    def joint_torque(self, state: RobotState, f_world: tuple[float, ...]) -> np.ndarray:
        """τ = Jᵀ f (eq. 13) for the world wrench ``f_world`` [N, N·m], applied implicitly over
        ``latency_horizon_ticks`` with this tick's D_C and K_max in the tool frame
        (:func:`tactex.control.damping.latency_shaped_torque`): unchanged on heavy modes."""
        jac = state.jacobian
        h = self.params.latency_horizon_ticks * self.params.dt
        if h > 0 and self._kernels is not None:
            tau = joint_kernels.run(self._kernels.task_torque, jac, state.ee_rotation, state.mass_matrix,
                                    np.array(f_world), self._d_tool, self._k_max, h)
            if tau is not None:
                return tau
            self._kernels = None
        tau = np.dot(f_world, jac)
        if h <= 0:
            return tau
        jac_tool = np.empty_like(jac)
        rt = state.ee_rotation.T
        np.dot(rt, jac[:3], out=jac_tool[:3])
        np.dot(rt, jac[3:], out=jac_tool[3:])
        gains = self._d_tool + h * self._k_max
        return latency_shaped_torque(state.mass_matrix, tau, jac_tool.T @ (gains[:, None] * jac_tool), None, h)

    def telemetry(self) -> dict[str, float]:
        return dict(self._last)
