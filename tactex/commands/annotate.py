"""``tactex annotate SCAN --out MARKED.ply``: paint a target and keep-out zones on a cloud in a browser."""

from __future__ import annotations

import argparse
import sys
import threading

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


def _check_out(args: argparse.Namespace) -> None:
    from pathlib import Path

    from tactex.errors import InputError

    out, scan = Path(args.out), Path(args.scan)
    if out.suffix.lower() != ".ply":
        raise InputError(f"--out '{out}' must end in .ply (the marks are PLY vertex properties)")
    if out.is_dir():
        raise InputError(f"--out '{out}' is a directory; give a file name ending in .ply")
    if scan.is_file() and out.exists() and out.resolve() == scan.resolve() and not args.force:
        raise InputError(f"--out '{out}' is the scan itself: saving would replace it; give another file, or --force")


def run(args: argparse.Namespace) -> int:
    import webbrowser

    from tactex.report.annotate_view import AnnotateView, check_port, open_annotation

    _check_out(args)
    check_port("127.0.0.1", args.port)  # before the cloud is read: a taken port is said at once
    annotation, notes = open_annotation(args.scan)
    for note in notes:
        print(f"tactex annotate: {note}", file=sys.stderr)
    view = AnnotateView(annotation, args.out, port=args.port, source=args.scan)
    c = annotation.counts()
    print(f"tactex annotate: {c.n_points} points ({c.n_target} target, {c.n_keep_out} keep-out already); "
          f"open {view.url} — Ctrl-C to stop", flush=True)
    if not args.no_browser:
        webbrowser.open(view.url)
    try:
        threading.Event().wait()
    except KeyboardInterrupt:
        pass
    finally:
        view.stop()
    if view.unsaved:
        print(f"tactex annotate: stopped with {view.unsaved} change(s) not saved"
              + (f" since {view.saved}" if view.saved else ""), file=sys.stderr)
    elif view.saved:
        print(f"tactex annotate: saved {view.saved}")
    return 0
