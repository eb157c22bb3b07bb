"""Which robot a task drives, and where its surface estimate comes from.

``--robot sim`` (default) is the MuJoCo world of :mod:`tactex.sim`; ``--robot franka`` a real
Franka (or ``tactex twin``) through :class:`~tactex.robots.libfranka_backend.LibfrankaBackend`.
The task code is the same: it gets a backend and a :class:`SurfaceVision`.

Vision: in simulation the camera's frames arrive through the backend and the estimate is made in
the loop (the simulated clock waits for it). On the real robot the estimate is made in the vision
process (:mod:`tactex.robots.vision_process`); the loop publishes the tool pose and picks up the
newest estimate, so a slow frame never delays a torque command.
"""

from __future__ import annotations

import os
import sys
from abc import ABC, abstractmethod
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from tactex.config import param
from tactex.errors import ConfigError, InputError, PolicyFault, RobotError, SensorFault, SurfaceNotFound
from tactex.perception.estimate import SurfaceEstimate
from tactex.perception.estimator import SurfaceEstimator, SurfaceEstimatorConfig
from tactex.perception.twin_camera import TWIN_CAMERA_PORT
from tactex.robots.libfranka_backend import FrankaConfig, connecting_line
from tactex.tasks.hand_eye import load_hand_eye

__all__ = [
    "ROBOT_STOPS",
    "InLoopVision",
    "NoVision",
    "ProcessVision",
    "RealRobotParams",
    "SurfaceVision",
    "end_on_robot",
    "load_hand_eye",
    "open_backend",
    "open_capture_camera",
    "open_vision",
    "stop_reason",
    "stopped_by_user",
    "twin_dirt_remaining",
]

#: What ends a run on a robot early and keeps its data: a libfranka error or lost link, a lost
#: sensor or vision process, a surface that is not where the plan expects it, a policy that broke its
#: contract, Ctrl-C (torque control has ended by the time they reach the task: a task pauses the loop
#: before it raises SurfaceNotFound or a PolicyFault).
ROBOT_STOPS = (RobotError, SensorFault, SurfaceNotFound, PolicyFault, KeyboardInterrupt)


def stop_reason(exc: BaseException) -> str:
    """The ``aborted`` entry of a run's metrics for one of :data:`ROBOT_STOPS`."""
    return f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__


def stopped_by_user(metrics: dict) -> bool:
    """Whether a run's metrics say Ctrl-C ended it (its ``aborted``, from :func:`stop_reason`)."""
    return str(metrics.get("aborted") or "").startswith(KeyboardInterrupt.__name__)


def end_on_robot(loop, exc: BaseException) -> str:
    """An error of ours that ends a run on a robot mid-task (a pose out of reach, a planning failure)
    ends it as :data:`ROBOT_STOPS` do: torque control ends (``loop.pause``: the robot holds itself
    while the run's data is written; a link already gone ended it already) and the run keeps what it
    recorded. Returns the ``aborted`` entry for its metrics."""
    try:
        loop.pause()
    except ROBOT_STOPS:
        pass
    return stop_reason(exc)


#: How often the loop asks whether the vision process is alive [ticks].
VISION_CHECK_TICKS = 100


