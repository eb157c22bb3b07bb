"""A minimal Cartesian impedance with a force feed-forward, used by the simulator's own tests,
benchmark and example (the real controllers live in :mod:`tactex.control`).

τ = Jᵀ(K e − D ẋ + f_ff) − D_q q̇, with e the TCP pose error [position; rotation vector] in the
world frame; along the world axes listed in ``free_axes`` the stiffness is zero so that the feed-
forward force alone sets the contact force there.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tactex.control.state import RobotState
from tactex.sim.ik import rotation_error

__all__ = ["SimpleImpedance"]


@dataclass
class SimpleImpedance:
    """Cartesian impedance of the TCP (world frame) plus a wrench feed-forward.

    Attributes:
        stiffness: (6,) [N/m ×3, N·m/rad ×3]; damping: (6,) [N·s/m ×3, N·m·s/rad ×3].
        joint_damping: null-space/joint damping [N·m·s/rad].
        free_axes: world translation axes (0, 1, 2) without stiffness (force-controlled).
    """

    stiffness: np.ndarray = field(default_factory=lambda: np.array([1500.0, 1500.0, 1500.0, 60.0, 60.0, 60.0]))
    damping: np.ndarray = field(default_factory=lambda: np.array([60.0, 60.0, 60.0, 2.0, 2.0, 2.0]))
    joint_damping: float = 0.5
    free_axes: tuple[int, ...] = ()

    def torque(self, state: RobotState, position: np.ndarray, rotation: np.ndarray,
               wrench_ff_world: np.ndarray | None = None) -> np.ndarray:
        """Joint torques (7,) [N·m] without gravity, tracking ``position`` [m] and ``rotation``."""
        wrench = np.empty(6)  # first the pose error [position; rotation vector], then the wrench
        np.subtract(position, state.ee_position, out=wrench[:3])
        rotation_error(rotation, state.ee_rotation, out=wrench[3:])
        wrench *= self.stiffness
        for axis in self.free_axes:
            wrench[axis] = 0.0
        wrench -= self.damping * state.ee_twist
        if wrench_ff_world is not None:
            wrench += wrench_ff_world
        tau = np.dot(state.jacobian.T, wrench)
        tau -= self.joint_damping * state.dq
        return tau
