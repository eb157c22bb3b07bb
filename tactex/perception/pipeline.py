"""Asynchronous perception: frames in, the latest surface estimate out, never blocking the caller.

VA-UFIC §II-B runs (i) acquisition + pre-processing and (ii) surface-normal estimation as two
concurrent threads while the controller runs at 1 kHz. :class:`AsyncSurfacePipeline` does the
same with two daemon threads and single-slot mailboxes (a newer frame replaces one that has not
been started yet — the controller wants the newest surface, not a backlog):

    submit(frame) / source.read() ──► [acquisition: SurfaceEstimator.prepare] ──► slot
    slot ──► [estimation: SurfaceEstimator.estimate_prepared] ──► published estimate

``latest()`` only reads one reference that the estimation thread swaps atomically, so it never
waits on a frame; ``submit()`` holds a lock only for a pointer swap. Ages are measured on the
pipeline's clock from the moment a frame *arrived* (device timestamps may use another clock).

Caveat: the threads share the Python GIL with the caller. The heavy steps are numpy/scipy
calls, most of which release it, but a pure-Python 1 kHz loop can still see jitter of up to
the interpreter's switch interval while an estimate is computed.
"""

from __future__ import annotations

import threading
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from tactex.errors import ConfigError, PerceptionError, TactexError
from tactex.perception.estimate import SurfaceEstimate
from tactex.perception.estimator import PreparedPatch, SurfaceEstimator
from tactex.perception.frame import CameraFrame

__all__ = ["AsyncSurfacePipeline", "FrameSource", "PipelineStats", "TimedEstimate"]


class FrameSource(Protocol):
    """Anything that yields camera frames: ``read()`` blocks until the next frame, None at the end."""

    def read(self) -> CameraFrame | None: ...


@dataclass(frozen=True)
class TimedEstimate:
    """An estimate with its freshness.

    Attributes:
        estimate: the surface estimate (``SurfaceEstimate.invalid`` before the first one).
        age_s: time since the frame it came from arrived [s] (inf before the first estimate).
        latency_s: arrival → estimate published [s].
        stale: True when older than the requested maximum age, or when there is no estimate yet.
        sequence: 1, 2, … for each published estimate (0 = none yet).
    """

    estimate: SurfaceEstimate
    age_s: float
    latency_s: float
    stale: bool
    sequence: int

    @property
    def usable(self) -> bool:
        """Valid and fresh: the only case a controller should act on."""
        return self.estimate.valid and not self.stale


@dataclass(frozen=True)
class PipelineStats:
    frames_received: int
    frames_dropped: int
    estimates_published: int
    errors: int
    last_error: str


@dataclass(frozen=True)
class _Published:
    estimate: SurfaceEstimate
    arrived: float
    finished: float
    sequence: int


