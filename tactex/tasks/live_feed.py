"""What a run shows live: the loop's side of ``--view``, a latest-value slot in shared memory.

A run (explore, clean, wipe) hands its state to the live page through a :class:`LiveFeed`: at most
:data:`FEED_PERIOD_S` apart (10 Hz) it overwrites one slot — the time, the phase, the tool pose, the
force and its set point, the agent, the time breakdown so far and one value per cloud point (the dirt
or target left) — and goes on. Nothing waits for the page: the slot is never queued, a snapshot the
page did not take is overwritten by the next, and a page that is slow or gone costs the loop nothing
but the copy. The page runs in a process of its own (:mod:`tactex.report.live_view`; in the run's
process its server thread would take the interpreter lock from the loop, and pylibfranka holds that
lock while it waits for the robot, which would starve the server).

Transport (no pickle): a private folder (in ``/dev/shm`` when there is one) holding ``slot.bin``, a
seqlocked block of float64 numbers and a short JSON text (the phase and the time breakdown), and per
cloud ``cloud_<n>.npz`` (points [m], colours, the initial target, the keep-out zone: written once) with
``field_<n>.f32`` (the value per point, inside the same seqlock). The page's Stop button sends the run
SIGINT: the run stops exactly as on Ctrl-C.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from tactex.errors import InputError

__all__ = ["FEED_PERIOD_S", "LiveFeed", "LiveSnapshot", "read_snapshot"]

#: Least time between two snapshots the loop writes [s]: the page updates at ≤ 10 Hz.
FEED_PERIOD_S = 0.1

# float64 slots of slot.bin
SEQ, T_S, WALL, FORCE_N, SET_POINT_N = 0, 1, 2, 3, 4
TCP, AGENT, TOOL_R = 5, 8, 11  # 3, 3 and 9 values (world frame [m]; world_R_tool row-major)
PROGRESS, CLOUD_GEN, N_FIELD, STATE, STOP, VIEWER, PORT, TEXT_LEN = 20, 21, 22, 23, 24, 25, 26, 27
N_NUMBERS = 32
TEXT_BYTES = 4096  # the JSON text after the numbers
SLOT_BYTES = 8 * N_NUMBERS + TEXT_BYTES
#: STATE: the run goes on / ended by itself / stopped (Stop or Ctrl-C).
RUNNING, FINISHED, STOPPED = 0.0, 1.0, 2.0
#: VIEWER: the page's process starting / serving / failed (its message in viewer.err).
STARTING, SERVING, FAILED = 0.0, 1.0, -1.0


def _shm_dir() -> str | None:
    return "/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else None


class LiveFeed:
    """The run's side of the live page (see the module docstring).

    Args:
        folder: the feed's folder; None makes a fresh private one (removed by :meth:`close`).
        period_s: least time between snapshots [s].
    """

    def __init__(self, folder: str | Path | None = None, period_s: float = FEED_PERIOD_S) -> None:
        if not (math.isfinite(period_s) and period_s > 0):
            raise InputError(f"period_s must be a positive time [s], got {period_s!r}")
        self.own = folder is None
        self.folder = Path(tempfile.mkdtemp(prefix="tactex-live-", dir=_shm_dir()) if folder is None else folder)
        slot = self.folder / "slot.bin"
        fresh = not slot.exists()
        if fresh:
            slot.write_bytes(bytes(SLOT_BYTES))
        self._raw = np.memmap(slot, dtype=np.uint8, mode="r+", shape=(SLOT_BYTES,))
        self.numbers = self._raw[:8 * N_NUMBERS].view(np.float64)
        if fresh:  # nothing measured yet: no time, force or pose (the page draws none)
            self.numbers[T_S:PROGRESS + 1] = np.nan
        self._text = self._raw[8 * N_NUMBERS:]
        self.period_s = float(period_s)
        self._next = 0.0  # time.monotonic() from which the next snapshot is due
        self._gen = 0
        self._field: np.ndarray | None = None
        self._values = np.full(N_NUMBERS, np.nan)

    # -- the run's side -----------------------------------------------------------------------------------
    def due(self) -> bool:
        """Whether a snapshot is due (cheap enough for every tick)."""
        return time.monotonic() >= self._next

    def set_cloud(self, points_m: np.ndarray, colors: np.ndarray | None = None, target: np.ndarray | None = None,
                  keep_out: np.ndarray | None = None) -> None:
        """The cloud the page draws (N, 3) [m, world], its colours (N, 3) in [0, 1], the initial target (N,) and
        the keep-out zone (N,) bool; the snapshots' ``field`` then has one value per point. Done once per cloud,
        between ticks (it writes a file)."""
        pts = np.asarray(points_m, dtype=np.float32)
        n = len(pts)
        if pts.ndim != 2 or pts.shape[1] != 3 or n == 0:
            raise InputError(f"the live cloud must be (N, 3) points, got {pts.shape}")
        arrays: dict[str, np.ndarray] = {"points": pts}
        for name, arr, dtype in (("colors", colors, np.float32), ("target", target, np.float32),
                                 ("keep_out", keep_out, bool)):
            if arr is not None:
                a = np.asarray(arr, dtype=dtype)
                if a.shape[0] != n:
                    raise InputError(f"the live cloud's {name} has {a.shape[0]} rows for {n} points")
                arrays[name] = a
        gen = self._gen + 1
        np.savez(self.folder / f"cloud_{gen}.npz", **arrays)
        field = np.memmap(self.folder / f"field_{gen}.f32", dtype=np.float32, mode="w+", shape=(n,))
        field[:] = np.nan
        self._gen, self._field = gen, field
        self._write(None, None, {CLOUD_GEN: gen, N_FIELD: n})

    def publish(self, t_s: float, *, phase: str = "", force_n: float = math.nan, set_point_n: float = math.nan,
                tcp_m: np.ndarray | None = None, agent_m: np.ndarray | None = None,
                world_R_tool: np.ndarray | None = None, progress: float = math.nan,
                field: np.ndarray | None = None, breakdown_s: dict[str, float] | None = None,
                figures: dict[str, float] | None = None) -> None:
        """One snapshot: the run's time ``t_s`` [s], its phase, the normal force and its set point [N], the TCP
        and the agent (3,) [m, world], the tool's rotation (3, 3), the share done (0–1), one value per cloud
        point (``field``: what is left, in the initial target's units), the time so far per activity [s] and
        other figures by name. The next is due :attr:`period_s` later."""
        self._next = time.monotonic() + self.period_s
        v = self._values
        v[T_S], v[WALL], v[FORCE_N], v[SET_POINT_N], v[PROGRESS] = t_s, time.time(), force_n, set_point_n, progress
        v[TCP:TCP + 3] = math.nan if tcp_m is None else tcp_m
        v[AGENT:AGENT + 3] = math.nan if agent_m is None else agent_m
        v[TOOL_R:TOOL_R + 9] = math.nan if world_R_tool is None else np.ravel(world_R_tool)
        text = json.dumps({"phase": phase, "breakdown_s": breakdown_s or {}, "figures": figures or {}},
                          allow_nan=True).encode()[:TEXT_BYTES]
        numbers = {i: v[i] for i in (T_S, WALL, FORCE_N, SET_POINT_N, PROGRESS)}
        numbers.update({i: v[i] for i in range(TCP, TOOL_R + 9)})
        self._write(text, field, numbers)

    def finish(self, stopped: bool = False) -> None:
        """The run has ended (by itself, or ``stopped`` by Stop or Ctrl-C): the page says so."""
        self._write(None, None, {STATE: STOPPED if stopped else FINISHED})

    def _write(self, text: bytes | None, field: np.ndarray | None, numbers: dict[int, float]) -> None:
        """Seqlock write: an odd sequence number while the slot changes."""
        buf = self.numbers
        seq = buf[SEQ]
        buf[SEQ] = seq + 1.0
        for i, x in numbers.items():
            buf[i] = x
        if text is not None:
            self._text[:len(text)] = np.frombuffer(text, dtype=np.uint8)
            buf[TEXT_LEN] = len(text)
        if field is not None and self._field is not None:
            self._field[:] = field
        buf[SEQ] = seq + 2.0

    # -- the page's side ----------------------------------------------------------------------------------
    @property
    def stop_requested(self) -> bool:
        return bool(self.numbers[STOP] > 0)

    def close(self) -> None:
        """Free the feed (a folder it made is removed)."""
        self._field = None
        if self.own:
            for p in self.folder.iterdir():
                p.unlink(missing_ok=True)
            self.folder.rmdir()


class LiveSnapshot:
    """A consistent copy of the slot (see :func:`read_snapshot`)."""

    def __init__(self, seq: float, numbers: np.ndarray, text: dict[str, Any], field: np.ndarray | None) -> None:
        self.seq = seq
        self.numbers = numbers
        self.t_s = float(numbers[T_S])
        self.force_n = float(numbers[FORCE_N])
        self.set_point_n = float(numbers[SET_POINT_N])
        self.tcp_m = numbers[TCP:TCP + 3]
        self.agent_m = numbers[AGENT:AGENT + 3]
        self.world_R_tool = numbers[TOOL_R:TOOL_R + 9].reshape(3, 3)
        self.progress = float(numbers[PROGRESS])
        self.cloud_gen = int(numbers[CLOUD_GEN])
        self.state = float(numbers[STATE])
        self.phase = str(text.get("phase", ""))
        self.breakdown_s: dict[str, float] = dict(text.get("breakdown_s", {}))
        self.figures: dict[str, float] = dict(text.get("figures", {}))
        self.field = field


def read_snapshot(feed: LiveFeed, field: np.ndarray | None) -> LiveSnapshot | None:
    """The slot's latest snapshot (``field``: the memmap of the current cloud's values, or None), or None while
    the writer is inside it (try again at the next poll)."""
    buf = feed.numbers
    for _ in range(100):
        s0 = float(buf[SEQ])
        if s0 % 2.0:
            time.sleep(0.0005)
            continue
        numbers = np.array(buf, copy=True)
        n_text = int(numbers[TEXT_LEN])
        raw = bytes(feed._text[:n_text]) if n_text > 0 else b"{}"
        values = None if field is None else np.array(field, copy=True)
        if float(buf[SEQ]) == s0:
            try:
                text = json.loads(raw)
            except ValueError:
                text = {}
            return LiveSnapshot(s0, numbers, text, values)
    return None
