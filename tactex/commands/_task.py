"""Options and run logic shared by ``tactex clean`` and ``tactex wipe`` (not a command itself)."""

from __future__ import annotations

import argparse

from tactex.config import add_dataclass_arguments, dataclass_from_args
from tactex.errors import ConfigError


def register_task(parser: argparse.ArgumentParser, kind: str, config_cls: type) -> None:
    """``--out``, ``--compare``, ``--quiet``, ``--no-video`` and one option per field of the task config."""
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="run folder: config.json, metrics.json, series.npz, PNG plots, report.html")
    parser.add_argument("--compare", action="store_true",
                        help="run tactex and every baseline with the same parameters, one sub-folder each, "
                             "and report them side by side (index.html, summary.txt)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar on stderr")
    parser.add_argument("--no-video", dest="video", action="store_false",
                        help="skip the replay video (otherwise written when GL rendering works)")
    group = parser.add_argument_group(f"{kind} parameters")
    add_dataclass_arguments(group, config_cls)


def run_task_command(kind: str, config_cls: type, args: argparse.Namespace) -> int:
    from tactex.report.outdir import prepare_out_dir
    from tactex.report.run_report import summary_table
    from tactex.tasks.demo import run_compare, run_task

    cfg = dataclass_from_args(config_cls, args)
    if args.compare and cfg.baseline:
        raise ConfigError(f"--compare runs tactex and every baseline; drop --baseline {cfg.baseline}")
    out = prepare_out_dir(args.out)  # made only once the parameters are known to be good
    if args.compare:
        reports = run_compare(kind, cfg, out, progress=not args.quiet, video=args.video)
        page = out / "index.html"
    else:
        reports = [run_task(kind, cfg, out, progress=not args.quiet, video=args.video)]
        page = reports[0].html or out
    print(summary_table([(r.label, r.metrics) for r in reports]))
    print(f"report: {page}")
    return 0
