"""``TwinConfig``: the twin's object, tool, dirt and network addresses (the ``tactex twin`` options)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tactex.config import param
from tactex.errors import ConfigError
from tactex.perception.mount import mount_offset
from tactex.perception.twin_camera import TWIN_CAMERA_PORT
from tactex.robots.netft import NETFT_PORT
from tactex.sim.board import BESIDE_OBJECTS_XY_M, ChessBoard
from tactex.sim.scene import SceneConfig
from tactex.sim.tool import ToolGeometry

__all__ = ["TwinConfig"]


@dataclass(frozen=True)
class TwinConfig:
    """The twin: object, tool, dirt and network addresses (units in brackets)."""

    object_name: str = param("sine_panel", "object from the registry (tactex.sim.objects), or a part's mesh or "
                                           "scan file (.stl/.obj/.ply/.pcd/.npz) made a height-field object "
                                           "(tactex.sim.part)")
    units: str = param("m", "length unit of the --object FILE: m, mm or in")
    object_position: tuple[float, float, float] | None = param(
        None, "object position in the robot base frame [m]; default: the object's own placement (0.5 0 0; the cup "
        "0.42 0 0), as in tactex clean")
    object_rpy_deg: tuple[float, float, float] = param((0.0, 0.0, 0.0), "object orientation roll/pitch/yaw [deg]")
    marking: str | None = param(None, "dirt pattern (X, RLI, blobs, shapes, full); empty = the object's default; "
                                      "default: tactex clean's (X on a built-in object, a part file's own marking)")
    # the tool of tactex clean and wipe (tactex.tasks.world.SimWorldParams): the client declares it
    tool_stiffness_n_per_m: float = param(2500.0, "sponge stiffness along the tool axis [N/m]")
    tool_damping_ratio: float = param(0.7, "sponge damping, fraction of critical [-]")
    tool_friction: float = param(0.4, "pad–surface Coulomb friction coefficient [-]")
    # one sponge, one option: tactex clean's wear model takes the same radius as --pad-radius-m
    tool_pad_radius_m: float = param(0.025, "sponge radius [m]", option="pad_radius_m",
                                     aliases=("--tool-pad-radius-m",))
    tool_pad_shape: str = param("sphere", "pad shape: sphere (domed sponge) or cylinder (flat)")
    payload_mass_kg: float = param(0.0, "extra mass hung at the TCP, unknown to the F/T calibration [kg]")
    dirt_resolution_m: float = param(0.002, "dirt grid cell size [m]")
    preston_coefficient: float = param(5e-3, "Preston wear coefficient [1/(Pa·m)]")
    dirt_force_threshold_n: float = param(2.0, "normal force below which no dirt is removed [N]")
    contact_sample_ticks: int = param(5, "ticks between dirt updates from the pad's contacts [-]")
    hostname: str = param("127.0.0.1", "address the robot (TCP 1337, gripper 1338) and the Net F/T serve on")
    ft_port: int = param(NETFT_PORT, "UDP port of the Net F/T stream")
    ft_rate_hz: float = param(1000.0, "Net F/T record rate [Hz]")
    camera_port: int = param(TWIN_CAMERA_PORT, "TCP port of the wrist camera's RGB-D frames (0: no camera)",
                             option="port_camera", aliases=("--camera-port",))
    camera_width: int = param(640, "wrist camera image width [px] (a RealSense D435's colour stream: 640)")
    camera_height: int = param(480, "wrist camera image height [px]")
    camera_rate_hz: float = param(30.0, "wrist camera frame rate while a client streams [Hz]")
    camera_mount_shift_mm: tuple[float, float, float] = param(
        (0.0, 0.0, 0.0), "the wrist camera moved off tactex's nominal mount, in its optical frame (x right, y down, z "
        "forward) [mm]: a mount a client must calibrate (tactex calibrate hand-eye --robot franka)")
    camera_mount_tilt_deg: tuple[float, float, float] = param(
        (0.0, 0.0, 0.0), "the wrist camera turned off tactex's nominal mount, x-y-z Euler angles in its optical frame "
        "[deg]")
    board: tuple[int, int] | None = param(
        None, "a chessboard lying on the table, seen by the wrist camera (for tactex calibrate hand-eye): its inner "
              "corners COLS ROWS, e.g. 9 6 (default: none)")
    board_square_m: float = param(0.025, "the board's square edge [m]")
    board_centre_m: tuple[float, float] = param(BESIDE_OBJECTS_XY_M, "where the board's centre lies on the table, x y "
                                                                     "in the robot base frame [m] (beside the object)")
    status_file: str = param("", "JSON file rewritten every status_period_s with the twin's status ('' = none)")
    status_period_s: float = param(0.5, "period of the status file [s]")
    realtime_factor: float = param(1.0, "simulated seconds per wall-clock second the twin aims at (it paces "
                                        "itself with sleeps; 0 = as fast as it can)")
    command_window_ms: float = param(
        0.5, "how long after each state the twin waits for the client's command before it steps [ms] (scaled with "
             "--realtime-factor above 1): the budget tactex plans for one FCI iteration (receive, compute, send; "
             "docs/real_robot.md); a later command is used a cycle late and counts against "
             "control_command_success_rate")
    joint_friction_residual: float = param(
        0.0, "fraction of franky-sim's dry joint friction (MuJoCo frictionloss 0.25–1.14 N·m) left on the arm: a "
             "real Franka adds gravity and friction to the commanded torques (libfranka's Torques are 'without "
             "gravity and friction'), franky-sim only gravity; 1 = franky-sim as it is [-]")
    ext_wrench_on_robot: bool = param(False, "report K_F_ext_hat_K as the wrench ON the robot (the opposite of "
                                             "libfranka's documented sign), for clients written that way")

    def __post_init__(self) -> None:
        from tactex.sim.part import is_part_file, resolve_object_or_part

        object.__setattr__(self, "object_name", resolve_object_or_part(self.object_name))  # 'Plate' is plate
        if self.marking is None:
            object.__setattr__(self, "marking", "" if is_part_file(self.object_name) else "X")
        self.scene_config()  # object, marking, tool and dirt checks
        if not (isinstance(self.ft_port, int) and 0 <= self.ft_port < 65536):
            raise ConfigError(f"ft_port must be a UDP port in 0..65535 (0: any free one), got {self.ft_port!r}")
        if not (isinstance(self.camera_port, int) and 0 <= self.camera_port < 65536):
            raise ConfigError(f"camera_port must be a TCP port in 0..65535 (0: no camera), got {self.camera_port!r}")
        if self.camera_port in (1337, 1338):
            raise ConfigError(f"camera_port {self.camera_port} is franky-sim's (1337 robot, 1338 gripper): pick "
                              "another")
        for name in ("camera_width", "camera_height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 8 <= v <= 4096:
                raise ConfigError(f"{name} must be a whole number of pixels in 8..4096, got {v!r}")
        if not (math.isfinite(self.camera_rate_hz) and 0.1 <= self.camera_rate_hz <= 120.0):
            raise ConfigError(f"camera_rate_hz must be in [0.1, 120] Hz, got {self.camera_rate_hz!r}")
        if not self.hostname.strip():
            raise ConfigError("hostname must be an address, e.g. 127.0.0.1")
        for name, lo in (("ft_rate_hz", 1.0), ("status_period_s", 0.01)):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= lo):
                raise ConfigError(f"{name} must be ≥ {lo:g}, got {v!r}")
        if not (math.isfinite(self.joint_friction_residual) and 0.0 <= self.joint_friction_residual <= 1.0):
            raise ConfigError(f"joint_friction_residual must be in [0, 1], got {self.joint_friction_residual!r}")
        if not (math.isfinite(self.command_window_ms) and 0.0 < self.command_window_ms < 1.0):
            raise ConfigError(f"command_window_ms must be in (0, 1) ms (the client's share of the 1 ms state "
                              f"period at real time), got {self.command_window_ms!r}")
        for name, hi in (("camera_mount_shift_mm", 50.0), ("camera_mount_tilt_deg", 20.0)):
            v = getattr(self, name)
            if len(v) != 3 or not all(math.isfinite(x) and abs(x) <= hi for x in v):
                raise ConfigError(f"{name} must be three numbers within ±{hi:g}, got {v!r}")
        if self.board is not None:
            if not self.camera_port:
                raise ConfigError("the board is seen only by the twin's camera: give it a camera port (--port-camera)")
            if len(self.board_centre_m) != 2 or not all(math.isfinite(x) for x in self.board_centre_m):
                raise ConfigError(f"board_centre_m must be x y [m], got {self.board_centre_m!r}")
            self.chess_board()  # its corners and square edge
        if not (math.isfinite(self.realtime_factor) and 0.0 <= self.realtime_factor <= 100.0):
            raise ConfigError(f"realtime_factor must be in [0, 100] (0: unpaced), got {self.realtime_factor!r}")

    def chess_board(self) -> ChessBoard | None:
        """The board on the twin's table (None: no board)."""
        if self.board is None:
            return None
        cols, rows = self.board
        return ChessBoard(cols=cols, rows=rows, square_m=self.board_square_m,
                          centre_m=(float(self.board_centre_m[0]), float(self.board_centre_m[1]), 0.0))

    def camera_mount_error(self) -> np.ndarray:
        """(4, 4) the served camera's optical frame in the nominal one's: nominal_T_served [m]."""
        return mount_offset(self.camera_mount_tilt_deg, np.asarray(self.camera_mount_shift_mm, dtype=float) * 1e-3)

    def scene_config(self) -> SceneConfig:
        """The :class:`SceneConfig` of the same object, tool and dirt (validates them)."""
        return SceneConfig(
            object_name=self.object_name, object_units=self.units, object_position=self.object_position,
            object_rpy_deg=self.object_rpy_deg,
            marking=self.marking, tool_stiffness_n_per_m=self.tool_stiffness_n_per_m,
            tool_damping_ratio=self.tool_damping_ratio, tool_friction=self.tool_friction,
            tool_pad_radius_m=self.tool_pad_radius_m, tool_pad_shape=self.tool_pad_shape,
            payload_mass_kg=self.payload_mass_kg, dirt_resolution_m=self.dirt_resolution_m,
            preston_coefficient=self.preston_coefficient, dirt_force_threshold_n=self.dirt_force_threshold_n,
            contact_sample_ticks=self.contact_sample_ticks,
        )

    @property
    def tool(self) -> ToolGeometry:
        return self.scene_config().tool