class AsyncSurfacePipeline:
    """Two-thread surface estimation that always offers the latest estimate with its age.

    Args:
        estimator: the :class:`SurfaceEstimator` (a default one when None).
        source: optional frame source polled by the acquisition thread; otherwise feed frames
            with :meth:`submit`.
        pose_provider: ``f(frame) -> world_T_tool (4, 4) | None`` used for frames from ``source``.
        max_age_ms: default freshness bound of :meth:`latest` [ms].
        clock: time source [s] (``time.monotonic``; inject a fake clock in tests/simulation).
    """

    def __init__(
        self,
        estimator: SurfaceEstimator | None = None,
        *,
        source: FrameSource | None = None,
        pose_provider: Callable[[CameraFrame], np.ndarray | None] | None = None,
        max_age_ms: float = 100.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not (np.isfinite(max_age_ms) and max_age_ms > 0):
            raise ConfigError(f"max_age_ms must be a positive number of milliseconds, got {max_age_ms!r}")
        self.estimator = estimator or SurfaceEstimator()
        self.source = source
        self.pose_provider = pose_provider
        self.max_age_ms = float(max_age_ms)
        self.clock = clock
        self._cond = threading.Condition()
        self._frame_slot: tuple[CameraFrame, np.ndarray | None, float] | None = None
        self._patch_slot: tuple[PreparedPatch, float] | None = None
        self._published: _Published | None = None
        self._stop = threading.Event()
        self._source_done = threading.Event()
        self._threads: list[threading.Thread] = []
        self._received = self._dropped = self._errors = 0
        self._last_error = ""
        self._sequence = 0

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> AsyncSurfacePipeline:
        if self._threads:
            if self._stop.is_set():  # a stop() whose join timed out: a thread may still be in source.read()
                raise PerceptionError(
                    "the pipeline's previous threads have not finished (stop() timed out, probably in a "
                    "blocking source.read()); call stop() again until it returns True before restarting"
                )
            return self
        self._stop.clear()
        self._source_done.clear()
        self._threads = [
            threading.Thread(target=self._acquire_loop, name="tactex-perception-acquire", daemon=True),
            threading.Thread(target=self._estimate_loop, name="tactex-perception-estimate", daemon=True),
        ]
        for th in self._threads:
            th.start()
        return self

    def stop(self, timeout_s: float = 5.0) -> bool:
        """Ask both threads to finish and join them (an estimate in progress is completed first).

        Returns True when both have ended. False when one is still running after ``timeout_s`` [s]
        (e.g. blocked in the source's ``read()``): it is kept, :attr:`running` stays True, a warning
        is issued, and :meth:`start` refuses until a later ``stop()`` has joined it, so that two
        threads never read the same camera."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        for th in self._threads:
            th.join(timeout_s)
        alive = [th for th in self._threads if th.is_alive()]
        self._threads = alive
        if alive:
            warnings.warn(
                f"perception thread(s) {[th.name for th in alive]} still running {timeout_s:g} s after stop() "
                "(a blocking source.read()?); they end when it returns", RuntimeWarning, stacklevel=2)
            return False
        return True

    def join(self, timeout_s: float | None = None) -> bool:
        """Wait until a finite ``source`` is exhausted and its last frame estimated; True when done."""
        for th in self._threads:
            th.join(timeout_s)
        return not self.running

    def __enter__(self) -> AsyncSurfacePipeline:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def running(self) -> bool:
        return any(th.is_alive() for th in self._threads)

    # ------------------------------------------------------------------ producer side
    def submit(self, frame: CameraFrame, world_T_tool: np.ndarray | None = None) -> None:
        """Hand a frame to the pipeline and return at once (a pending, unstarted frame is dropped)."""
        arrived = self.clock()
        pose = None if world_T_tool is None else np.array(world_T_tool, dtype=np.float64)
        with self._cond:
            if self._frame_slot is not None:
                self._dropped += 1
            self._frame_slot = (frame, pose, arrived)
            self._received += 1
            self._cond.notify_all()

    # ------------------------------------------------------------------ consumer side
    def latest(self, max_age_ms: float | None = None) -> TimedEstimate:
        """The newest estimate, its age and a stale flag; never waits for a frame."""
        pub = self._published  # a single reference read: atomic, no lock
        limit = (self.max_age_ms if max_age_ms is None else float(max_age_ms)) * 1e-3
        if pub is None:
            return TimedEstimate(
                SurfaceEstimate.invalid(float("nan"), "no frame has been processed yet"),
                float("inf"), float("nan"), True, 0,
            )
        age = self.clock() - pub.arrived
        return TimedEstimate(pub.estimate, age, pub.finished - pub.arrived, age > limit, pub.sequence)

    def wait_for(self, sequence: int, timeout_s: float | None = None) -> TimedEstimate | None:
        """Block until an estimate with ``sequence`` ≥ the given one is published (not for control loops).

        Returns None on timeout.
        """
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        with self._cond:
            while self._published is None or self._published.sequence < sequence:
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return None
                self._cond.wait(remaining)
        return self.latest()

    def stats(self) -> PipelineStats:
        return PipelineStats(self._received, self._dropped, self._sequence, self._errors, self._last_error)

    # ------------------------------------------------------------------ threads
    def _record_error(self, exc: BaseException) -> str:
        self._errors += 1
        kind = "invalid input" if isinstance(exc, TactexError) else "internal error"
        self._last_error = f"{kind}: {type(exc).__name__}: {exc}"
        return self._last_error

    def _next_frame(self) -> tuple[CameraFrame, np.ndarray | None, float] | None:
        if self.source is not None:
            frame = self.source.read()
            if frame is None:
                return None
            pose = self.pose_provider(frame) if self.pose_provider is not None else None
            arrived = self.clock()
            with self._cond:
                self._received += 1
            return frame, pose, arrived
        with self._cond:
            while self._frame_slot is None and not self._stop.is_set():
                self._cond.wait()
            item, self._frame_slot = self._frame_slot, None
        return item

    def _acquire_loop(self) -> None:
        while not self._stop.is_set():
            try:
                item = self._next_frame()
            except Exception as exc:  # a camera error must not kill the thread silently
                self._publish(SurfaceEstimate.invalid(float("nan"), self._record_error(exc)), self.clock())
                continue
            if item is None:
                if self.source is not None:
                    with self._cond:
                        self._source_done.set()  # the source is exhausted
                        self._cond.notify_all()
                    return
                continue
            frame, pose, arrived = item
            try:
                patch = self.estimator.prepare(frame, pose)
            except Exception as exc:
                ts = getattr(frame, "timestamp", float("nan"))
                self._publish(SurfaceEstimate.invalid(ts, self._record_error(exc)), arrived)
                continue
            with self._cond:
                if self._patch_slot is not None:
                    self._dropped += 1
                self._patch_slot = (patch, arrived)
                self._cond.notify_all()

    def _estimate_loop(self) -> None:
        while True:
            with self._cond:
                while self._patch_slot is None and not (self._stop.is_set() or self._source_done.is_set()):
                    self._cond.wait()
                if self._patch_slot is None:
                    return
                (patch, arrived), self._patch_slot = self._patch_slot, None
            try:
                est = self.estimator.estimate_prepared(patch)
            except Exception as exc:
                est = SurfaceEstimate.invalid(patch.timestamp, self._record_error(exc))
            self._publish(est, arrived)

    def _publish(self, est: SurfaceEstimate, arrived: float) -> None:
        with self._cond:
            self._sequence += 1
            self._published = _Published(est, arrived, self.clock(), self._sequence)
            self._cond.notify_all()
