"""Serve the annotation page for a scan until Ctrl-C: what ``tactex annotate`` runs."""

from __future__ import annotations

import os
import sys
import threading
import webbrowser
from pathlib import Path

from tactex.errors import InputError

__all__ = ["check_annotation_out", "serve_annotation"]


def check_annotation_out(scan: str | Path, out: str | Path, force: bool = False) -> None:
    """Refuse an ``out`` file the page could not save to, or that would replace the scan without ``force``."""
    out, scan = Path(out), Path(scan)
    if out.suffix.lower() != ".ply":
        raise InputError(f"--out '{out}' must end in .ply (the marks are PLY vertex properties)")
    if out.is_dir():
        raise InputError(f"--out '{out}' is a directory; give a file name ending in .ply")
    folder = out.parent
    if not folder.is_dir():
        raise InputError(f"--out '{out}': its folder '{folder}' does not exist (the page's Save could not write "
                         "there, and your marks would be lost): make it first, or give another file")
    if not os.access(folder, os.W_OK) or (out.exists() and not os.access(out, os.W_OK)):
        raise InputError(f"--out '{out}' cannot be written (no permission): give a file you can write")
    if scan.is_file() and out.exists() and out.resolve() == scan.resolve() and not force:
        raise InputError(f"--out '{out}' is the scan itself: saving would replace it; give another file, or --force")


def serve_annotation(scan: str | Path, out: str | Path, *, port: int = 8080, open_browser: bool = True,
                     force: bool = False, units: str = "m") -> None:
    """Serve the page painting ``scan``'s target and keep-out on localhost ``port`` (0: a free one) until
    Ctrl-C; its Save button writes ``out`` (a PLY, in metres whatever the scan's ``units``). Says on stderr
    what was left unsaved."""
    from tactex.report.annotate_view import AnnotateView, check_port, open_annotation

    check_annotation_out(scan, out, force)
    check_port("127.0.0.1", port)  # before the cloud is read: a taken port is said at once
    annotation, notes = open_annotation(scan, units)
    for note in notes:
        print(f"tactex annotate: {note}", file=sys.stderr)
    view = AnnotateView(annotation, out, port=port, source=scan)
    c = annotation.counts()
    print(f"tactex annotate: {c.n_points} points ({c.n_target} target, {c.n_keep_out} keep-out already); "
          f"open {view.url} — Ctrl-C to stop", flush=True)
    if open_browser:
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
