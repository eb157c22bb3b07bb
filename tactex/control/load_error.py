"""The robot's load error: a tool whose mass or centre of mass is set wrong in the robot.

A Franka compensates the gravity of the load it was told (Desk's end-effector settings); a tool heavier
or lighter than that hangs on the flange as an unmodelled force. The wrist F/T sensor does not see it
(it is calibrated with the tool as it is), so a force loop pressing with 10 N presses with 10 N plus the
error until its integrator has learned it, and learns it again after every lift-off.

While the arm holds still in free space the torque commanded to hold it is exactly what cancels that
force (plus the joints' static friction), once the share that moves the arm (M·q̈ + C·q̇) is taken off.
:class:`LoadErrorEstimator` averages it over such a hold and
turns it into a wrench at the TCP in the world frame, which the safety layer adds to every command
(:attr:`tactex.control.safety.SafetyLayer.load_wrench_world`) at whatever posture the arm takes.

Only a force that looks like a weight is taken: above ``deadband_n`` (below it, the joints' static
friction and the sensor's noise are as large) and within ``max_tilt_deg`` of the vertical. Anything else
(a hold that was touching something, friction) is reported and left alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tactex.control.state import RobotState
from tactex.errors import InputError

__all__ = ["LoadError", "LoadErrorEstimator"]

#: Standard gravity [m/s²], to state a load error as a mass.
G_M_S2 = 9.81


@dataclass(frozen=True)
class LoadError:
    """What a still hold says of the load.

    Attributes:
        wrench_world: (6,) [N, N·m] the wrench the robot must add at the TCP, world frame, rows
            [force; moment], to hold the tool as the robot's own compensation would if its load were set
            right (upwards for a tool heavier than set).
        n_samples: ticks averaged.
        accepted: the estimate looks like a weight and is large enough to act on.
        reason: why it was not accepted ("" when it was).
    """

    wrench_world: np.ndarray
    n_samples: int
    accepted: bool
    reason: str = ""

    @property
    def force_n(self) -> float:
        """Magnitude [N] of the force part."""
        return float(np.linalg.norm(self.wrench_world[:3]))

    @property
    def mass_kg(self) -> float:
        """The load error as a mass [kg]: positive when the tool is heavier than the robot was told."""
        return float(self.wrench_world[2]) / G_M_S2

    def describe(self) -> str:
        """One line for the terminal."""
        more = "heavier" if self.mass_kg > 0 else "lighter"
        if not self.accepted:
            return f"load check: {self.force_n:.2f} N at rest not compensated ({self.reason})"
        return (f"load check: the tool is {abs(self.mass_kg) * 1e3:.0f} g {more} than the robot's load "
                f"({self.force_n:.1f} N); compensated. Set the tool's mass and centre of mass in the robot "
                "(Desk: end effector) to remove it")


class LoadErrorEstimator:
    """Collects the commanded torque of a still hold in free space; :meth:`estimate` turns it into a
    :class:`LoadError`.

    Args:
        deadband_n: smaller forces [N] are not acted on (static friction and noise are as large).
        max_tilt_deg: a weight points down: a force further than this from the vertical [deg] is not one.
        max_joint_speed_rad_s: ticks with a faster joint [rad/s] are not a still hold and are skipped.
        max_contact_n: ticks with a larger F/T force [N] are touching something and are skipped.
        min_samples: fewer still ticks give no estimate.
    """

    def __init__(self, deadband_n: float = 0.5, max_tilt_deg: float = 30.0, max_joint_speed_rad_s: float = 0.2,
                 max_contact_n: float = 1.0, min_samples: int = 50) -> None:
        for name, value in (("deadband_n", deadband_n), ("max_tilt_deg", max_tilt_deg),
                            ("max_joint_speed_rad_s", max_joint_speed_rad_s), ("max_contact_n", max_contact_n)):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value)
                                                                                      and value > 0):
                raise InputError(f"the load check's {name} must be a positive number, got {value!r}")
        if isinstance(min_samples, bool) or not isinstance(min_samples, int) or min_samples < 1:
            raise InputError(f"the load check's min_samples must be a positive integer, got {min_samples!r}")
        self.deadband_n = float(deadband_n)
        self.max_tilt_deg = float(max_tilt_deg)
        self.max_joint_speed = float(max_joint_speed_rad_s)
        self.max_contact_n = float(max_contact_n)
        self.min_samples = min_samples
        self._tau_sum: np.ndarray | None = None
        self._jac_sum: np.ndarray | None = None
        self._n = 0
        self._pending: tuple[RobotState, np.ndarray] | None = None  # the last still tick, until its next state

    def add(self, state: RobotState, tau_command: np.ndarray) -> None:
        """One tick: the state and the torque [N·m] commanded from it (gravity left to the robot), in the
        order they happen. A command's share of the hold is what it did not spend on the arm's motion up
        to the next state (M·q̈ + C·q̇, q̈ from the two states' joint speeds), so the settle after a move
        counts while the arm still rings. Ticks where the arm is not still, touches something, or holds
        a non-finite number are skipped."""
        tau = np.asarray(tau_command, dtype=float)
        pending, self._pending = self._pending, None
        if pending is not None:
            before, tau_before = pending
            dt = float(state.t - before.t)
            if dt > 0 and np.isfinite(state.dq).all():
                accel = (state.dq - before.dq) / dt
                self._accumulate(tau_before - before.coriolis - before.mass_matrix @ accel, before.jacobian)
        if tau.shape != state.q.shape or not (np.isfinite(tau).all() and np.isfinite(state.jacobian).all()
                                              and np.isfinite(state.dq).all()):
            return
        if not np.all(np.abs(state.dq) < self.max_joint_speed):
            return
        if not float(np.linalg.norm(state.wrench_tool[:3])) < self.max_contact_n:
            return
        self._pending = (state, tau)

    def _accumulate(self, tau_hold: np.ndarray, jacobian: np.ndarray) -> None:
        if not (np.isfinite(tau_hold).all()):
            return
        if self._tau_sum is None:
            self._tau_sum = np.zeros_like(tau_hold)
            self._jac_sum = np.zeros_like(jacobian, dtype=float)
        self._tau_sum += tau_hold
        self._jac_sum += jacobian
        self._n += 1

    @property
    def n_samples(self) -> int:
        """Still ticks collected so far."""
        return self._n

    def estimate(self) -> LoadError | None:
        """The load error of the ticks collected; None with fewer than ``min_samples`` still ticks."""
        if self._n < self.min_samples or self._tau_sum is None or self._jac_sum is None:
            return None
        tau = self._tau_sum / self._n
        jac = self._jac_sum / self._n
        # the wrench at the TCP whose joint torques are the hold's (least squares: the redundant joint's
        # share, which no wrench at the TCP makes, is left out)
        wrench = np.linalg.lstsq(jac.T, tau, rcond=None)[0]
        force = float(np.linalg.norm(wrench[:3]))
        tilt = math.degrees(math.acos(min(1.0, abs(float(wrench[2])) / force))) if force > 0 else 0.0
        if not np.isfinite(wrench).all():
            return LoadError(np.zeros(6), self._n, False, "not finite")
        if force < self.deadband_n:
            return LoadError(wrench, self._n, False, f"below the {self.deadband_n:g} N dead band")
        if tilt > self.max_tilt_deg:
            return LoadError(wrench, self._n, False, f"{tilt:.0f}° from the vertical: not a weight (friction, a "
                             "touch?)")
        return LoadError(wrench, self._n, True)
