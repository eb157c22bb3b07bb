"""``tactex capture --camera realsense|sim --out FILE.ply``: one coloured scan in the robot base frame."""

from __future__ import annotations

import argparse
import sys

NAME = "capture"
HELP = ("capture a coloured scan with the wrist camera into a PLY in the robot base frame (colours, normals), "
        "cropped to the workspace, and say where its red marking is")


def register(parser: argparse.ArgumentParser) -> None:
    from tactex.config import add_dataclass_arguments
    from tactex.sim.objects import object_names
    from tactex.tasks.capture import DEFAULT_BOX_M, CaptureConfig

    parser.add_argument("--camera", required=True, choices=("realsense", "sim"),
                        help="realsense: an Intel RealSense (live, or --playback FILE); sim: the wrist camera of "
                             "tactex's simulated scene, the arm at capture poses above --object")
    parser.add_argument("--out", required=True, metavar="FILE.ply", help="the scan: x y z, normals, colours [m]")
    source = parser.add_argument_group("camera")
    source.add_argument("--playback", metavar="FILE.db3", help="play a RealSense recording (.db3 or .bag) instead "
                        "of a live camera")
    source.add_argument("--serial", help="the RealSense's serial number (default: the first one connected)")
    source.add_argument("--object", dest="object_name", default="plate", metavar="NAME",
                        help=f"--camera sim: the scene's object, one of {', '.join(object_names())} (default: plate)")
    pose = parser.add_argument_group("camera pose (the colour stream's optical frame: x right, y down, z forward)")
    pose.add_argument("--camera-pose", metavar="FILE", help="base_T_camera, a 4×4 rigid transform in metres (.json "
                      "nested list or .npy)")
    pose.add_argument("--robot-ip", help="read the tool pose from this Franka (or tactex twin) and compose it with "
                      "--hand-eye")
    pose.add_argument("--hand-eye", metavar="FILE", help="tool_T_camera, the hand-eye calibration (.json or .npy; "
                      "tactex calibrate hand-eye writes it)")
    add_dataclass_arguments(parser, CaptureConfig, skip=("box_m",))
    lo = " ".join(f"{v:g}" for v in DEFAULT_BOX_M)
    parser.add_argument("--box", dest="box_m", type=float, nargs=6, default=None,
                        metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
                        help=f"workspace box in the robot base frame [m] (default: {lo}: in front of the robot, "
                             "the surface it stands on cut away 2 mm above z = 0: a table at another height needs "
                             "its own ZMIN)")


#: Frames a live RealSense delivers before its auto-exposure has settled, read and dropped [-].
WARM_UP_FRAMES = 15


def _source(args: argparse.Namespace):
    """The frame source, how to name it in messages, and how many of its first frames to drop."""
    from tactex.errors import ConfigError
    from tactex.tasks.hand_eye import load_hand_eye, load_pose_file

    base_T_camera = load_pose_file(args.camera_pose) if args.camera_pose else None
    if args.camera == "sim":
        if args.playback or args.serial or args.robot_ip or args.hand_eye:
            raise ConfigError("--camera sim takes its pose from the simulated arm (or --camera-pose); --playback, "
                              "--serial, --robot-ip and --hand-eye are for --camera realsense")
        from tactex.sim.scene import SceneConfig
        from tactex.tasks.capture import SimCaptureSource

        scene = SceneConfig(object_name=args.object_name, camera_width=320, camera_height=240)
        return SimCaptureSource(scene, base_T_camera=base_T_camera), "the simulated camera", 0
    if base_T_camera is not None and (args.robot_ip or args.hand_eye):
        raise ConfigError("give the camera pose either as --camera-pose or as --robot-ip with --hand-eye, not both")
    if base_T_camera is None and not (args.robot_ip and args.hand_eye):
        raise ConfigError("--camera realsense needs the camera's pose in the robot base frame: --camera-pose FILE, "
                          "or --robot-ip with --hand-eye FILE")
    from tactex.perception.mount import CameraMount
    from tactex.perception.realsense import RealSenseSource

    if base_T_camera is not None:
        mount, tool_pose = CameraMount(base_T_camera), None
    else:
        from tactex.robots.read_pose import read_tool_pose

        mount = CameraMount(load_hand_eye(args.hand_eye))
        base_T_tool = read_tool_pose(args.robot_ip)  # the arm holds still during the capture
        tool_pose = lambda: base_T_tool  # noqa: E731
    if args.playback:
        source = RealSenseSource(mount=mount, tool_pose_provider=tool_pose, playback=args.playback)
        return source, f"the recording '{args.playback}'", 0
    source = RealSenseSource(mount=mount, tool_pose_provider=tool_pose, serial=args.serial)
    return source, "the RealSense", WARM_UP_FRAMES


def _target_summary(path) -> str:
    """What ``tactex explore`` would take as the target of the scan, in its own words."""
    from tactex.errors import InputError
    from tactex.experiments.explore import ExploreConfig, load_explore_cloud

    try:
        _, info = load_explore_cloud(str(path), ExploreConfig(voxel_size_m=0.0))
    except InputError as exc:
        return f"none: {exc}"
    return f"{info['target_rule']}: {info['target_where']}"


def run(args: argparse.Namespace) -> int:
    from tactex.config import dataclass_from_args
    from tactex.errors import InputError, SensorFault
    from tactex.tasks.capture import DEFAULT_BOX_M, CaptureConfig, capture_cloud, read_views, write_capture

    cfg = dataclass_from_args(CaptureConfig, args, box_m=DEFAULT_BOX_M if args.box_m is None else tuple(args.box_m))
    if not args.out.lower().endswith(".ply"):
        raise InputError(f"--out '{args.out}': the capture is written as a PLY file (a name ending in .ply)")
    source, what, warm_up = _source(args)
    try:
        read_views(source, warm_up, what, "frames dropped while its exposure settles")
        cloud = capture_cloud(source, cfg, what)
    except SensorFault as exc:  # a stream that ended: nothing to write, and not the user's input
        print(f"tactex capture: error: {exc}", file=sys.stderr)
        return 1
    finally:
        source.close()
    out = write_capture(cloud, args.out)
    lo, hi = cloud.points.min(axis=0), cloud.points.max(axis=0)
    extent = ", ".join(f"{a} {lo[i]:+.3f}…{hi[i]:+.3f}" for i, a in enumerate("xyz"))
    print(f"{len(cloud)} points with colours and normals from {cfg.views} frame(s) of {what}, spacing "
          f"{cloud.spacing * 1e3:.1f} mm, within {extent} m (robot base frame); written to {out}")
    print(f"target: {_target_summary(out)}")
    return 0
