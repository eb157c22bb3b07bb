"""``tactex study --out DIR [--spec FILE] [--grid NAME=V1,V2 ...]``: many clean/wipe runs with statistics."""

from __future__ import annotations

import argparse
import sys

from tactex.commands._out import add_force_argument, check_out

NAME = "study"
HELP = ("run clean or wipe over a grid and/or random draws of parameters and seeds (local processes or Ray), "
        "with a table of every run, statistics per setting and plots; re-running resumes")


def add_executor_arguments(parser: argparse.ArgumentParser) -> None:
    """``--workers``, ``--ray``, ``--ray-address``: the same in ``tactex study`` and ``tactex sweep``."""
    group = parser.add_argument_group("where the runs execute")
    group.add_argument("--ray", action="store_true",
                       help="run on a local Ray instance started for this command (pip install 'tactex[distributed]')")
    group.add_argument("--ray-address", metavar="ADDRESS", default=None,
                       help="run on an existing Ray cluster: auto, HOST:PORT, or a client address ray://HOST:10001 "
                            "(docs/distributed.md)")


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="study folder: runs.jsonl, table.csv/.parquet, summary.csv/.txt, study.json, plots; "
                             "an existing study there is resumed")
    add_force_argument(parser, NAME)
    parser.add_argument("--spec", metavar="FILE", help="study file (.toml, .yaml): task, seeds, draws, [fixed], "
                                                       "[grid], [random], [success]; CLI options add to it")
    parser.add_argument("--task", choices=("clean", "wipe"), default=None, help="the task (default: clean)")
    parser.add_argument("--grid", metavar="NAME=V1,V2", action="append", default=[],
                        help="a grid factor, e.g. --grid object_name=plate,bowl --grid tool_friction=0.2,0.8 "
                             "(a baseline of tactex itself is the empty value: --grid baseline=,raster)")
    parser.add_argument("--set", metavar="NAME=VALUE", action="append", default=[], dest="fixed",
                        help="a parameter of every run, e.g. --set budget_s=30")
    parser.add_argument("--random", metavar="NAME=DIST:A:B", action="append", default=[],
                        help="a randomly drawn factor: uniform:LOW:HIGH, loguniform:LOW:HIGH, integers:LOW:HIGH "
                             "or choice:A:B:C (with --draws)")
    parser.add_argument("--units", choices=("m", "mm", "in"), default=None,
                        help="length unit of the runs' --cloud file (the same as --set units=mm); default m")
    parser.add_argument("--draws", type=int, default=None, help="random draws per grid setting (default: 0)")
    parser.add_argument("--draw-seed", type=int, default=None, help="seed of the random draws (default: 0)")
    parser.add_argument("--seeds", metavar="N|S1,S2", default=None,
                        help="seeds per setting: a count (5 = seeds 0-4) or a list (0,3,7); default 1")
    parser.add_argument("--workers", type=int, default=0,
                        help="runs at once: local processes, or the runs in flight on Ray (0 = one per CPU)")
    parser.add_argument("--retry-failed", action="store_true", help="when resuming, run the failed runs again")
    parser.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    add_executor_arguments(parser)


def spec_from_args(args: argparse.Namespace):
    """The study of ``--spec`` with the CLI's lists added (a CLI value replaces the file's)."""
    from tactex.errors import ConfigError
    from tactex.experiments.study_spec import load_spec_file, parse_assignment, spec_from_dict

    data = load_spec_file(args.spec) if args.spec else {}
    data = {**data, "grid": dict(data.get("grid") or {}), "fixed": dict(data.get("fixed") or {}),
            "random": dict(data.get("random") or {})}
    for text in args.grid:
        name, values = parse_assignment(text, "--grid")
        data["grid"][name] = values
    for text in args.fixed:
        name, values = parse_assignment(text, "--set")
        if len(values) != 1:
            raise ConfigError(f"--set {text}: one value per --set; use --grid for several")
        data["fixed"][name] = values[0]
    for text in args.random:
        name, (value,) = parse_assignment(text.replace(",", ":"), "--random")
        kind, _, rest = value.partition(":")
        parts = [p for p in rest.split(":") if p != ""]
        if kind != "choice":
            try:
                parts = [float(p) for p in parts]
            except ValueError as exc:
                raise ConfigError(f"--random {text}: {kind} needs numbers LOW:HIGH") from exc
        data["random"][name] = {kind: parts}
    if args.units is not None:
        data["fixed"]["units"] = args.units
    if args.task:
        data["task"] = args.task
    if args.draws is not None:
        data["draws"] = args.draws
    if args.draw_seed is not None:
        data["draw_seed"] = args.draw_seed
    if args.seeds is not None:
        text = args.seeds.strip()
        try:
            data["seeds"] = [int(s) for s in text.split(",") if s.strip()] if "," in text else int(text)
        except ValueError as exc:
            raise ConfigError(f"--seeds '{text}': give a count (5) or a list of integers (0,3,7)") from exc
    return spec_from_dict(data)


def run(args: argparse.Namespace) -> int:
    from tactex.experiments.executor import make_executor
    from tactex.experiments.study import check_same_study, print_to_stderr, run_study

    spec = spec_from_args(args)
    check_out(args, NAME)
    if not args.force:
        check_same_study(spec, args.out)
    say = None if args.quiet else print_to_stderr("tactex study")
    with make_executor(args.workers, ray=args.ray, ray_address=args.ray_address) as ex:
        # Ctrl-C: a RunInterrupted saying where the finished runs are, which the CLI reports (exit 130)
        result = run_study(spec, args.out, ex, retry_failed=args.retry_failed, progress=say)
    text = result.files.get("summary_text")
    if text is not None:
        print(text.read_text().rstrip())
    failed = result.failed
    print(f"{len(result.records)} runs ({result.skipped} resumed), {len(failed)} failed; study: {result.out_dir}")
    for rec in failed[:5]:
        print(f"  failed: {rec['factors']}: {rec['error'].splitlines()[0] if rec['error'] else ''}", file=sys.stderr)
    if failed:  # a script that runs a study must see it (the table and runs.jsonl have the finished runs)
        print(f"tactex study: {len(failed)} of {len(result.records)} runs failed (--retry-failed runs them again)",
              file=sys.stderr)
        return 1
    return 0
