"""Joint impedance with a minimum-jerk joint trajectory: how TEC moves between its pre-recorded
capture and hover poses (§V-A3: "a simple joint impedance controller")."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tactex.config import param
from tactex.control.controller import Controller
from tactex.control.state import RobotState
from tactex.errors import ConfigError, ControllerFault, InputError

__all__ = ["JointImpedanceController", "JointImpedanceParams", "JointTarget", "min_jerk"]


def min_jerk(s: float) -> tuple[float, float]:
    """Minimum-jerk profile at normalised time s ∈ [0, 1]: (position fraction, d/ds)."""
    s = min(max(s, 0.0), 1.0)
    return 10 * s**3 - 15 * s**4 + 6 * s**5, 30 * s**2 - 60 * s**3 + 30 * s**4


@dataclass(frozen=True)
class JointImpedanceParams:
    """Gains of the Franka example joint impedance controller (stiffness and damping as there).

    The damping is applied implicitly (see :class:`JointImpedanceController`): the explicit −D·q̇
    of the example is unstable at 1 kHz on any motion mode whose inertia is below D·dt/2, e.g.
    joints 1 and 3 turning against each other when joint 2 is near 0 (their axes then align and
    only the small link 2 moves). The real arm's reflected rotor inertia hides this; a model
    without it, or a lighter arm, does not.
    """

    stiffness: tuple[float, ...] = param((600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0), "joint stiffness [N·m/rad]")
    damping: tuple[float, ...] = param((50.0, 50.0, 50.0, 50.0, 30.0, 25.0, 15.0), "joint damping [N·m·s/rad]")
    dt: float = param(1e-3, "control period the damping is made stable for [s]")

    def __post_init__(self) -> None:
        k, d = np.asarray(self.stiffness, float), np.asarray(self.damping, float)
        ok = np.all(k >= 0) and np.all(d >= 0) and np.isfinite(k).all() and np.isfinite(d).all()
        if k.shape != d.shape or not ok:
            raise ConfigError(f"joint stiffness and damping must be ≥ 0 and of equal length, got {k} and {d}")
        if not (np.isfinite(self.dt) and 0 < self.dt <= 0.1):
            raise ConfigError(f"JointImpedanceParams.dt must be a control period in (0, 0.1] s, got {self.dt!r}")


@dataclass(frozen=True)
class JointTarget:
    """Move from ``q_start`` to ``q_goal`` [rad] between ``t_start`` and ``t_start + duration_s`` [s]."""

    q_start: np.ndarray
    q_goal: np.ndarray
    t_start: float
    duration_s: float

    def __post_init__(self) -> None:
        q0 = np.asarray(self.q_start, dtype=float)
        q1 = np.asarray(self.q_goal, dtype=float)
        if q0.ndim != 1 or q0.shape != q1.shape or not (np.isfinite(q0).all() and np.isfinite(q1).all()):
            raise InputError(
                f"JointTarget needs finite q_start and q_goal of one shape [rad], got {q0.tolist()} and {q1.tolist()}"
            )
        if not (np.isfinite(self.t_start) and np.isfinite(self.duration_s) and self.duration_s >= 0):
            raise InputError(f"JointTarget needs a finite t_start and duration_s ≥ 0 [s], got {self.t_start}, "
                             f"{self.duration_s}")
        object.__setattr__(self, "q_start", q0)
        object.__setattr__(self, "q_goal", q1)

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Desired joint position [rad] and velocity [rad/s] at time t [s]."""
        if self.duration_s <= 0:
            return self.q_goal, np.zeros_like(self.q_goal)
        s, ds = min_jerk((t - self.t_start) / self.duration_s)
        delta = self.q_goal - self.q_start
        return self.q_start + s * delta, ds * delta / self.duration_s


class JointImpedanceController(Controller):
    """τ = K (q_d − q) + D_dt (dq_d − dq) + C(q, dq)·dq on a :class:`JointTarget` (gravity by the robot).

    D_dt = M (M + dt·D)⁻¹ D = (D⁻¹ + dt·M⁻¹)⁻¹ is the damping D applied implicitly over one control
    period (backward Euler, as MuJoCo integrates joint damping): the series combination of D with
    M/dt. It equals D on modes whose inertia is large against D·dt and never exceeds M/dt, which
    a 1 kHz loop can apply without ringing; it is symmetric positive definite, so still passive.
    """

    name = "joint_impedance"

    def __init__(self, params: JointImpedanceParams | None = None) -> None:
        self.params = params or JointImpedanceParams()
        self._k = np.asarray(self.params.stiffness, dtype=float)
        self._d = np.asarray(self.params.damping, dtype=float)
        self._d_mat = np.diag(self._d)
        self._dt_d_mat = float(self.params.dt) * self._d_mat  # dt·D, added to M every tick

    def damping_matrix(self, mass_matrix: np.ndarray) -> np.ndarray:
        """D_dt [N·m·s/rad] for the joint-space inertia ``mass_matrix`` [kg·m²]."""
        m = np.asarray(mass_matrix, dtype=float)
        return m @ np.linalg.solve(m + self._dt_d_mat, self._d_mat)

    def torque(self, state: RobotState, reference: JointTarget) -> np.ndarray:
        if not isinstance(reference, JointTarget):
            raise ControllerFault(f"{self.name} needs a JointTarget, got {type(reference).__name__}")
        if reference.q_goal.shape != state.q.shape or self._k.shape != state.q.shape:
            raise ControllerFault(f"joint target has shape {reference.q_goal.shape}, gains {self._k.shape}, "
                                  f"the robot {state.q.shape}")
        q_d, dq_d = reference.at(state.t)
        m = state.mass_matrix
        accel = np.linalg.solve(m + self._dt_d_mat, self._d * (dq_d - state.dq))
        return self._k * (q_d - state.q) + m @ accel + state.coriolis
