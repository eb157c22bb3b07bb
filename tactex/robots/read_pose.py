"""The tool's pose read once from a Franka (or tactex twin), without taking control of the arm.

A capture needs where the camera was, ``base_T_tool · tool_T_camera``; the tool frame is tactex's
TCP (:func:`~tactex.robots.libfranka_backend.flange_T_tcp`), whatever end effector Desk has set:
the flange pose is recovered from the state as ``O_T_EE · F_T_EEᵀ⁻¹`` and composed with ours.
"""

from __future__ import annotations

import importlib.util

import numpy as np

from tactex.errors import MissingDependencyError, RobotError
from tactex.robots.libfranka_backend import flange_T_tcp
from tactex.robots.scheduling import kept_scheduling
from tactex.sim.tool import ToolGeometry

__all__ = ["base_T_tool_from_state", "read_tool_pose"]


def _matrix(values) -> np.ndarray:
    """A column-major libfranka 4×4 (16 floats) as a (4, 4) array."""
    return np.asarray(values, dtype=float).reshape(4, 4).T


def base_T_tool_from_state(state, tool: ToolGeometry) -> np.ndarray:
    """base_T_tool (4, 4) [m] of tactex's TCP from a libfranka ``RobotState``."""
    base_T_flange = _matrix(state.O_T_EE) @ np.linalg.inv(_matrix(state.F_T_EE))
    return base_T_flange @ flange_T_tcp(tool)


def read_tool_pose(robot_ip: str, tool: ToolGeometry | None = None) -> np.ndarray:
    """base_T_tool (4, 4) [m] read once from the robot at ``robot_ip`` (the brakes may stay closed)."""
    if importlib.util.find_spec("pylibfranka") is None:
        raise MissingDependencyError("pylibfranka", "franka", "Reading the camera pose from the robot (--robot-ip)")
    import pylibfranka

    try:
        with kept_scheduling():  # libfranka raises the thread to real time when it connects
            robot = pylibfranka.Robot(robot_ip, pylibfranka.RealtimeConfig.kIgnore)
            state = robot.read_once()
            del robot  # the connection closes here, inside the block
    except Exception as exc:
        raise RobotError(f"cannot read the state of the Franka at {robot_ip} ({exc}): check the FCI address and "
                         "that FCI is activated in Desk") from exc
    return base_T_tool_from_state(state, tool or ToolGeometry())
