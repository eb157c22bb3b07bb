"""A dependency-free progress line on stderr for long simulated runs."""

from __future__ import annotations

import sys
import time
from typing import TextIO

__all__ = ["Progress"]


class Progress:
    """``Progress(total, label)``; ``update(done, **info)``; ``close()``. Redraws at most 5×/s.

    Silent when ``enabled`` is False (tests, library use); on a non-terminal stream it prints a
    plain line every 10 % instead of redrawing.
    """

    def __init__(self, total: float, label: str, *, unit: str = "s", enabled: bool = True,
                 stream: TextIO | None = None) -> None:
        self.total = max(float(total), 1e-12)
        self.label = label
        self.unit = unit
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self._t0 = time.perf_counter()
        self._last_draw = 0.0
        self._last_decile = -1
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())

    def update(self, done: float, **info: object) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        frac = min(max(done / self.total, 0.0), 1.0)
        extra = "  ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in info.items())
        if self._tty:
            if now - self._last_draw < 0.2 and frac < 1.0:
                return
            bar = "#" * int(frac * 24)
            wall = now - self._t0
            line = (f"\r{self.label:<14} [{bar:<24}] {done:7.2f}/{self.total:.1f} {self.unit}"
                    f"  {wall:5.1f} s wall  {extra}")
            self.stream.write(line[:160].ljust(100))
            self.stream.flush()
            self._last_draw = now
        else:
            decile = int(frac * 10)
            if decile > self._last_decile:
                self._last_decile = decile
                self.stream.write(f"{self.label}: {100 * frac:3.0f}%  ({now - self._t0:.1f} s wall)  {extra}\n")
                self.stream.flush()

    def note(self, message: str) -> None:
        """A line of its own (``label: message``), e.g. before a long silent step."""
        if not self.enabled:
            return
        if self._tty and self._last_draw > 0.0:
            self.stream.write("\n")
        self.stream.write(f"{self.label}: {message}\n")
        self.stream.flush()

    def close(self, message: str = "") -> None:
        if not self.enabled:
            return
        if self._tty:
            self.stream.write("\n")
        if message:
            self.stream.write(f"{self.label}: {message}\n")
        self.stream.flush()
