"""``tactex calibrate hand-eye --out cam.json``: where the wrist camera sits on the tool (tool_T_camera)."""

from __future__ import annotations

import argparse
import sys

NAME = "calibrate"
HELP = ("calibrate the wrist camera's mount on the tool (hand-eye, AX = XB on chessboard views) and write the "
        "tool_T_camera file --hand-eye reads; in simulation for now")


def register(parser: argparse.ArgumentParser) -> None:
    from tactex.config import add_dataclass_arguments
    from tactex.tasks.hand_eye_calibration import HandEyeConfig

    parser.add_argument("what", choices=("hand-eye",), help="hand-eye: the camera's pose in the tool frame")
    parser.add_argument("--out", required=True, metavar="FILE.json",
                        help="the calibration: tool_T_camera, a 4×4 in metres (.json nested list or .npy)")
    parser.add_argument("--robot", choices=("sim",), default="sim",
                        help="sim: tactex's simulated arm and wrist camera, a board of geoms on the table (default)")
    parser.add_argument("--board", type=int, nargs=2, metavar=("COLS", "ROWS"), default=(9, 6),
                        help="the chessboard's inner corners (OpenCV's pattern size; COLS + 1 by ROWS + 1 squares, "
                             "one count even and one odd) (default: 9 6)")
    parser.add_argument("--square-m", type=float, default=0.025, help="the board's square edge [m] (default: 0.025)")
    add_dataclass_arguments(parser, HandEyeConfig)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from tactex.config import dataclass_from_args
    from tactex.sim.board import ChessBoard
    from tactex.tasks.hand_eye_calibration import HandEyeConfig, calibrate_in_simulation, write_hand_eye

    cfg = dataclass_from_args(HandEyeConfig, args)
    board = ChessBoard(cols=args.board[0], rows=args.board[1], square_m=args.square_m)
    if not args.out.endswith((".json", ".npy")):
        from tactex.errors import InputError

        raise InputError(f"--out '{args.out}': the hand-eye file is .json or .npy (what --hand-eye reads)")

    def note(msg: str) -> None:
        print(f"tactex calibrate: {msg}", file=sys.stderr, flush=True)

    result = calibrate_in_simulation(cfg, board, note=note)
    for r in result.residuals:
        print(f"pose {r.index + 1:2d}: board {r.position_mm:.2f} mm, {r.rotation_deg:.3f}° from the views' mean")
    out = write_hand_eye(args.out, result.tool_T_camera)
    t = result.tool_T_camera
    print(f"tool_T_camera ({result.method}, {len(result.residuals)} poses): camera at "
          f"{np.round(t[:3, 3] * 1e3, 2).tolist()} mm in the tool frame, optical axis "
          f"{np.round(t[:3, 2], 4).tolist()}; written to {out}")
    mm, deg = result.error()
    print(f"against the simulated mount: {mm:.2f} mm, {deg:.3f}°")
    return 0