@dataclass(frozen=True)
class RealRobotParams(FrankaConfig):
    """``--robot franka``: the robot (see FrankaConfig) and its camera."""

    robot_ip: str = param("", "the robot's FCI address, e.g. 172.16.0.2 (127.0.0.1 for tactex twin)")
    camera: str = param("auto", "wrist camera: twin (the frames tactex twin serves: clean and calibrate only), "
                                "realsense, sim (a vision process rendering its own copy of the twin's scene: the "
                                "wipe's surface estimate), none, or auto (sim on a loopback robot address, realsense "
                                "otherwise); tactex clean captures its target with twin or realsense")
    camera_port: int = param(TWIN_CAMERA_PORT, "--camera twin: the twin's camera TCP port (tactex twin --port-camera)")
    serial: str = param("", "--camera realsense: the RealSense's serial number (default: the first one connected)")
    playback: str = param("", "--camera realsense: play this RealSense recording (.db3 or .bag) instead of a live "
                              "camera")
    capture_frames: int = param(3, "frames read at each capture; the last one is used (those before let the exposure "
                                   "and the arm settle) [-]")
    hand_eye: str = param("", "hand-eye calibration: a .npy or .json 4×4 tool_T_camera (camera optical frame in the "
                              "tool frame, metres); empty: the nominal mount of the tactex tool")

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.camera not in ("auto", "twin", "sim", "realsense", "none"):
            raise ConfigError(f"camera must be auto, twin, sim, realsense or none, got {self.camera!r}")
        if not (isinstance(self.camera_port, int) and 0 < self.camera_port < 65536):
            raise ConfigError(f"camera_port must be a TCP port in 1..65535, got {self.camera_port!r}")
        n = self.capture_frames
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 100:
            raise ConfigError(f"capture_frames must be a whole number in 1..100, got {n!r}")
        if self.playback and self.camera != "realsense":
            raise ConfigError("--playback plays a RealSense recording: give it with --camera realsense")
        if self.playback:
            from pathlib import Path

            if not Path(self.playback).is_file():
                raise InputError(f"--playback '{self.playback}' is not a file (give a RealSense recording, .db3 "
                                 "or .bag)")
        if self.hand_eye:
            load_hand_eye(self.hand_eye)

    @property
    def camera_kind(self) -> str:
        if self.camera != "auto":
            return self.camera
        return "sim" if self.ignore_realtime and self.realtime == "auto" else "realsense"

    def franka(self) -> FrankaConfig:
        """The backend's part of these parameters."""
        names = {f.name for f in fields(FrankaConfig)}
        return FrankaConfig(**{n: getattr(self, n) for n in names})


class SurfaceVision(ABC):
    """The task's view of the wrist camera: the newest surface estimate, if a new one arrived."""

    @abstractmethod
    def update(self, state) -> SurfaceEstimate | None:
        """Called once per tick with the latest state (a task may call it after the tick's command is
        sent, to make the next tick's reference); a new estimate or None."""

    def publish(self, state) -> None:  # noqa: B027 (optional hook)
        """Tell the camera where the tool is at ``state`` (to pose its next frame). Called once per
        tick after the tick's command is sent: nothing the torque needs waits for it."""

    def stats(self) -> dict[str, Any]:
        return {}

    def close(self) -> None:  # noqa: B027 (optional hook)
        """Release the camera (idempotent)."""


class InLoopVision(SurfaceVision):
    """Simulation: the backend's frames, estimated in the loop."""

    def __init__(self, backend, estimator: SurfaceEstimator) -> None:
        self.backend = backend
        self.estimator = estimator

    def update(self, state) -> SurfaceEstimate | None:
        frame = self.backend.camera_frame()
        if frame is None:
            return None
        return self.estimator.estimate(frame, state.ee_pose)


class ProcessVision(SurfaceVision):
    """The real robot: estimates from the vision process; a dead process is a SensorFault."""

    def __init__(self, process) -> None:
        self.process = process
        self._ticks = 0

    def update(self, state) -> SurfaceEstimate | None:
        self._ticks += 1
        if self._ticks % VISION_CHECK_TICKS == 0:
            self.process.check()
        return self.process.latest()

    def publish(self, state) -> None:
        self.process.publish_tool(state.t, state.ee_rotation, state.ee_position)

    def stats(self) -> dict[str, Any]:
        return {"vision_process_estimates": self.process.estimates}

    def close(self) -> None:
        self.process.close()


class NoVision(SurfaceVision):
    """No camera: the task runs on touch alone."""

    def update(self, state) -> SurfaceEstimate | None:
        return None


def open_backend(scene_config, robot: RealRobotParams | None, *, announce: bool = False):
    """The task's robot: the MuJoCo scene of ``scene_config``, or the real Franka with that scene's tool
    (its kinematics serve the transit IK). ``announce``: say on stderr that the robot is being connected,
    since an address where nothing answers holds libfranka silent for a minute."""
    if robot is None:
        from tactex.robots.mujoco_backend import MujocoBackend

        return MujocoBackend(scene_config)
    from tactex.robots.libfranka_backend import LibfrankaBackend

    if announce:
        print(f"robot: {connecting_line(robot.robot_ip)}", file=sys.stderr, flush=True)
    return LibfrankaBackend(robot.franka(), tool=scene_config.tool, ik_scene=scene_config)


