"""The controllers by name, and for each the reference that holds a state where it is.

A task picks its controller by name from :data:`CONTROLLERS` (each class built with its papers'
defaults); a new controller is one file with a :class:`~tactex.control.controller.Controller`
subclass and one entry here. :func:`hold_reference` gives the reference each one tracks to keep
the tool still at a state's pose without pressing: the start of a smoke run, and the reference
type a controller expects, in one place. :class:`~tactex.control.safety.SafetyLayer` and
:class:`~tactex.control.nullspace.NullspacePosture` wrap another controller and are not listed.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from tactex.control.cartesian_impedance import CartesianImpedanceController
from tactex.control.controller import Controller
from tactex.control.ga_line_force import GaLineForceController
from tactex.control.joint_impedance import JointImpedanceController, JointTarget
from tactex.control.references import LineForceReference, PoseForceReference
from tactex.control.state import RobotState
from tactex.control.ufic import UficController
from tactex.control.va_ufic import VaUficController
from tactex.errors import ConfigError

__all__ = ["CONTROLLERS", "controller", "hold_reference"]

#: Controller name → class: TEC's geometric-algebra line and force impedance, UFIC, VA-UFIC with its
#: energy tanks, the Cartesian impedance baseline, and the joint impedance of the moves between phases.
CONTROLLERS: dict[str, type[Controller]] = {
    "ga_line_force": GaLineForceController,
    "ufic": UficController,
    "va_ufic": VaUficController,
    "cartesian_impedance": CartesianImpedanceController,
    "joint_impedance": JointImpedanceController,
}


def controller(name: str) -> Controller:
    """The registered controller ``name`` with its default parameters; a :class:`ConfigError` lists
    the valid names."""
    cls = CONTROLLERS.get(name)
    if cls is None:
        raise ConfigError(f"unknown controller '{name}'; valid: {', '.join(CONTROLLERS)}")
    return cls()


def _hold_line(state: RobotState) -> LineForceReference:
    # the line through the TCP along the tool axis (the outward normal is −tool z), no force
    return LineForceReference(state.ee_position.copy(), -state.ee_rotation[:, 2], force_n=0.0)


def _hold_pose(state: RobotState) -> PoseForceReference:
    return PoseForceReference(state.ee_position.copy(), state.ee_rotation.copy())


def _hold_joints(state: RobotState) -> JointTarget:
    return JointTarget(state.q.copy(), state.q.copy(), float(state.t), 0.0)


_HOLD: dict[type[Controller], Callable[[RobotState], Any]] = {
    GaLineForceController: _hold_line,
    UficController: _hold_pose,
    VaUficController: _hold_pose,
    CartesianImpedanceController: _hold_pose,
    JointImpedanceController: _hold_joints,
}


def hold_reference(name: str, state: RobotState) -> Any:
    """The reference with which controller ``name`` holds the tool at ``state``'s pose (joint
    posture, for the joint impedance) without a contact force."""
    if name not in CONTROLLERS:
        raise ConfigError(f"unknown controller '{name}'; valid: {', '.join(CONTROLLERS)}")
    return _HOLD[CONTROLLERS[name]](state)
