"""Baseline: Cartesian impedance with a fixed orientation, like libfranka's example controller.

τ = Jᵀ(−K x̃ − D (ẋ − ẋ_d) + R·f_d^ee): a spring-damper on the pose error and an optional constant
(feed-forward, no feedback) tool-frame wrench. It is the comparison point for the other controllers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tactex.config import param
from tactex.control.controller import Controller
from tactex.control.references import PoseForceReference
from tactex.control.state import RobotState
from tactex.errors import ConfigError, ControllerFault
from tactex.geometry.so3 import rotation_error_world

__all__ = ["CartesianImpedanceController", "CartesianImpedanceParams"]


@dataclass(frozen=True)
class CartesianImpedanceParams:
    """Defaults of libfranka's cartesian_impedance_example_controller (150 N/m, 10 N·m/rad, critical)."""

    stiffness_linear: float = param(150.0, "translational stiffness [N/m]")
    stiffness_angular: float = param(10.0, "rotational stiffness [N·m/rad]")
    damping_linear: float = param(2.0 * np.sqrt(150.0), "translational damping [N·s/m]")
    damping_angular: float = param(2.0 * np.sqrt(10.0), "rotational damping [N·m·s/rad]")

    def __post_init__(self) -> None:
        for name in ("stiffness_linear", "stiffness_angular", "damping_linear", "damping_angular"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ConfigError(f"CartesianImpedanceParams.{name} must be finite and ≥ 0, got {v!r}")


class CartesianImpedanceController(Controller):
    """Fixed-gain Cartesian impedance on a :class:`PoseForceReference` (its wrench is feed-forward)."""

    name = "cartesian_impedance"

    def __init__(self, params: CartesianImpedanceParams | None = None) -> None:
        self.params = params or CartesianImpedanceParams()
        p = self.params
        self._k = np.array([p.stiffness_linear] * 3 + [p.stiffness_angular] * 3)
        self._d = np.array([p.damping_linear] * 3 + [p.damping_angular] * 3)

    def torque(self, state: RobotState, reference: PoseForceReference) -> np.ndarray:
        if not isinstance(reference, PoseForceReference):
            raise ControllerFault(f"{self.name} needs a PoseForceReference, got {type(reference).__name__}")
        x_err = np.concatenate([state.ee_position - reference.position_world,
                                rotation_error_world(state.ee_rotation, reference.rotation_world)])
        rot = state.ee_rotation
        w = reference.wrench_tool
        f = -self._k * x_err - self._d * (state.ee_twist - reference.twist_world)
        f += np.concatenate([rot @ w[:3], rot @ w[3:]])
        return state.jacobian.T @ f
