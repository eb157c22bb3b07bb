"""``tactex calibrate hand-eye --out cam.json``: where the wrist camera sits on the tool (tool_T_camera)."""

from __future__ import annotations

import argparse
import math
import sys

NAME = "calibrate"
HELP = ("calibrate the wrist camera's mount on the tool (hand-eye, AX = XB on chessboard views) and write the "
        "tool_T_camera file --hand-eye reads; in simulation, or on a Franka (or tactex twin) with its wrist camera")


def register(parser: argparse.ArgumentParser) -> None:
    from tactex.config import add_dataclass_arguments
    from tactex.sim.board import BESIDE_OBJECTS_XY_M
    from tactex.tasks.hand_eye_calibration import HandEyeConfig
    from tactex.tasks.robot import RealRobotParams

    parser.add_argument("what", choices=("hand-eye",), help="hand-eye: the camera's pose in the tool frame")
    parser.add_argument("--out", required=True, metavar="FILE.json",
                        help="the calibration: tool_T_camera, a 4×4 in metres (.json nested list or .npy)")
    parser.add_argument("--robot", choices=("sim", "franka"), default="sim",
                        help="sim: tactex's simulated arm and wrist camera, a board of geoms on the table (default); "
                             "franka: a real Franka through libfranka, or tactex twin with --board "
                             "(docs/real_robot.md)")
    parser.add_argument("--board", type=int, nargs=2, metavar=("COLS", "ROWS"), default=(9, 6),
                        help="the chessboard's inner corners (OpenCV's pattern size; COLS + 1 by ROWS + 1 squares, "
                             "one count even and one odd) (default: 9 6)")
    parser.add_argument("--square-m", type=float, default=0.025, help="the board's square edge [m] (default: 0.025)")
    parser.add_argument("--board-centre-m", type=float, nargs=2, metavar=("X", "Y"), default=BESIDE_OBJECTS_XY_M,
                        help="--robot franka: where the board's centre lies on the table, in the robot base frame [m] "
                             f"(default: {BESIDE_OBJECTS_XY_M[0]:g} {BESIDE_OBJECTS_XY_M[1]:g}, tactex twin's "
                             "--board-centre-m)")
    add_dataclass_arguments(parser, HandEyeConfig)
    robot = parser.add_argument_group("real robot (with --robot franka)")
    robot.add_argument("--taught", action="store_true",
                       help="you guide the arm by hand to each pose (the Franka's guiding mode) and press Enter where "
                            "the camera sees the whole board, 'done' to solve (at most --poses views); without it the "
                            "arm visits generated poses around --board-centre-m under torque control")
    add_dataclass_arguments(robot, RealRobotParams, skip=("hand_eye",))  # what this command makes


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from tactex.commands._task import robot_params
    from tactex.config import dataclass_from_args
    from tactex.errors import InputError
    from tactex.sim.board import ChessBoard
    from tactex.tasks.hand_eye_calibration import HandEyeConfig, write_hand_eye

    cfg = dataclass_from_args(HandEyeConfig, args)
    robot = robot_params(args)
    if args.taught and robot is None:
        raise InputError("--taught is for a real robot, whose arm you guide by hand: add --robot franka")
    if not args.out.endswith((".json", ".npy")):
        raise InputError(f"--out '{args.out}': the hand-eye file is .json or .npy (what --hand-eye reads)")
    if not all(math.isfinite(v) for v in args.board_centre_m):
        raise InputError(f"--board-centre-m must be two numbers [m], got {args.board_centre_m}")
    # in simulation the board lies where the simulated calibration puts it (ChessBoard's default)
    placed = {} if robot is None else {"centre_m": (*args.board_centre_m, 0.0)}
    board = ChessBoard(cols=args.board[0], rows=args.board[1], square_m=args.square_m, **placed)

    def note(msg: str) -> None:
        print(f"tactex calibrate: {msg}", file=sys.stderr, flush=True)

    result = _calibrate(cfg, board, robot, args.taught, note)
    for r in result.residuals:
        print(f"pose {r.index + 1:2d}: board {r.position_mm:.2f} mm, {r.rotation_deg:.3f}° from the views' mean")
    out = write_hand_eye(args.out, result.tool_T_camera)
    t = result.tool_T_camera
    print(f"tool_T_camera ({result.method}, {len(result.residuals)} poses): camera at "
          f"{np.round(t[:3, 3] * 1e3, 2).tolist()} mm in the tool frame, optical axis "
          f"{np.round(t[:3, 2], 4).tolist()}; written to {out}")
    if result.truth is not None:
        mm, deg = result.error()
        print(f"against the simulated mount: {mm:.2f} mm, {deg:.3f}°")
    return 0


def _calibrate(cfg, board, robot, taught: bool, note):
    """The hand-eye result: in simulation, on the robot from planned poses, or from poses taught by hand."""
    if robot is None:
        from tactex.tasks.hand_eye_calibration import calibrate_in_simulation

        return calibrate_in_simulation(cfg, board, note=note)
    if taught:
        from tactex.tasks.hand_eye_robot import calibrate_taught

        def ask(prompt: str) -> str:
            print(prompt, end="", file=sys.stderr, flush=True)
            line = sys.stdin.readline()
            if not line:
                raise EOFError
            return line

        return calibrate_taught(cfg, board, robot, ask=ask, note=note)
    from tactex.tasks.hand_eye_robot import calibrate_on_robot

    return calibrate_on_robot(cfg, board, robot, note=note)
