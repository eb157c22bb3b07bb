"""``tactex explore CLOUD --out DIR``: ergodic exploration of a cloud file or a built-in object."""

from __future__ import annotations

import argparse
import sys

from tactex.commands._out import add_force_argument, check_out
from tactex.commands._view import add_view_arguments, live_feed
from tactex.config import add_dataclass_arguments, dataclass_from_args

NAME = "explore"
HELP = "explore a point cloud (file or built-in object) with spectral HEDAC and write metrics and plots"

# Explorer fields that ExploreConfig already exposes under the names of the TEC experiments.
_SHARED = ("alpha", "n_eigen", "agent_radius_m", "max_velocity", "seed")


def register(parser: argparse.ArgumentParser) -> None:
    from tactex.ergodic import HedacConfig
    from tactex.experiments.explore import ExploreConfig
    from tactex.pointcloud.shapes import surface_names

    parser.add_argument(
        "cloud",
        metavar="CLOUD",
        help=f"a cloud file (.ply, .pcd, .npz) or mesh (.ply with faces, .stl, .obj), or a built-in object: "
             f"{', '.join(surface_names())}",
    )
    parser.add_argument("--out", required=True, metavar="DIR", help="run directory for metrics, trajectory and plots")
    add_force_argument(parser, NAME)
    add_dataclass_arguments(parser, ExploreConfig)
    x0_help = ExploreConfig.__dataclass_fields__["x0"].metadata["help"]
    parser.add_argument("--x0", type=float, nargs=3, metavar=("X", "Y", "Z"), default=None, help=x0_help)
    parser.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    add_view_arguments(parser)
    group = parser.add_argument_group("explorer (advanced)", "further HEDAC parameters (TEC Table II)")
    add_dataclass_arguments(group, HedacConfig, skip=_SHARED)


def run(args: argparse.Namespace) -> int:
    from tactex.ergodic import HedacConfig
    from tactex.experiments.explore import ExploreConfig, run_explore

    cfg = dataclass_from_args(ExploreConfig, args, x0=tuple(args.x0) if args.x0 is not None else None)
    hedac = dataclass_from_args(HedacConfig, args)
    check_out(args, NAME)

    def progress(msg: str) -> None:
        print(f"tactex explore: {msg}", file=sys.stderr, flush=True)

    with live_feed(args, NAME) as live:
        result = run_explore(args.cloud, args.out, cfg, hedac=hedac, progress=None if args.quiet else progress,
                             force=args.force, live=live)
    m = result.metrics
    print(
        f"{m['n_points']} points, {m['n_target']} target; preprocessing {m['preprocess_time_s']:.3f} s; "
        f"step median {m['step_time_median_s'] * 1e3:.3f} ms; after {len(result.trajectory)} steps: "
        f"ergodicity {m['final_ergodicity']:.4f}, coverage residual {m['final_coverage_residual']:.4f}, "
        f"path {m['final_path_length_m']:.3f} m"
        + (f" + {m['final_air_path_length_m']:.3f} m through the air ({m['relocations']} relocation(s))"
           if m["relocations"] else "")
        + (f", keep-out contacts {m['keep_out_contacts']} of {m['keep_out_points']} points"
           if m["keep_out_points"] else "")
        + f"; report in {result.out_dir}"
    )
    return 0
