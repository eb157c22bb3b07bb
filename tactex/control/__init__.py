"""tactex.control: robot state, the controller family and its safety layer.

Controllers (one file each, one base class :class:`Controller`): TEC's geometric-algebra
line-and-force impedance (:class:`GaLineForceController`), unified force-impedance control
(:class:`UficController`), VA-UFIC with energy tanks (:class:`VaUficController`) and a plain
Cartesian impedance baseline (:class:`CartesianImpedanceController`). Wrap any of them in
:class:`SafetyLayer` before sending torques to a robot. :class:`FrictionCompensator` (not in
the papers) feeds the measured tangential contact force forward through VA-UFIC's impedance tank.
"""

from tactex.control.alignment import (
    AlignmentShaper,
    alignment_coefficient,
    contact_alignment,
    force_shaping,
    rho_align_rate,
)
from tactex.control.cartesian_impedance import CartesianImpedanceController, CartesianImpedanceParams
from tactex.control.controller import Controller
from tactex.control.energy_tank import EnergyTank, ForceTank, ImpedanceTank, TankStep, smooth_fill_gate, smooth_valve
from tactex.control.friction import FrictionCompensator, FrictionCompensatorParams
from tactex.control.ga_line_force import GaLineForceController, GaLineForceParams
from tactex.control.references import LineForceReference, PoseForceReference
from tactex.control.safety import FRANKA_Q_MAX, FRANKA_Q_MIN, FRANKA_TAU_MAX, SafetyEvent, SafetyLayer, SafetyLimits
from tactex.control.state import RobotState
from tactex.control.ufic import UficController, UficParams
from tactex.control.va_ufic import PortFeedforward, VaUficController, VaUficParams, desired_rotation_from_normal

__all__ = [
    "FRANKA_Q_MAX",
    "FRANKA_Q_MIN",
    "FRANKA_TAU_MAX",
    "AlignmentShaper",
    "CartesianImpedanceController",
    "CartesianImpedanceParams",
    "Controller",
    "EnergyTank",
    "ForceTank",
    "FrictionCompensator",
    "FrictionCompensatorParams",
    "GaLineForceController",
    "GaLineForceParams",
    "ImpedanceTank",
    "LineForceReference",
    "PortFeedforward",
    "PoseForceReference",
    "RobotState",
    "SafetyEvent",
    "SafetyLayer",
    "SafetyLimits",
    "TankStep",
    "UficController",
    "UficParams",
    "VaUficController",
    "VaUficParams",
    "alignment_coefficient",
    "contact_alignment",
    "desired_rotation_from_normal",
    "force_shaping",
    "rho_align_rate",
    "smooth_fill_gate",
    "smooth_valve",
]
