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
from tactex.control.references import LineForceReference
from tactex.control.state import RobotState
from tactex.errors import ConfigError, ControllerFault
from tactex.geometry.motor import twist_to_wrench, z_line_motor_log

__all__ = ["GaLineForceController", "GaLineForceParams"]

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
        "force, and K_d = 0.5 on a less filtered derivative destabilised the simulated Franka (20 Hz: diverged, "
        "5 Hz: lost contact)",
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
        for name in ("kp", "ki", "kd", "integral_limit", "dt", "derivative_cutoff_hz", "contact_threshold_n",
                     "integral_leak_time", "approach_damping_z", "approach_below", "approach_speed_max"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0 or (name in ("dt", "derivative_cutoff_hz", "integral_leak_time") and v == 0):
                raise ConfigError(f"GaLineForceParams.{name} must be finite and ≥ 0 (> 0 for dt/cut-off), got {v!r}")
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
        self._integral = np.zeros(6)
        self._err_prev = np.zeros(6)
        self._derr = np.zeros(6)
        self._t_prev: float | None = None
        self._w_des = np.zeros(6)
        self._ilim = p.integral_limit / p.ki if p.ki > 0 else 0.0
        self._tau_d = 1.0 / (2.0 * np.pi * p.derivative_cutoff_hz)
        self._w_line: np.ndarray | None = None
        self._w_c2 = 0.0
        self._err2 = 0.0

    def reset(self, state: RobotState) -> None:
        self._integral[:] = 0.0
        self._err_prev = np.zeros(6)
        self._derr[:] = 0.0
        self._t_prev = None
        self._w_line = None

    def line_error(self, state: RobotState, reference: LineForceReference) -> np.ndarray:
        """log of the motor from the tool z-line to the target line, in the tool frame, [t; ω]."""
        rot = state.ee_rotation
        point_tool = (reference.point_world - state.ee_position) @ rot
        dir_tool = -(reference.normal_world @ rot)
        return z_line_motor_log(point_tool, dir_tool)

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
        rot = state.ee_rotation

        w_line = self._k * self.line_error(state, reference)  # eq. 36–38
        v_tool = (state.ee_twist.reshape(2, 3) @ rot).ravel()  # J^ee q̇ (eq. 46)

        w_des = self._w_des
        w_des[2] = reference.force_n
        err = self._axes * (w_des - state.wrench_tool)  # eq. 39–41
        in_contact = state.wrench_tool[2] >= p.contact_threshold_n
        if in_contact:
            self._integral += err * dt
            np.minimum(self._integral, self._ilim, out=self._integral)  # np.clip costs ~4 µs more
            np.maximum(self._integral, -self._ilim, out=self._integral)
        else:
            self._integral *= 1.0 - dt / (dt + p.integral_leak_time)
        if tp is None:
            self._err_prev = err
        self._derr += self._alpha(dt) * ((err - self._err_prev) / dt - self._derr)
        self._err_prev = err
        w_c = p.kp * err + p.ki * self._integral + p.kd * self._derr  # eq. 40

        w_tool = w_line - self._d * v_tool + w_c  # eq. 47 in [linear; angular]
        excess = v_tool[2] - p.approach_speed_max
        if excess > 0.0 and state.wrench_tool[2] < p.approach_below * reference.force_n:
            w_tool[2] -= p.approach_damping_z * excess  # speed cap while approaching (not in eq. 47)
        self._w_line = w_line
        self._w_c2 = float(w_c[2])
        self._err2 = float(err[2])
        return state.jacobian.T @ (w_tool.reshape(2, 3) @ rot.T).ravel()

    def _alpha(self, dt: float) -> float:
        return dt / (dt + self._tau_d)

    def telemetry(self) -> dict[str, float]:
        """Line offset [m] and angle [rad] (from the line twist), force error and command [N]."""
        if self._w_line is None:
            return {}
        xi = self._w_line / np.maximum(self._k, 1e-12)
        return {
            "line_offset_m": float(np.hypot(xi[0], xi[1])),
            "line_angle_rad": float(np.hypot(xi[3], xi[4])),
            "force_error_n": self._err2,
            "force_cmd_n": self._w_c2,
        }