def check_estimate_camera(robot: RealRobotParams | None) -> None:
    """Refuse a camera that cannot feed a surface estimate (the wipe's vision) before the robot is touched."""
    if robot is not None and robot.camera_kind == "twin":
        raise ConfigError("--camera twin serves tactex clean's captures and calibrate's views; a surface estimate "
                          "on the twin comes from --camera sim (a vision process rendering the twin's scene)")


def open_vision(backend, estimator_config: SurfaceEstimatorConfig, scene_config, robot: RealRobotParams | None,
                rate_hz: float = 30.0) -> SurfaceVision:
    """The task's vision: in-loop in simulation; for a real robot the vision process with the
    twin's simulated camera (``scene_config``'s object) or a RealSense posed by ``hand_eye``."""
    if robot is None:
        return InLoopVision(backend, SurfaceEstimator(estimator_config))
    check_estimate_camera(robot)
    kind = robot.camera_kind
    if kind == "none":
        return NoVision()
    from dataclasses import asdict

    from tactex.robots.vision_process import VisionProcess

    cpus = sorted(set(range(os.cpu_count() or 1)) - {robot.control_cpu}) if robot.control_cpu >= 0 else []

    est = {f.name: getattr(estimator_config, f.name) for f in fields(estimator_config)}
    if kind == "sim":
        scene = {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(scene_config).items()}
        source = {"kind": "sim", "scene": scene, "estimator": est, "rate_hz": rate_hz, "cpus": cpus}
    else:
        if robot.hand_eye:
            tool_T_camera = load_hand_eye(robot.hand_eye)
        else:
            tool_T_camera = nominal_tool_T_camera(scene_config)
        source = {"kind": "realsense", "tool_T_camera": tool_T_camera.tolist(), "estimator": est, "rate_hz": rate_hz,
                  "cpus": cpus}
    return ProcessVision(VisionProcess(source))


def nominal_tool_T_camera(scene_config) -> np.ndarray:
    """The camera's pose in the tool frame on tactex's tool (the simulated mount)."""
    from tactex.robots.mujoco_backend import MujocoBackend
    from tactex.robots.vision_process import camera_mount

    sim = MujocoBackend(scene_config)
    try:
        return camera_mount(sim)
    finally:
        sim.close()


def open_capture_camera(robot: RealRobotParams, scene_config, tool_pose):
    """The frame source of the clean's captures on a robot (``--camera twin`` or ``realsense``), each frame posed
    by the tool pose the robot reports (``tool_pose() -> world_T_tool``, read when the frame arrives: the arm
    holds still meanwhile) and the hand-eye calibration (``--hand-eye``; the tactex tool's nominal mount without
    one)."""
    from tactex.perception.mount import CameraMount

    kind = robot.camera
    if kind not in ("twin", "realsense"):
        raise ConfigError(f"clean on a robot captures its target with --camera twin (tactex twin's camera) or "
                          f"--camera realsense, or takes it from --cloud FILE; got --camera {kind}")
    tool_T_camera = load_hand_eye(robot.hand_eye) if robot.hand_eye else nominal_tool_T_camera(scene_config)
    mount = CameraMount(tool_T_camera)
    if kind == "twin":
        from tactex.perception.twin_camera import TwinCameraSource, twin_status

        twin_status(robot.robot_ip, robot.camera_port)  # its port answers before the arm moves to the capture
        return TwinCameraSource(robot.robot_ip, robot.camera_port, mount=mount, tool_pose_provider=tool_pose)
    from tactex.perception.realsense import RealSenseSource

    return RealSenseSource(mount=mount, tool_pose_provider=tool_pose, serial=robot.serial or None,
                           playback=robot.playback or None)


def twin_dirt_remaining(robot: RealRobotParams):
    """``f() -> the fraction of the marking left by the twin's own count`` for a run on tactex twin with its
    camera (``--camera twin``), else None (a real robot does not know its dirt)."""
    if robot.camera != "twin":
        return None
    from tactex.perception.twin_camera import twin_status

    def remaining() -> float:
        return float(twin_status(robot.robot_ip, robot.camera_port)["dirt_remaining_fraction"])

    return remaining
