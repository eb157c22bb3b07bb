"""``--view``: the live page of a run, started beside it (:mod:`tactex.report.live_view` in its own process,
fed through a :class:`~tactex.tasks.live_feed.LiveFeed`)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from tactex.errors import InputError
from tactex.tasks.live_feed import FAILED, PORT, STARTING, VIEWER, LiveFeed

__all__ = ["LivePage", "open_live_page"]

#: Longest wait for the page's process to serve [s] (importing viser on a busy machine).
START_TIMEOUT_S = 60.0


class LivePage:
    """A running live page: its ``url``, and the ``feed`` the run writes to. :meth:`close` ends it."""

    def __init__(self, feed: LiveFeed, proc: subprocess.Popen, url: str) -> None:
        self.feed, self.proc, self.url = feed, proc, url

    def close(self, stopped: bool = False) -> None:
        """Tell the page the run ended (``stopped``: by Stop or Ctrl-C), end its process, free the feed."""
        self.feed.finish(stopped)
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.feed.close()

    def __enter__(self) -> LivePage:
        return self

    def __exit__(self, kind, exc, tb) -> None:
        self.close(stopped=kind is not None and issubclass(kind, KeyboardInterrupt))


def open_live_page(port: int, title: str, force_set_point_n: float = 0.0) -> LivePage:
    """Start the live page on localhost ``port`` (0: a free one), its force plot scaled for ``force_set_point_n``
    [N] (0: a run without force, no plot); InputError when it cannot serve there."""
    from tactex.report.annotate_view import check_port

    try:
        check_port("127.0.0.1", port)
    except InputError as exc:
        raise InputError(str(exc).replace("--port", "--view-port")) from None
    feed = LiveFeed()
    code = "import sys; from tactex.report.live_view import serve_live; serve_live(sys.argv[1], int(sys.argv[2]), " \
           "sys.argv[3], int(sys.argv[4]), float(sys.argv[5]))"
    log = Path(feed.folder, "viewer.log")
    with log.open("wb") as err_out:  # the page's own messages go to a file: a pipe nobody reads could block it
        proc = subprocess.Popen([sys.executable, "-c", code, str(feed.folder), str(port), title, str(os.getpid()),
                                 repr(float(force_set_point_n))],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err_out)
    deadline = time.monotonic() + START_TIMEOUT_S
    while feed.numbers[VIEWER] == STARTING and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    if feed.numbers[VIEWER] == STARTING or feed.numbers[VIEWER] == FAILED:
        err = Path(feed.folder, "viewer.err")
        said = err.read_text().strip() if err.is_file() else ""
        if not said and proc.poll() is not None:
            lines = log.read_text(errors="replace").strip().splitlines()
            said = lines[-1] if lines else f"exit code {proc.returncode}"
        page = LivePage(feed, proc, "")
        page.close()
        raise InputError(f"the live page did not start: {said or 'no answer within a minute'}")
    return LivePage(feed, proc, f"http://127.0.0.1:{int(feed.numbers[PORT])}/")
