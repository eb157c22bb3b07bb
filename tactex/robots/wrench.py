"""Where the contact wrench comes from on a real robot: one small interface, two sources.

- :class:`FrankaWrenchSource`: the arm's own estimate ``K_F_ext_hat_K`` (from the joint torque
  sensors and the model; VA-UFIC's setting), in the stiffness frame K (the end effector set with
  ``set_EE``: our tool frame at the TCP). libfranka's sign (robot_state.h): "forces applied by the
  robot to the environment are positive", which is our convention already.
- :class:`NetFTWrenchSource`: an ATI Net F/T at the wrist (TEC's setting), its reading in the
  sensor frame calibrated for the tool by :class:`~tactex.sim.ft_sensor.FTSensorModel` (the tool's
  weight removed, moved to the TCP). A stream that stops gives NaN: the safety layer bridges short
  dropouts and backs off when the sensor is lost.

Every source returns the wrench the tool exerts on the environment at the TCP in the tool frame
[f (N), m (N·m)], as :attr:`tactex.RobotState.wrench_tool`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from tactex.robots.netft import NetFTClient
from tactex.sim.ft_sensor import FTSensorModel

__all__ = ["FrankaWrenchSource", "NetFTWrenchSource", "WrenchSource"]


class WrenchSource(ABC):
    """Base class of the wrench sources (see the module docstring)."""

    name = "wrench"

    def start(self, world_R_tool: np.ndarray | None = None) -> None:  # noqa: B027 (optional hook)
        """Open the stream (called once, out of contact, before torque control starts)."""

    def prefetch(self, world_R_tool: np.ndarray | None = None) -> None:  # noqa: B027 (optional hook)
        """Read what the sensor has sent so far, and prepare the next tick's wrench with the tool
        orientation ``world_R_tool`` of the state just answered. Called after each command is sent
        and before the next state is read, so the I/O and arithmetic run while the robot executes,
        not between a state and its command."""

    @abstractmethod
    def wrench_tool(self, franka_state, world_R_tool: np.ndarray) -> np.ndarray:
        """Contact wrench (6,) [N, N·m] at the TCP in the tool frame for this tick; NaN when lost."""

    def stats(self) -> dict:
        """Counters for metrics.json."""
        return {}

    def close(self) -> None:  # noqa: B027 (optional hook)
        """Stop the stream (idempotent)."""


class FrankaWrenchSource(WrenchSource):
    """Franka's estimated external wrench ``K_F_ext_hat_K`` (see the module docstring)."""

    name = "franka"

    def wrench_tool(self, franka_state, world_R_tool: np.ndarray) -> np.ndarray:
        return np.asarray(franka_state.K_F_ext_hat_K, dtype=float)


class NetFTWrenchSource(WrenchSource):
    """A Net F/T at the wrist whose axes are the tool's (as the sim's sensor: the tool frame is the
    flange turned −45° about z), the TCP ``tcp_offset_m`` along its z axis.

    Args:
        client: the stream (not started).
        tool_mass_kg, tool_com_m: the tool below the sensor (mass [kg], centre of mass in the sensor
            frame [m]) whose weight is removed; the client's tare removes the bias at the start pose,
            so the weight is added back for that pose (``start_rotation``).
        tcp_offset_m: TCP distance along the sensor z axis [m].
    """

    name = "netft"

    def __init__(self, client: NetFTClient, tool_mass_kg: float, tool_com_m, tcp_offset_m: float) -> None:
        self.client = client
        self.model = FTSensorModel(tool_mass_kg, tool_com_m, tcp_offset_m)
        self._tare_weight = np.zeros(6)
        self._next: np.ndarray | None = None  # the wrench prepared by prefetch() for the next tick
        self.lost_ticks = 0

    def start(self, world_R_tool: np.ndarray | None = None) -> None:
        """Start the stream and tare (out of contact). The tare removes the sensor's bias and the
        tool's weight at the start pose; given that pose's ``world_R_tool``, the weight is put back
        so that the weight compensation holds at every other orientation."""
        self.client.start()
        if world_R_tool is not None:
            # with no contact the sensor reads minus the tool's weight w = m·Rᵀg and its moment c × w
            w = self.model.mass * (np.asarray(world_R_tool, dtype=float).T @ self.model.gravity)
            self._tare_weight = np.concatenate([-w, -np.cross(self.model.com, w)])

    def prefetch(self, world_R_tool: np.ndarray | None = None) -> None:
        """Read the socket and, given the orientation, compensate the newest record for the tool's
        weight now. The state read next is at most one cycle later: the weight's direction in the
        sensor frame then differs by the arm's rotation in that cycle (a milliradian at 1 rad/s, a
        few millinewtons for this tool), less than the record's own age."""
        self.client.poll()
        self._next = None if world_R_tool is None else self._measure(world_R_tool)

    def _measure(self, world_R_tool: np.ndarray) -> np.ndarray:
        # the socket was read by prefetch() less than one cycle ago, as the robot state's age
        raw, _age = self.client.latest(poll=False)
        if not np.isfinite(raw[0]):
            return raw
        raw = raw + self._tare_weight
        return self.model.measure(raw[:3], raw[3:], world_R_tool)

    def wrench_tool(self, franka_state, world_R_tool: np.ndarray) -> np.ndarray:
        """The wrench prefetched for this tick, else the newest record compensated at ``world_R_tool``."""
        wrench, self._next = self._next, None
        if wrench is None:
            wrench = self._measure(world_R_tool)
        if not np.isfinite(wrench[0]):
            self.lost_ticks += 1
        return wrench

    def stats(self) -> dict:
        return {"ft_records": self.client.records, "ft_dropouts": self.client.dropouts,
                "ft_status_errors": self.client.status_errors, "ft_lost_ticks": self.lost_ticks}

    def close(self) -> None:
        self.client.close()
