"""Null-space posture control for a redundant arm, as a wrapper around any task-space controller.

A 7-DoF Franka under a 6-D task controller (TEC's GA line controller, UFIC, VA-UFIC) has one
uncontrolled direction: over seconds of contact the elbow drifts, the arm wanders to its joint
limits and into poor postures. The Franka example Cartesian impedance controller adds
τ_ns = (I − Jᵀ J⁺ᵀ)(k (q_d − q) − d dq); so do we, for every task controller. The projection
keeps the task wrench untouched (it lives in the null space of Jᵀ's left inverse).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from tactex.config import param
from tactex.control import joint_kernels
from tactex.control.controller import Controller
from tactex.control.linalg import solve
from tactex.control.state import RobotState
from tactex.errors import ConfigError, ControllerFault, InputError

__all__ = ["PINV_DAMPING", "NullspaceParams", "NullspacePosture", "nullspace_projector", "project_nullspace"]

#: δ of the damped pseudo-inverse in the posture's projection [-].
PINV_DAMPING = 1e-3


def nullspace_projector(jacobian: np.ndarray, damping: float = PINV_DAMPING) -> np.ndarray:
    """N = I − Jᵀ J⁺ᵀ (n, n), with J⁺ the damped pseudo-inverse Jᵀ (J Jᵀ + δ² I)⁻¹."""
    j = jacobian
    jjt = j @ j.T + damping**2 * np.eye(j.shape[0])
    j_pinv_t = solve(jjt, j)  # (J⁺)ᵀ = (J Jᵀ + δ²I)⁻¹ J
    return np.eye(j.shape[1]) - j.T @ j_pinv_t


_EYE6_DAMPED = PINV_DAMPING**2 * np.eye(6)


def project_nullspace(jacobian: np.ndarray, tau: np.ndarray, damping: float = PINV_DAMPING) -> np.ndarray:
    """N τ = τ − Jᵀ (J Jᵀ + δ² I)⁻¹ J τ, without forming N (one 6×6 solve with a vector: the 1 kHz path)."""
    j = jacobian
    reg = _EYE6_DAMPED if damping == PINV_DAMPING and j.shape[0] == 6 else damping**2 * np.eye(j.shape[0])
    return tau - j.T @ solve(j @ j.T + reg, j @ tau)


@dataclass(frozen=True)
class NullspaceParams:
    """Posture spring in the null space (Franka example: stiffness 20, damping 2·√20)."""

    stiffness: float = param(20.0, "null-space posture stiffness [N·m/rad]")
    damping: float = param(2.0 * np.sqrt(20.0), "null-space joint damping [N·m·s/rad]")
    latency_horizon_ticks: float = param(
        3.0, "the posture torque is applied as M (M + (h·D + h²·K)·I)⁻¹ τ over the horizon h = this × dt "
        "(tactex.control.damping) [-]; 0: as computed. Explicit, the null-space damping on the light wrist "
        "is unstable behind a one-tick command delay: the wrist chatters against the torque-rate limit")
    dt: float = param(1e-3, "control period [s]")

    def __post_init__(self) -> None:
        k, d = self.stiffness, self.damping
        if not (np.isfinite(k) and np.isfinite(d) and k >= 0 and d >= 0):
            raise ConfigError(f"null-space gains must be finite and ≥ 0, got {self.stiffness}, {self.damping}")
        h, dt = self.latency_horizon_ticks, self.dt
        if not (np.isfinite(h) and h >= 0 and np.isfinite(dt) and dt > 0):
            raise ConfigError(f"NullspaceParams: latency_horizon_ticks must be ≥ 0 and dt > 0, got {h!r}, {dt!r}")


class NullspacePosture(Controller):
    """``inner``'s torque plus a posture spring towards ``q_posture`` projected in the null space.

    ``q_posture`` defaults to the joint positions at :meth:`reset`.
    """

    def __init__(self, inner: Controller, q_posture: np.ndarray | None = None,
                 params: NullspaceParams | None = None) -> None:
        self.inner = inner
        self.params = params or NullspaceParams()
        self.name = f"{inner.name}+nullspace"
        if q_posture is not None:
            q = np.asarray(q_posture, dtype=float)
            if q.ndim != 1 or not np.isfinite(q).all():
                raise InputError(f"q_posture must be a finite 1-D array of joint positions [rad], got {q_posture!r}")
        self._fixed = None if q_posture is None else np.asarray(q_posture, dtype=float).copy()
        self.q_posture = self._fixed
        self._kernels = joint_kernels.kernels()  # compiled now, never inside a control loop

    def reset(self, state: RobotState) -> None:
        self.q_posture = state.q.copy() if self._fixed is None else self._fixed
        self.inner.reset(state)

    def resume(self, state: RobotState) -> None:
        self.q_posture = state.q.copy() if self._fixed is None else self._fixed
        self.inner.resume(state)

    def torque(self, state: RobotState, reference: Any) -> np.ndarray:
        tau = self.inner.torque(state, reference)
        if self.q_posture is None:
            self.q_posture = state.q.copy()
        if self.q_posture.shape != state.q.shape:
            raise ControllerFault(f"q_posture has {self.q_posture.shape[0]} joints, the robot {state.q.shape[0]}")
        p = self.params
        h = p.latency_horizon_ticks * p.dt
        if self._kernels is not None:
            tau_ns = joint_kernels.run(self._kernels.posture_torque, state.jacobian, state.mass_matrix, self.q_posture,
                                       state.q, state.dq, p.stiffness, p.damping, h, PINV_DAMPING)
            if tau_ns is not None:
                return tau + tau_ns
            self._kernels = None
        tau_ns = project_nullspace(state.jacobian, p.stiffness * (self.q_posture - state.q) - p.damping * state.dq)
        if h > 0:
            m = state.mass_matrix
            tau_ns = m @ solve(m + (h * p.damping + h * h * p.stiffness) * np.eye(m.shape[0]), tau_ns)
        return tau + tau_ns

    def telemetry(self) -> dict[str, float]:
        return self.inner.telemetry()
