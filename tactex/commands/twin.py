"""``tactex twin --object NAME|FILE``: our scene inside franky-sim on loopback, with the wrist F/T
published over the Net F/T protocol and its wrist camera's RGB-D frames over TCP, for rehearsing a
real-robot run (see docs/twin.md)."""

from __future__ import annotations

import argparse
import sys

from tactex.config import add_dataclass_arguments, dataclass_from_args

NAME = "twin"
HELP = ("serve a simulated Franka (franky-sim, libfranka's protocol) with our object and tool on loopback, "
        "and its wrist F/T over Net F/T; runs until SIGTERM/SIGINT")


def register(parser: argparse.ArgumentParser) -> None:
    from tactex.twin.config import TwinConfig

    fields = TwinConfig.__dataclass_fields__
    parser.add_argument("--object", dest="object_name", default=None, metavar="NAME|FILE",
                        help=f"{fields['object_name'].metadata['help']} (default: {fields['object_name'].default})")
    parser.add_argument("--object-name", dest="object_name", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--port-ft", "--ft-port", dest="ft_port", type=int, default=None, metavar="P",
                        help=f"{fields['ft_port'].metadata['help']} (default: {fields['ft_port'].default})")
    parser.add_argument("--export-cloud", metavar="FILE.ply", default=None,
                        help="write the object's surface with its marking (red, target = 1) in the robot base "
                             "frame as a PLY at 3 mm spacing, for tactex clean --cloud, and exit")
    add_dataclass_arguments(parser, TwinConfig, skip=("object_name", "ft_port"))


def run(args: argparse.Namespace) -> int:
    from tactex.twin.config import TwinConfig
    from tactex.twin.scene import export_marking_cloud
    from tactex.twin.twin import run_twin

    cfg = dataclass_from_args(TwinConfig, args)
    if args.export_cloud:
        out = export_marking_cloud(cfg, args.export_cloud)
        print(f"marking of '{cfg.object_name}' written to {out} (robot base frame, metres)")
        return 0

    def ready(twin) -> None:
        host, port = twin.netft.address
        camera = (f", camera tcp {cfg.hostname}:{twin.camera.address[1]} ({cfg.camera_width}×{cfg.camera_height} at "
                  f"{cfg.camera_rate_hz:g} Hz)" if twin.camera is not None else "")
        board = cfg.chess_board()
        if board is not None and twin.camera is not None:
            camera += (f", a {board.cols}×{board.rows} chessboard at {board.centre_m[0]:g} {board.centre_m[1]:g} m "
                       f"({board.square_m * 1e3:g} mm squares)")
        print(f"twin ready: robot {cfg.hostname}:1337, Net F/T udp {host}:{port}{camera}, object {cfg.object_name}",
              flush=True)

    twin = run_twin(cfg, ready=ready)
    status = twin.status()
    print(f"twin stopped after {status['sim_time_s']:.1f} s simulated; dirt removed "
          f"{100 * status['dirt_removed_fraction']:.1f} %", file=sys.stderr, flush=True)
    return 0
