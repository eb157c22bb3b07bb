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
from tactex.geometry.so3 import rotation_error_world_rows

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
        # the gains as Python floats: the tick runs on floats (cheaper at 1 kHz than numpy on 3-vectors)
        self._gains_f = (-p.stiffness_linear, -p.stiffness_angular, p.damping_linear, p.damping_angular)

    def torque(self, state: RobotState, reference: PoseForceReference) -> np.ndarray:
        if not isinstance(reference, PoseForceReference):
            raise ControllerFault(f"{self.name} needs a PoseForceReference, got {type(reference).__name__}")
        rl = state.ee_rotation.tolist()
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rl
        px, py, pz = state.ee_position.tolist()
        dx, dy, dz = reference.position_world.tolist()
        ox, oy, oz = rotation_error_world_rows(rl, reference.rotation_world.tolist())
        v0, v1, v2, v3, v4, v5 = state.ee_twist.tolist()
        u0, u1, u2, u3, u4, u5 = reference.twist_world.tolist()
        w0, w1, w2, w3, w4, w5 = reference.wrench_tool.tolist()
        nkl, nka, dl, da = self._gains_f
        f_world = (  # −K x̃ − D (ẋ − ẋ_d) + [R f_d; R m_d], world frame
            nkl * (px - dx) - dl * (v0 - u0) + (r00 * w0 + r01 * w1 + r02 * w2),
            nkl * (py - dy) - dl * (v1 - u1) + (r10 * w0 + r11 * w1 + r12 * w2),
            nkl * (pz - dz) - dl * (v2 - u2) + (r20 * w0 + r21 * w1 + r22 * w2),
            nka * ox - da * (v3 - u3) + (r00 * w3 + r01 * w4 + r02 * w5),
            nka * oy - da * (v4 - u4) + (r10 * w3 + r11 * w4 + r12 * w5),
            nka * oz - da * (v5 - u5) + (r20 * w3 + r21 * w4 + r22 * w5),
        )
        return np.dot(f_world, state.jacobian)
