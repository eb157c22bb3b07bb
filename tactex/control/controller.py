"""Base class of the controller family: state and reference in, joint torques out."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from tactex.control.state import RobotState

__all__ = ["Controller"]


class Controller(ABC):
    """A joint-torque controller. Pure numpy; knows nothing of the simulator.

    Subclasses implement :meth:`torque`. ``reset`` is called once before the first tick, with the
    state the robot is in, so that integrators and filters start from it. ``resume`` restarts a
    controller that was interrupted (a safety retreat, another controller in between) without
    giving back energy it had spent: a controller with energy tanks keeps their levels.
    """

    #: Short registry name (``ga_line_force``, ``ufic``, ``va_ufic``, ``cartesian_impedance`` ...).
    name: str = "controller"

    def reset(self, state: RobotState) -> None:  # noqa: B027 - optional hook
        """Clear internal states (integrators, filters, tanks) and start from ``state``."""

    def resume(self, state: RobotState) -> None:
        """Start again from ``state`` after an interruption: integrators, filters and set-point
        offsets restart as in :meth:`reset`, but stored energy (tanks) is kept, since refilling a
        tank that ran dry would create energy and defeat the passivity it guards. By default the
        same as :meth:`reset` (a controller without tanks has nothing to keep)."""
        self.reset(state)

    @abstractmethod
    def torque(self, state: RobotState, reference: Any) -> np.ndarray:
        """Joint torques (n,) [N·m] for this tick, gravity NOT included (the robot compensates it)."""

    def telemetry(self) -> dict[str, float]:
        """Scalars worth logging this tick (tank energies, gains, errors); empty by default."""
        return {}
