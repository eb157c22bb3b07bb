"""``tactex annotate SCAN --out MARKED.ply``: paint a target and keep-out zones on a cloud in a browser."""

from __future__ import annotations

import argparse

NAME = "annotate"
HELP = ("paint the target (with a weight) and keep-out zones on a scan in a local web page; saves a PLY "
        "with per-point target and keep_out that explore, clean, sweep and study read")


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scan", metavar="SCAN",
                        help="cloud file (.ply, .pcd, .npz) or mesh (.ply with faces, .stl, .obj); a PLY saved by "
                             "annotate opens with its marks, to edit")
    parser.add_argument("--out", required=True, metavar="MARKED.ply", help="the PLY the page's Save button writes")
    parser.add_argument("--port", type=int, default=8080, help="localhost port of the page (0: a free one)")
    parser.add_argument("--no-browser", action="store_true", help="print the page's address, open no browser")
    parser.add_argument("--force", action="store_true", help="let Save write over SCAN itself")
    parser.add_argument("--units", choices=("m", "mm", "in"), default="m",
                        help="length unit of SCAN; the saved PLY is in metres (default m)")


def run(args: argparse.Namespace) -> int:
    from tactex.experiments.annotate import serve_annotation

    serve_annotation(args.scan, args.out, port=args.port, open_browser=not args.no_browser, force=args.force,
                     units=args.units)
    return 0
