"""The robot state every controller reads, from the simulator or from libfranka."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["RobotState"]


@dataclass(frozen=True, slots=True)
class RobotState:
    """One snapshot of a torque-controlled arm (n joints), in SI units.

    Attributes:
        t: time [s].
        q: (n,) joint positions [rad].
        dq: (n,) joint velocities [rad/s].
        tau_measured: (n,) measured joint torques [N·m].
        ee_position: (3,) tool centre point (TCP) in the world frame [m].
        ee_rotation: (3, 3) rotation world_R_tool (columns: tool axes in the world; tool z points
            from the flange into the surface).
        ee_twist: (6,) TCP twist in the world frame [v (m/s), ω (rad/s)].
        jacobian: (6, n) geometric Jacobian of the TCP in the world frame, rows [linear; angular].
        mass_matrix: (n, n) joint-space inertia [kg·m²].
        coriolis: (n,) Coriolis and centrifugal torques C(q, dq)·dq [N·m].
        gravity: (n,) gravity torques g(q) [N·m].
        wrench_tool: (6,) contact wrench the tool exerts on the environment, at the TCP, in the
            tool frame [f (N), m (N·m)]; pressing along the tool axis gives f_z > 0. From the
            wrist F/T sensor, gravity of the tool compensated.
    """

    t: float
    q: np.ndarray
    dq: np.ndarray
    tau_measured: np.ndarray
    ee_position: np.ndarray
    ee_rotation: np.ndarray
    ee_twist: np.ndarray
    jacobian: np.ndarray
    mass_matrix: np.ndarray
    coriolis: np.ndarray
    gravity: np.ndarray
    wrench_tool: np.ndarray

    @property
    def n_joints(self) -> int:
        return int(self.q.shape[0])

    @property
    def ee_pose(self) -> np.ndarray:
        """(4, 4) world_T_tool: the TCP pose as a homogeneous transform."""
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = self.ee_rotation, self.ee_position
        return pose

    @property
    def wrench_world(self) -> np.ndarray:
        """Contact wrench rotated into the world frame [f, m] (moments about the TCP)."""
        rot = self.ee_rotation
        return np.concatenate([rot @ self.wrench_tool[:3], rot @ self.wrench_tool[3:]])

    def is_finite(self) -> bool:
        """True when every array of the state is finite (the safety layer's first check).

        One running sum is finite iff every term is (NaN/inf propagate); a finite overflow to inf
        also reads as non-finite, which is the safe side. Much cheaper at 1 kHz than 12 checks.
        """
        total = self.t
        for a in (
            self.q, self.dq, self.tau_measured, self.ee_position, self.ee_rotation, self.ee_twist,
            self.jacobian, self.mass_matrix, self.coriolis, self.gravity, self.wrench_tool,
        ):
            total += float(a.sum())
        return bool(np.isfinite(total))
