"""TEC's geometric-algebra line-and-force impedance controller (TEC §IV-B, eq. 34–47).

Per tick, in the tool (end-effector) frame, the frame the paper's Jacobian J_G^ee uses (eq. 42–45):

1. target line L_a,⊥ through the agent point along −n (eq. 28), tool line L_ee = the tool z-axis
   through the TCP (eq. 35);
2. motor M from L_ee to L_a,⊥ (eq. 36, normalisation of [54]) and its logarithm V (eq. 37);
3. V → wrench W_L (eq. 38; see :func:`tactex.geometry.twist_to_wrench` for the pairing);
4. wrench PID on the measured F/T wrench in the tool frame (eq. 39–41);
5. twist damping W_V (eq. 46) and τ = −J^T·(K W_L − D W_V + W_C) (eq. 47), which in numpy's
   [linear; angular] convention is τ = J_worldᵀ · blockdiag(R, R) · (K⊙V − D⊙v_tool + w_C). The
   paper's minus belongs to its GA inner product (B·W = −τ, §III-B); with plain Jᵀ it cancels, and the
   closed-loop tests confirm the sign (the tool descends the line error and presses into the surface).
   The damping term D⊙v_tool enters as the joint damping Jᵀ·blockdiag(R, R)·D·blockdiag(R, R)ᵀ·J,
   and the whole torque is applied implicitly over ``latency_horizon_ticks`` control periods
   (:mod:`tactex.control.damping`): the same on heavy modes, and stable on the light wrist rotation,
   where the explicit form chatters at 1 kHz, and behind the real robot's one-cycle command delay.

Steps 2–3 are evaluated with the closed forms of :mod:`tactex.geometry.motor`, which
``tests/test_geometry_motor.py`` checks against ``pygafro.Line.getMotor`` / ``Motor.log``; a
pygafro round trip per tick would cost more than the whole 100 µs budget.

The screw of M lies on the common perpendicular of the two lines, so its rotation has no
component about the tool axis and, when the tool axis is parallel to the target line, its
translation has none along it: the line term never pushes along the line, the force loop owns
that direction (``tests/test_control_ga.py`` checks it). Moving the agent point along its line
leaves the wrench unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tactex.config import param
from tactex.control.controller import Controller
from tactex.control.damping import latency_shaped_torque
from tactex.control.references import LineForceReference
from tactex.control.state import RobotState
from tactex.errors import ConfigError, ControllerFault
from tactex.geometry.motor import twist_to_wrench, z_line_motor_log_floats

__all__ = ["APPROACH_FADE_BAND", "GaLineForceController", "GaLineForceParams"]

#: The approach speed cap fades out between (1 − this) and (1 + this) × approach_below × the set point [-].
APPROACH_FADE_BAND = 0.2

@dataclass(frozen=True)
class GaLineForceParams:
    """Gains of TEC §V-A3. The paper lists K = diag(30,30,30,750,750,300) and
    D = diag(10,10,10,150,150,50) in gafro's twist order [e12, e13, e23, e1i, e2i, e3i], i.e.
    angular first: 30 N·m/rad and 750/750/300 N/m; here they are split by unit."""

    stiffness_linear: tuple[float, float, float] = param((750.0, 750.0, 300.0), "line stiffness, tool x/y/z [N/m]")
    stiffness_angular: tuple[float, float, float] = param((30.0, 30.0, 30.0), "line stiffness, rotation [N·m/rad]")
    damping_linear: tuple[float, float, float] = param((150.0, 150.0, 50.0), "twist damping, tool x/y/z [N·s/m]")
    damping_angular: tuple[float, float, float] = param((10.0, 10.0, 10.0), "twist damping, rotation [N·m·s/rad]")
    kp: float = param(0.5, "wrench PID proportional gain K_p,W [-]")
    ki: float = param(5.0, "wrench PID integral gain K_i,W [1/s]")
    kd: float = param(0.5, "wrench PID derivative gain K_d,W [s]")
    derivative_cutoff_hz: float = param(
        2.0,
        "low-pass cut-off of the wrench-error derivative [Hz]; the F/T signal carries the tool's inertial "
        "force, and K_d = 0.5 on a less filtered derivative destabilises the force loop (the arm rings or "
        "loses the contact)",
    )
    wrench_cutoff_hz: float = param(
        50.0,
        "first-order low-pass of the measured wrench the PID regulates [Hz]: a sliding contact's stick-slip "
        "shows on the F/T as one-tick spikes, which K_p and K_d (as K_d·ΔW/τ, 6× K_p) would pass straight to "
        "the joints; a lower cut-off, or a second low-pass on the derivative, adds enough lag to destabilise the "
        "force loop on a stiff pad",
    )
    force_axes: tuple[float, float, float, float, float, float] = param(
        (0.0, 0.0, 1.0, 0.0, 0.0, 0.0),
        "wrench components the PID regulates (1) or ignores (0), tool frame [f; m]. The paper applies "
        "scalar gains to all six; with a zero set point the tangential and moment integrators cancel "
        "friction against the line stiffness, so by default only the pressing force is regulated",
    )
    integral_limit: float = param(40.0, "bound on |K_i ∫W_e| per component (anti-windup) [N or N·m]")
    contact_threshold_n: float = param(
        1.0,
        "the integrator runs only while the measured pressing force exceeds this [N]: in free flight it would "
        "wind up (K_i·F per second) and the tool would hit the surface at speed",
    )
    approach_speed_max: float = param(
        0.03,
        "approach speed cap along the tool axis while the pressing force is below approach_below × the set point "
        "[m/s]: the force loop alone would approach at K_p·F/D_z ≈ 0.1 m/s (and faster after a lost contact), and "
        "the impact on a stiff pad would exceed 2× the set point",
    )
    wrench_median_ticks: int = param(
        3, "median over this many ticks of the measured wrench before the low-pass (1: none) [-]: a sliding "
        "pad's one-tick F/T dips would reach the joints through K_d's high-frequency gain (K_d/τ_d ≈ 6) as "
        "torque steps at the robot's torque-rate limit; a median drops single-tick outliers without the lag "
        "of a slew limit, which keeps the controller from recovering after a large spike")
    outlier_median_ticks: int = param(
        5, "a longer median [ticks] that replaces wrench_median_ticks' where the two differ by more than outlier_n "
        "(1: off): a sliding pad's F/T also dips for two ticks (a slip and its rebound), which the short median "
        "passes and K_d's high-frequency gain turns into torque steps at the robot's rate limit; where the two "
        "agree the short median's lag stays, since the longer one's extra tick of delay on every sample costs the "
        "force loop phase margin (the arm rings longer after a disturbance)")
    outlier_n: float = param(
        1.0, "difference between the short and the long median beyond which the long one is used [N, N·m]")
    latency_horizon_ticks: float = param(
        2.0, "horizon h of the implicit impedance in control periods [-]: τ = M (M + h·B + h²·K)⁻¹ τ_explicit "
        "with the line stiffness K and damping D mapped to the joints (tactex.control.damping), so that a "
        "command acting one or two ticks late does not ring on the light wrist modes: 2 caps dt·B/m at 1/2, "
        "inside the 0.618 that two ticks of delay allow; a longer horizon softens the force loop and raises the "
        "touch-down force peak; 0: explicit, as eq. 47")
    approach_speed_min: float = param(
        0.005, "out of contact, below this speed along the tool axis the tool counts as held by joint friction and "
        "the force integrator builds up the push [m/s]")
    approach_damping_z: float = param(
        400.0, "damping on the approach speed in excess of approach_speed_max [N·s/m]")
    approach_below: float = param(
        0.5, "fraction of the set point under which the approach damping acts [-]; a fixed small threshold would "
        "miss a lost contact, since the F/T reads the tool's own inertia (~2 N) while the arm falls")
    integral_leak_time: float = param(
        0.2, "out of contact the integrator decays with this time constant, so a lost contact is approached "
        "again with K_p·F only and not the whole held force [s]")
    dt: float = param(1e-3, "nominal control period, used when state.t does not advance [s]")

    def __post_init__(self) -> None:
        for name in ("stiffness_linear", "stiffness_angular", "damping_linear", "damping_angular"):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != (3,) or not np.isfinite(v).all() or (v < 0).any():
                raise ConfigError(f"GaLineForceParams.{name} must be 3 finite values ≥ 0, got {getattr(self, name)!r}")
        for name in ("kp", "ki", "kd", "integral_limit", "dt", "derivative_cutoff_hz",
                     "latency_horizon_ticks",
                     "wrench_cutoff_hz", "contact_threshold_n",
                     "integral_leak_time", "approach_damping_z", "approach_below", "approach_speed_max",
                     "approach_speed_min", "outlier_n"):
            v = getattr(self, name)
            positive = ("dt", "derivative_cutoff_hz", "wrench_cutoff_hz", "integral_leak_time")
            if not np.isfinite(v) or v < 0 or (name in positive and v == 0):
                raise ConfigError(f"GaLineForceParams.{name} must be finite and ≥ 0 (> 0 for dt/cut-off), got {v!r}")
        for name in ("wrench_median_ticks", "outlier_median_ticks"):
            m = getattr(self, name)
            if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or not 1 <= m <= 15 or m % 2 == 0:
                raise ConfigError(f"GaLineForceParams.{name} must be an odd integer in [1, 15], got {m!r}")
        axes = np.asarray(self.force_axes, dtype=float)
        if axes.shape != (6,) or not np.isin(axes, (0.0, 1.0)).all():
            raise ConfigError(f"GaLineForceParams.force_axes must be six 0/1 flags, got {self.force_axes!r}")


class GaLineForceController(Controller):
    """TEC eq. 47 on a :class:`LineForceReference`. Reference: agent point, normal, force."""

    name = "ga_line_force"

    def __init__(self, params: GaLineForceParams | None = None) -> None:
        self.params = params or GaLineForceParams()
        p = self.params
        self._k = np.concatenate([p.stiffness_linear, p.stiffness_angular]).astype(float)
        self._d = np.concatenate([p.damping_linear, p.damping_angular]).astype(float)
        self._axes = np.asarray(p.force_axes, dtype=float)
        self._d_z = float(p.damping_linear[2])
        # The tick runs on Python floats (gains as tuples, PID states as lists): at 1 kHz a numpy call on
        # a 6-vector costs more than the float operations it replaces, and the tick makes dozens of them.
        self._k_f = tuple(self._k.tolist())
        self._axes_f = tuple(self._axes.tolist())
        self._integral = [0.0] * 6  # ∫W_e per tool axis [N·s, N·m·s]
        self._err_prev = [0.0] * 6
        self._derr = [0.0] * 6  # low-passed dW_e/dt
        self._t_prev: float | None = None
        self._n_hist = max(p.wrench_median_ticks, p.outlier_median_ticks)
        # the long median only where the measured wrench is read: the regulated axes, and the pressing force
        # (contact, approach cap) on every setting
        self._outlier_axes = tuple(sorted({2} | {i for i in range(6) if p.force_axes[i]}))
        self._ilim = p.integral_limit / p.ki if p.ki > 0 else 0.0
        self._tau_d = 1.0 / (2.0 * np.pi * p.derivative_cutoff_hz)
        self._tau_w = 1.0 / (2.0 * np.pi * p.wrench_cutoff_hz)
        self._w_filt: list[float] | None = None  # low-passed measured wrench, tool frame
        self._w_line: tuple[float, ...] | None = None
        self._w_c2 = 0.0
        self._w_hist: list[list[float]] = []  # the last raw wrenches (as many as the longer median), oldest first
        self._err2 = 0.0

    def reset(self, state: RobotState) -> None:
        self._integral = [0.0] * 6
        self._err_prev = [0.0] * 6
        self._derr = [0.0] * 6
        self._w_filt = None
        self._w_hist = []
        self._t_prev = None
        self._w_line = None

    @staticmethod
    def _line_error_floats(rl: list[list[float]], state: RobotState, reference: LineForceReference
                           ) -> tuple[float, float, float, float, float, float]:
        """:meth:`line_error` as six Python floats; ``rl`` is the tool rotation R as nested floats."""
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rl
        ax, ay, az = reference.point_world.tolist()
        px, py, pz = state.ee_position.tolist()
        wx, wy, wz = ax - px, ay - py, az - pz
        nx, ny, nz = reference.normal_world.tolist()
        return z_line_motor_log_floats(  # target point Rᵀ(p_a − x) and direction −Rᵀn in the tool frame
            r00 * wx + r10 * wy + r20 * wz, r01 * wx + r11 * wy + r21 * wz, r02 * wx + r12 * wy + r22 * wz,
            -(r00 * nx + r10 * ny + r20 * nz), -(r01 * nx + r11 * ny + r21 * nz), -(r02 * nx + r12 * ny + r22 * nz))

    def line_error(self, state: RobotState, reference: LineForceReference) -> np.ndarray:
        """log of the motor from the tool z-line to the target line, in the tool frame, [t; ω]."""
        return np.array(self._line_error_floats(state.ee_rotation.tolist(), state, reference))

    def line_wrench(self, state: RobotState, reference: LineForceReference) -> np.ndarray:
        """K·W_L (eq. 38 scaled by the stiffness), tool frame [f; m]."""
        return self._k * twist_to_wrench(self.line_error(state, reference))

    def torque(self, state: RobotState, reference: LineForceReference) -> np.ndarray:
        if not isinstance(reference, LineForceReference):
            raise ControllerFault(f"{self.name} needs a LineForceReference, got {type(reference).__name__}")
        p = self.params
        tp = self._t_prev
        dt = state.t - tp if tp is not None and 0.0 < state.t - tp < 0.1 else p.dt
        self._t_prev = state.t
        rl = state.ee_rotation.tolist()
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rl

        k0, k1, k2, k3, k4, k5 = self._k_f
        l0, l1, l2, l3, l4, l5 = self._line_error_floats(rl, state, reference)
        w_line = (k0 * l0, k1 * l1, k2 * l2, k3 * l3, k4 * l4, k5 * l5)  # eq. 36–38
        vx, vy, vz, wx, wy, wz = state.ee_twist.tolist()
        v_tool = (  # J^ee q̇ = [Rᵀv; Rᵀω] (eq. 46)
            r00 * vx + r10 * vy + r20 * vz, r01 * vx + r11 * vy + r21 * vz, r02 * vx + r12 * vy + r22 * vz,
            r00 * wx + r10 * wy + r20 * wz, r01 * wx + r11 * wy + r21 * wz, r02 * wx + r12 * wy + r22 * wz)

        # eq. 39–41, per tool axis on floats; the clamp to ±lim keeps a NaN, as np.minimum/np.maximum do
        force_n = reference.force_n
        w_raw = state.wrench_tool.tolist()
        hist = self._w_hist
        hist.append(w_raw)
        if len(hist) > self._n_hist:
            del hist[0]
        w_med = _column_medians(hist, p.wrench_median_ticks)
        n_long = p.outlier_median_ticks
        if n_long > p.wrench_median_ticks and len(hist) >= n_long:
            window, thr = hist[-n_long:], p.outlier_n
            w_med = list(w_med)  # (the newest row itself when there is no short median)
            for i in self._outlier_axes:
                b = sorted([row[i] for row in window])[n_long // 2]
                if w_med[i] - b > thr or b - w_med[i] > thr:
                    w_med[i] = b
        w_meas = self._w_filt
        if w_meas is None:
            w_meas = w_med
        else:
            a_w = dt / (dt + self._tau_w)
            w_meas = [m + a_w * (r - m) for m, r in zip(w_meas, w_med, strict=True)]
        self._w_filt = w_meas
        w_des = (0.0, 0.0, force_n, 0.0, 0.0, 0.0)
        axes, integral, derr, err_prev = self._axes_f, self._integral, self._derr, self._err_prev
        in_contact = w_raw[2] >= p.contact_threshold_n
        # out of contact and not moving in: joint friction holds the tool (a real arm's joints stick at
        # ~1 N·m, more than K_p·F pushes), so the pressing integrator builds up until it moves; the
        # approach speed cap below keeps the touch-down gentle
        stalled = not in_contact and v_tool[2] < p.approach_speed_min
        lim = self._ilim
        leak = 1.0 - dt / (dt + p.integral_leak_time)
        alpha = self._alpha(dt)
        kp, ki, kd = p.kp, p.ki, p.kd
        err = [0.0] * 6
        w_tool = [0.0] * 6
        for i in range(6):
            e = axes[i] * (w_des[i] - w_meas[i])
            err[i] = e
            if in_contact or (i == 2 and stalled):
                s = integral[i] + e * dt
                integral[i] = lim if s > lim else (-lim if s < -lim else s)
            else:
                integral[i] *= leak
            e_prev = e if tp is None else err_prev[i]
            derr[i] += alpha * ((e - e_prev) / dt - derr[i])
            w_c = kp * e + ki * integral[i] + kd * derr[i]  # eq. 40
            w_tool[i] = w_line[i] + w_c  # eq. 47 in [linear; angular]; −D W_V is added below, implicitly
            if i == 2:
                self._w_c2 = w_c
        self._err_prev = err
        self._err2 = err[2]

        # a commanded approach speed (far above the surface): the damping D_z pulls towards it, not to rest,
        # without a step in the force set point (which K_d would pass on as a kick)
        v_approach = reference.approach_speed_m_s if not in_contact else 0.0
        if v_approach > 0.0:
            w_tool[2] += self._d_z * v_approach
        excess = v_tool[2] - max(p.approach_speed_max, v_approach)
        if excess > 0.0:  # speed cap while approaching (not in eq. 47)
            # faded out across a band around approach_below × the set point, not switched: the pad compresses at
            # centimetres per second while the force ramps up after touch-down, and a switch would drop
            # approach_damping_z × excess (newtons) from the command in one tick
            below = p.approach_below * force_n
            fade = (1.0 + APPROACH_FADE_BAND - w_meas[2] / below) / (2.0 * APPROACH_FADE_BAND) if below > 0.0 else 0.0
            if fade > 0.0:
                w_tool[2] -= (fade if fade < 1.0 else 1.0) * p.approach_damping_z * excess
        self._w_line = w_line
        # τ = Jᵀ [R f; R m]: the rotation on floats, one (6,) · (6, 7) product
        f0, f1, f2, m0, m1, m2 = w_tool
        f_world = (r00 * f0 + r01 * f1 + r02 * f2, r10 * f0 + r11 * f1 + r12 * f2, r20 * f0 + r21 * f1 + r22 * f2,
                   r00 * m0 + r01 * m1 + r02 * m2, r10 * m0 + r11 * m1 + r12 * m2, r20 * m0 + r21 * m1 + r22 * m2)
        jac = state.jacobian
        # eq. 46–47's −Jᵀ D J^ee q̇ as joint damping, and the whole impedance applied implicitly over
        # latency_horizon_ticks (tactex.control.damping): the explicit form rings at 500 Hz on the wrist,
        # whose rotation about the flange axis is too light for 10 N·m·s/rad at 1 kHz, and at 60 Hz behind
        # a one-tick command delay; on heavy modes the two are the same
        jac_tool = np.empty_like(jac)
        rt = state.ee_rotation.T
        np.dot(rt, jac[:3], out=jac_tool[:3])
        np.dot(rt, jac[3:], out=jac_tool[3:])
        damping = jac_tool.T @ (self._d[:, None] * jac_tool)
        stiffness = jac_tool.T @ (self._k[:, None] * jac_tool)
        tau = np.dot(f_world, jac) - damping @ state.dq
        if p.latency_horizon_ticks <= 0:
            return tau
        return latency_shaped_torque(state.mass_matrix, tau, damping, stiffness, p.latency_horizon_ticks * p.dt)

    def _alpha(self, dt: float) -> float:
        return dt / (dt + self._tau_d)

    def telemetry(self) -> dict[str, float]:
        """Line offset [m] and angle [rad] (from the line twist), force error and command [N]."""
        if self._w_line is None:
            return {}
        xi = np.array(self._w_line) / np.maximum(self._k, 1e-12)
        return {
            "line_offset_m": float(np.hypot(xi[0], xi[1])),
            "line_angle_rad": float(np.hypot(xi[3], xi[4])),
            "force_error_n": self._err2,
            "force_cmd_n": self._w_c2,
        }


def _column_medians(hist: list[list[float]], n: int) -> list[float]:
    """Per component, the median of the last ``n`` rows of ``hist`` (the newest row until there are ``n``)."""
    if n <= 1 or len(hist) < n:
        return hist[-1]
    return [sorted(col)[n // 2] for col in zip(*hist[-n:], strict=True)]
