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
    """

    dt: float

    def reset(self, seed: int | None = None) -> RobotState: ...

    def state(self) -> RobotState: ...

    def apply_torque(self, tau: np.ndarray) -> None: ...

    def step(self) -> RobotState: ...

    def camera_frame(self) -> CameraFrame | None: ...

    def close(self) -> None: ...
