"""``--view`` and ``--view-port``, shared by the commands whose run can be watched live (not a command itself)."""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Iterator

from tactex.errors import ConfigError

#: The live page's port when ``--view`` is given without ``--view-port``.
DEFAULT_VIEW_PORT = 8080


def add_view_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--view", action="store_true",
                        help="show the run live in a local web page (its address is printed; docs/live_view.md): the "
                             "cloud coloured by what is left, the paths, the tool, the force, the phase and the time "
                             "so far, and a Stop button that ends the run as Ctrl-C does")
    parser.add_argument("--view-port", type=int, default=None, metavar="P",
                        help=f"localhost port of the --view page (default {DEFAULT_VIEW_PORT}; 0: a free one)")


@contextlib.contextmanager
def live_feed(args: argparse.Namespace, command: str, force_set_point_n: float = 0.0) -> Iterator[object | None]:
    """The run's :class:`~tactex.tasks.live_feed.LiveFeed` while its page serves (None without ``--view``);
    the page is told how the run ended and closed after it. ``force_set_point_n`` [N] scales its force plot
    (0: none)."""
    if not args.view:
        if args.view_port is not None:
            raise ConfigError(f"--view-port {args.view_port} is the live page's port: add --view")
        yield None
        return
    from tactex.experiments.live import open_live_page

    port = DEFAULT_VIEW_PORT if args.view_port is None else args.view_port
    with open_live_page(port, f"tactex {command} → {args.out}", force_set_point_n) as page:
        print(f"tactex {command}: live view at {page.url} (its Stop button ends the run as Ctrl-C does)",
              file=sys.stderr, flush=True)
        yield page.feed
