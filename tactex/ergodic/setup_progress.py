"""Progress of the explorer's set-up on a large cloud: its per-point neighbourhoods, taken a chunk at a time.

On 100k points the explorer's neighbourhoods (one K-D tree ball per point, for the step and for the
sweep's frontier) take seconds; :func:`in_chunks` does such work in chunks of points and says how far
it got every few seconds, so that a run's output never goes quiet for long.
"""

from __future__ import annotations

import time
from collections.abc import Callable

__all__ = ["CHUNK_POINTS", "PROGRESS_EVERY_S", "SETUP_PROGRESS_POINTS", "in_chunks"]

#: A cloud of this many points reports its set-up's progress [-].
SETUP_PROGRESS_POINTS = 50_000
#: Points per chunk [-].
CHUNK_POINTS = 10_000
#: Seconds between progress lines (the set-up has two such phases and lines before and after them: under 5 s of quiet).
PROGRESS_EVERY_S = 2.0


def in_chunks(n: int, work: Callable[[int, int], None], say: Callable[[str], None] | None, what: str) -> None:
    """``work(lo, hi)`` over the points lo…hi − 1 of n, a chunk at a time, in order; with ``say`` and at least
    ``SETUP_PROGRESS_POINTS`` points, a line "``what``: k of n points (t s) ..." every ``PROGRESS_EVERY_S``."""
    t0 = last = time.perf_counter()
    for lo in range(0, n, CHUNK_POINTS):
        hi = min(lo + CHUNK_POINTS, n)
        work(lo, hi)
        now = time.perf_counter()
        if say is not None and n >= SETUP_PROGRESS_POINTS and hi < n and now - last >= PROGRESS_EVERY_S:
            last = now
            say(f"{what}: {hi} of {n} points ({now - t0:.0f} s) ...")
