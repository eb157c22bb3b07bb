"""The protocol every robot backend (MuJoCo simulation, libfranka) implements."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from tactex.control.state import RobotState
from tactex.perception.frame import CameraFrame

__all__ = ["RobotBackend"]


@runtime_checkable
class RobotBackend(Protocol):
    """A torque-controlled arm with a wrist F/T sensor and a wrist RGB-D camera.

    ``dt`` is the control period [s] (1 ms for a Franka). ``apply_torque`` takes torques
    *without* gravity: like the Franka firmware, the backend adds gravity compensation.

    Optional hook (not part of the protocol's required methods, so a backend without it still
    conforms): ``pause() -> None``, called before wall-clock work longer than a control cycle between
    two ticks (planning, a model build). A backend whose robot needs a command every cycle ends torque
    control there and starts it again at the next tick (:meth:`LibfrankaBackend.pause`); a simulated
    robot, which waits anyway, has a no-op (:meth:`MujocoBackend.pause`). A backend without it is
    treated as one that waits (:meth:`tactex.robots.loop.ControlLoop.pause`).
    """

    dt: float

    def reset(self, seed: int | None = None) -> RobotState: ...

    def state(self) -> RobotState: ...

    def apply_torque(self, tau: np.ndarray) -> None: ...

    def step(self) -> RobotState: ...

    def camera_frame(self) -> CameraFrame | None: ...

    def close(self) -> None: ...
