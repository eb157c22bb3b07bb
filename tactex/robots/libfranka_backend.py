"""The real Franka through libfranka (``pylibfranka``) — not implemented yet.

The class exists so that code can name the real-robot backend and get a clear error: without the
optional extra it raises :class:`~tactex.errors.MissingDependencyError` with the install command;
with it, a :class:`~tactex.errors.TactexError` saying the 1 kHz torque loop is still to be written
(the protocol it must implement is :class:`tactex.robots.backend.RobotBackend`).
"""

from __future__ import annotations

import importlib.util

from tactex.errors import MissingDependencyError, TactexError

__all__ = ["LibfrankaBackend"]


class LibfrankaBackend:
    """Placeholder for the libfranka backend (see the module docstring).

    Args:
        robot_ip: the robot's FCI address, e.g. "172.16.0.2".
    """

    def __init__(self, robot_ip: str) -> None:
        if importlib.util.find_spec("pylibfranka") is None:
            raise MissingDependencyError("pylibfranka", "franka", "the real-robot backend")
        raise TactexError(
            f"the libfranka backend (robot {robot_ip!r}) is not implemented yet; use "
            "tactex.robots.MujocoBackend, or implement tactex.robots.backend.RobotBackend on pylibfranka"
        )
