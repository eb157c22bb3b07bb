"""Options and run logic shared by ``tactex clean`` and ``tactex wipe`` (not a command itself)."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from tactex.commands._out import add_force_argument, check_out
from tactex.commands._view import add_view_arguments, live_feed
from tactex.config import add_dataclass_arguments, dataclass_from_args
from tactex.errors import ConfigError
from tactex.tasks.robot import RealRobotParams


def register_task(parser: argparse.ArgumentParser, kind: str, config_cls: type) -> None:
    """``--out``, ``--compare``, ``--quiet``, ``--no-video`` and one option per field of the task config."""
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="run folder: config.json, metrics.json, series.npz, PNG plots, report.html")
    add_force_argument(parser, kind)
    parser.add_argument("--compare", action="store_true",
                        help="run tactex and every baseline with the same parameters, one sub-folder each, "
                             "and report them side by side (index.html, summary.txt)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar on stderr")
    parser.add_argument("--no-video", dest="video", action="store_false",
                        help="skip the replay video (otherwise written when GL rendering works)")
    add_view_arguments(parser)
    group = parser.add_argument_group(f"{kind} parameters")
    add_dataclass_arguments(group, config_cls)
    parser.add_argument("--robot", choices=("sim", "franka"), default="sim",
                        help="sim: the MuJoCo world (default); franka: a real Franka through libfranka, or "
                             "tactex twin (docs/real_robot.md)")
    robot = parser.add_argument_group("real robot (with --robot franka)")
    add_dataclass_arguments(robot, RealRobotParams)


def robot_params(args: argparse.Namespace) -> RealRobotParams | None:
    """The real robot's parameters with ``--robot franka``; None in simulation (where giving one of
    them is a mistake worth naming)."""
    from tactex.tasks.robot import RealRobotParams

    if args.robot == "franka":
        return dataclass_from_args(RealRobotParams, args)
    given = [f.name for f in dataclasses.fields(RealRobotParams) if getattr(args, f.name, None) is not None]
    if given:
        raise ConfigError(f"--{given[0].replace('_', '-')} is for a real robot: add --robot franka")
    return None


def run_task_command(kind: str, config_cls: type, args: argparse.Namespace) -> int:
    from tactex.experiments.run import run_compare, run_task, task_summary

    cfg = dataclass_from_args(config_cls, args)
    robot = robot_params(args)
    if args.compare and cfg.baseline:
        raise ConfigError(f"--compare runs tactex and every baseline; drop --baseline {cfg.baseline}")
    if args.compare and robot is not None:
        raise ConfigError("--compare runs in simulation only; on a robot run tactex and a --baseline one at a time")
    if robot is not None and getattr(args, "dirt_preston_coefficient", None) is not None:
        raise ConfigError("--dirt-preston-coefficient sets the simulated dirt's; a robot's dirt is what it is (the "
                          "twin's: tactex twin --preston-coefficient); the wear model's estimate is --preston-estimate")
    if kind == "clean":
        check_cloud_size(cfg, args.force)  # before the simulation starts, or the robot moves
    if args.compare and args.view:
        raise ConfigError("--view shows one run; drop --compare, or watch a --baseline run on its own")
    check_out(args, kind)  # the run driver makes the folder, once the parameters are known to be good
    out = Path(args.out).expanduser()
    if args.compare:
        reports = run_compare(kind, cfg, out, progress=not args.quiet, video=args.video)
        page = out / "index.html"
    else:
        with live_feed(args, kind, cfg.force_n) as live:
            reports = [run_task(kind, cfg, out, progress=not args.quiet, video=args.video and robot is None,
                                robot=robot, live=live)]
        page = reports[0].html or out
    print(task_summary(reports))
    print(f"report: {page}")
    aborted = [r.metrics.get("aborted") for r in reports if r.metrics.get("aborted")]
    if aborted:
        print(f"tactex {kind}: error: the run stopped early ({aborted[0]}); what it recorded is in {out}",
              file=sys.stderr)
        return 1
    return 0


def check_cloud_size(cfg, force: bool) -> None:
    """A clean's ``--cloud`` over the basis size cap refused (unless ``force``) before the run starts, with the
    basis's estimated cost and the voxel size that fits; the file is read once more for it, only then."""
    from tactex.spectral.estimate import MAX_BASIS_POINTS, check_basis_size
    from tactex.spectral.modes import auto_n_eigen
    from tactex.tasks.clean.config import RASTER_BASELINES
    from tactex.tasks.clean.target import load_target_cloud

    if not cfg.cloud or cfg.baseline in RASTER_BASELINES or force:
        return
    from tactex.pointcloud.io import read_cloud

    if len(read_cloud(cfg.cloud, mesh_spacing_m=cfg.voxel_size_m or 0.003, units=cfg.units).cloud) <= MAX_BASIS_POINTS:
        return  # a voxel grid only thins a file: under the cap raw, under it voxelised
    cloud = load_target_cloud(cfg.cloud, cfg.voxel_size_m, units=cfg.units)
    n_eigen = cfg.n_eigen or auto_n_eigen(len(cloud) * cloud.spacing**2, cfg.agent_radius_m, len(cloud))
    check_basis_size(len(cloud), n_eigen, cloud.spacing, points=cloud.points)
