"""``tactex sweep CLOUD [CLOUD ...] --out DIR``: the n_K × α study of TEC §V-B (Fig. 6–11)."""

from __future__ import annotations

import argparse
import sys

from tactex.commands._out import add_force_argument, check_out
from tactex.config import add_dataclass_arguments, dataclass_from_args

NAME = "sweep"
HELP = ("explore clouds over a grid of n_K and α from several starts (TEC Fig. 6-11) and plot the ergodicity, "
        "on local processes or Ray; or tune HEDAC's parameters with Ray Tune (--tune)")


def register(parser: argparse.ArgumentParser) -> None:
    from tactex.commands.study import add_executor_arguments
    from tactex.experiments.sweep import SweepConfig
    from tactex.pointcloud.shapes import surface_names

    parser.add_argument("clouds", metavar="CLOUD", nargs="+",
                        help=f"cloud files (.ply, .pcd, .npz), meshes (.ply with faces, .stl, .obj) or built-in "
                             f"objects: {', '.join(surface_names())}")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="run directory for sweep.json, curves.npz, plots; a sweep's folder given again resumes it")
    add_force_argument(parser, NAME)
    parser.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    parser.add_argument("--tune", metavar="SPACE", default=None,
                        help="instead of the grid, search HEDAC's parameters with Ray Tune: a .toml/.yaml file with "
                             "metric, mode, samples, seed and [space] (docs/distributed.md); runs on Ray")
    add_dataclass_arguments(parser, SweepConfig)
    add_executor_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from tactex.errors import RunInterrupted
    from tactex.experiments.executor import make_executor
    from tactex.experiments.sweep import SweepConfig, run_sweep

    cfg = dataclass_from_args(SweepConfig, args)
    check_out(args, NAME)

    def progress(msg: str) -> None:
        print(f"tactex sweep: {msg}", file=sys.stderr, flush=True)

    say = None if args.quiet else progress
    if args.tune:
        return _tune(args, cfg, say)
    with make_executor(cfg.workers, ray=args.ray, ray_address=args.ray_address) as ex:
        try:
            result = run_sweep(args.clouds, args.out, cfg, progress=say, executor=ex, force=args.force)
        except RunInterrupted:
            raise  # the settings done are written; its message says where
        except KeyboardInterrupt:
            print(f"tactex sweep: the finished settings are in {args.out}/settings — run the same command again "
                  "to resume", file=sys.stderr)
            raise
    alphas = cfg.alpha
    for key, cloud in result.summary["clouds"].items():
        print(f"{key}: {cloud['n_points']} points, {cloud['n_target']} target"
              + (f", {cloud['keep_out_points']} kept out ({_keep_out_from(cloud, cfg)}; most kept-out points "
                 f"touched in a run: {max(r['keep_out_contacts_max'] for r in cloud['results']):g})"
                 if cloud["keep_out_points"] else "")
              + f"; final ergodicity (eq. 48), mean of {cfg.starts} starts")
        print("  n_K \\ α " + "".join(f"{a:>9g}" for a in alphas))
        for k in cfg.n_eigen:
            row = {r["alpha"]: r["final_ergodicity_mean"] for r in cloud["results"] if r["n_eigen"] == k}
            print(f"  {k:8d} " + "".join(f"{row[a]:9.4f}" for a in alphas))
        best = cloud["best"]
        print(f"  best: n_K = {best['n_eigen']}, α = {best['alpha']:g} ({best['final_ergodicity_mean']:.4f})")
    for f in result.summary["failed"]:
        print(f"  failed: {f['cloud']} n_K = {f['n_eigen']}, α = {f['alpha']:g}: {f['error']}", file=sys.stderr)
    print(f"report: {result.out_dir} ({result.summary['sweep_time_s']:.1f} s)")
    return 0


def _keep_out_from(cloud: dict, cfg) -> str:
    """Where a cloud's keep-out zone came from, in words: the file's own property, the options, or both merged."""
    from tactex.pointcloud.ply_marks import KEEP_OUT_PROPERTY

    in_file = any(f"'{KEEP_OUT_PROPERTY}' property" in note for note in cloud["source"].get("notes", []))
    options = [o for o, given in (("--keep-out-channel", cfg.keep_out_channel), ("--keep-out-mask", cfg.keep_out_mask))
               if given]
    if in_file and options:
        return f"the file's {KEEP_OUT_PROPERTY} property merged with {' and '.join(options)}"
    return f"the file's {KEEP_OUT_PROPERTY} property" if in_file else " and ".join(options)


def _tune(args: argparse.Namespace, cfg, say) -> int:
    from tactex.experiments.tune import load_tune_spec, run_tune

    spec = load_tune_spec(args.tune)
    result = run_tune(args.clouds, args.out, spec, cfg, workers=cfg.workers, ray_address=args.ray_address,
                      progress=say)
    best = ", ".join(f"{k} = {v:g}" for k, v in result.best.items())
    print(f"best of {len(result.trials)} trials: {best}: {spec.metric} = {result.best_value:.4f}")
    print(f"trials: {result.files['table']}")
    return 0
