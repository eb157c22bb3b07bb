"""``tactex demo``: a short clean and a short wipe on built-in objects, one run folder, no files needed."""

from __future__ import annotations

import argparse

from tactex.commands._out import add_force_argument, check_out
from tactex.config import add_dataclass_arguments, dataclass_from_args

NAME = "demo"
HELP = "short cleaning and wiping runs in simulation with a report (under 3 minutes, no files needed)"


def register(parser: argparse.ArgumentParser) -> None:
    from tactex.experiments.demo import DemoConfig

    parser.add_argument("--out", default="runs/demo", metavar="DIR",
                        help="run folder (default: runs/demo); a previous demo there is replaced")
    add_force_argument(parser, NAME)
    parser.add_argument("--quiet", action="store_true", help="no progress bar on stderr")
    add_dataclass_arguments(parser, DemoConfig)


def run(args: argparse.Namespace) -> int:
    from tactex.experiments.demo import DemoConfig, run_demo

    cfg = dataclass_from_args(DemoConfig, args)
    check_out(args, NAME)
    result = run_demo(args.out, cfg, progress=not args.quiet)
    print(result.summary())
    print(f"\n{sum(len(r) for r in result.reports.values())} runs in {result.wall_time_s:.0f} s wall; "
          f"report: {result.index}")
    return 0
