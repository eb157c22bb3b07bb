"""Hand-eye calibration on a robot (``tactex calibrate hand-eye --robot franka``): the arm visits poses around a
chessboard lying on the table, and at each one the wrist camera's image and the robot's tool pose are read.

The poses are those of the simulated calibration (:func:`~tactex.tasks.hand_eye_calibration.calibrate_in_simulation`:
the camera, on its nominal mount, ``distance_m`` from the board's centre, tilted around it and rolled), reached
by joint moves under torque control from the IK of tactex's arm model. At each pose torque control pauses, as
for the clean's captures (the robot holds its posture itself, so the image and the pose read are of an arm at
rest), ``capture_frames`` frames are read and the last one's board is detected. The views then go through the
same solver and checks as in simulation. On tactex twin the board is the twin's (``tactex twin --board 9 6``)
and its camera may sit off the nominal mount (``--camera-mount-shift-mm``, ``--camera-mount-tilt-deg``), a mount
the calibration must find.

Taught poses (:func:`calibrate_taught`, ``--taught``): the user guides the arm by hand (the Franka's guiding
mode, torque control never started), and at each pose where the camera sees the board presses Enter; the tool
pose is read once from the robot and the frames from the camera.

Every error ends torque control (the backend closes); the views taken so far are in the error's message only as
their count: a calibration is redone, not resumed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from tactex.errors import ConfigError, InputError, RobotError, RunStopped, SensorFault, SimulationError
from tactex.sim.board import ChessBoard
from tactex.tasks.hand_eye_calibration import (
    HandEyeConfig,
    HandEyeResult,
    board_pose,
    detect_board,
    generated_tool_poses,
    solve_views,
)

__all__ = ["calibrate_on_robot", "calibrate_taught"]

#: Settling after each joint move before torque control pauses [s].
SETTLE_S = 0.5


def _check_camera(robot) -> None:
    if robot.camera not in ("twin", "realsense"):
        raise ConfigError(f"the calibration reads the wrist camera: give --camera twin (tactex twin's camera) or "
                          f"--camera realsense, got --camera {robot.camera}")


def _wrist_camera(robot, scene_cfg, tool_pose: Callable[[], np.ndarray]):
    """The robot's wrist camera (``--camera twin|realsense``). Its frames are posed by the nominal mount: only
    their colour images are used, with the tool poses the calibration reads itself."""
    from tactex.tasks.robot import open_capture_camera

    _check_camera(robot)
    return open_capture_camera(replace(robot, hand_eye=""), scene_cfg, tool_pose)


class _Views:
    """The views taken so far: base_T_tool and camera_T_board of each with the board found, and the poses
    skipped (index → why)."""

    def __init__(self, board: ChessBoard, say: Callable[[str], None]) -> None:
        self.board, self.say = board, say
        self.tools: list[np.ndarray] = []
        self.boards: list[np.ndarray] = []
        self.skipped: dict[int, str] = {}

    def take(self, i: int, label: str, camera, frames: int, base_T_tool) -> None:
        """View ``i`` (said as ``pose {label}``): the board in the last of ``frames`` frames of ``camera``, seen
        with the tool at ``base_T_tool`` (a pose, or a callable read after the frames)."""
        from tactex.tasks.capture import read_views

        try:
            frame = read_views(camera, frames, getattr(camera, "what", "the camera"))[-1]
        finally:
            camera.stop()
        tool = np.asarray(base_T_tool() if callable(base_T_tool) else base_T_tool, dtype=float)
        corners = None if frame.rgb is None else detect_board(frame.rgb, self.board)
        if corners is None:
            self.skipped[i] = "board not found"
            self.say(f"pose {label}: board not found (the whole board in view, evenly lit?)")
            return
        self.tools.append(tool)
        self.boards.append(board_pose(corners, self.board, frame.intrinsics))
        self.say(f"pose {label}: board found")

    def solve(self, n_targets: int, method: str, where: str) -> HandEyeResult:
        return solve_views(self.tools, self.boards, n_targets, self.skipped, self.board, method, self.say,
                           where=where)


def calibrate_on_robot(config: HandEyeConfig, board: ChessBoard, robot, *, scene_config=None,
                       note: Callable[[str], None] | None = None) -> HandEyeResult:
    """Calibrate the wrist camera of ``robot`` (:class:`~tactex.tasks.robot.RealRobotParams` with ``camera``
    twin or realsense) from views of ``board``, whose centre in the robot base frame aims the poses.
    ``scene_config``: the tool whose kinematics and nominal camera mount plan the poses (tactex's by default).
    Raises :class:`~tactex.errors.InputError` when too few views find the board."""
    from tactex.robots.loop import ControlLoop
    from tactex.sim.scene import SceneConfig
    from tactex.tasks.robot import nominal_tool_T_camera, open_backend

    _check_camera(robot)  # before the poses are planned
    scene_cfg = scene_config or SceneConfig()
    targets = generated_tool_poses(board, config, nominal_tool_T_camera(scene_cfg))
    opened: list = []
    camera = _wrist_camera(robot, scene_cfg, lambda: opened[0].state().ee_pose)
    try:
        backend = open_backend(scene_cfg, robot, announce=note is not None)
    except BaseException:
        camera.close()
        raise
    opened.append(backend)
    views = _Views(board, note or (lambda msg: None))
    try:
        loop = ControlLoop(backend)
        for i, target in enumerate(targets):
            try:
                q = backend.solve_ik(target[:3, 3], target[:3, :3])
            except SimulationError:
                views.skipped[i] = "out of the arm's reach"
                continue
            loop.move_joints(q, settle_s=SETTLE_S)
            loop.pause()  # the robot holds itself: the image and the pose are of an arm at rest
            views.take(i, f"{i + 1}/{len(targets)}", camera, robot.capture_frames, lambda: backend.state().ee_pose)
    except (RobotError, SensorFault) as exc:  # torque control has ended (the backend's fault handling)
        raise RunStopped(_stopped(exc, views)) from exc
    finally:
        camera.close()
        backend.close()
    return views.solve(len(targets), config.method,
                       f" at --board-centre-m {board.centre_m[0]:g} {board.centre_m[1]:g} in the robot base frame and")


def _stopped(exc: Exception, views) -> str:
    """What stopped a calibration after it started, and what is lost."""
    return (f"{type(exc).__name__}: {exc} (after {len(views.tools)} view(s) of the board; no hand-eye written: "
            "run the calibration again)")


def calibrate_taught(config: HandEyeConfig, board: ChessBoard, robot, *, ask: Callable[[str], str] = input,
                     scene_config=None, note: Callable[[str], None] | None = None) -> HandEyeResult:
    """Calibrate from poses a person teaches: ``ask(prompt)`` returns when the arm, guided by hand, rests where
    the camera sees the whole board ('' or anything else: take the view; ``done``: solve with the views taken;
    end of input (EOFError) also solves). The tool pose is read once per view (torque control never starts: the
    robot stays in its guiding mode). At most ``config.poses`` views are taken."""
    from tactex.robots.read_pose import read_tool_pose
    from tactex.sim.scene import SceneConfig

    scene_cfg = scene_config or SceneConfig()
    camera = _wrist_camera(robot, scene_cfg, lambda: np.eye(4))
    views = _Views(board, note or (lambda msg: None))
    ended = "'done'"
    try:
        for i in range(config.poses):
            try:
                answer = ask(f"pose {i + 1}/{config.poses}: guide the arm until the camera sees the whole board, let "
                             "it rest, press Enter ('done' to solve now): ")
            except EOFError:
                ended = "the end of the input"
                break
            if answer.strip().lower() == "done":
                break
            views.take(i, f"{i + 1}", camera, robot.capture_frames, read_tool_pose(robot.robot_ip, scene_cfg.tool))
    except (RobotError, SensorFault) as exc:
        raise RunStopped(_stopped(exc, views)) from exc
    finally:
        camera.close()
    if not views.tools and not views.skipped:
        raise InputError(f"no pose was taught: {ended} came before the first one. --taught asks for each pose on "
                         "the terminal (Enter takes a view): run it where you can answer, or give it one line per "
                         "pose on its input")
    return views.solve(len(views.tools) + len(views.skipped), config.method,
                       " where the camera sees it whole at the poses you taught and")
