"""The asynchronous perception pipeline: staleness flags, never blocking the caller, error handling.

No timing thresholds: ordering is asserted with events, ages with an injected clock.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

from tactex.errors import ConfigError, PerceptionError
from tactex.perception import (
    AsyncSurfacePipeline,
    CameraFrame,
    D435I_DEPTH_640x480,
    PreparedPatch,
    RecordedFrameSource,
    SurfaceEstimate,
    SurfaceEstimator,
)
from tactex.perception.synthetic import Plane, look_at, render_frame

K = D435I_DEPTH_640x480
WAIT_S = 30.0  # generous upper bound for threads to make progress; never a performance claim


def plane_frame(t: float = 0.0) -> CameraFrame:
    frame, _ = render_frame(
        K, look_at([0.0, 0.0, 0.3], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0)), [Plane((0, 0, 0), (0.0, 0.3, 1.0))],
        timestamp=t,
    )
    return frame


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class GatedEstimator(SurfaceEstimator):
    """Blocks inside the estimation stage until released (a slow estimator, made deterministic)."""

    def __init__(self) -> None:
        super().__init__()
        self.entered = threading.Event()
        self.release = threading.Event()
        self.log: list[str] = []

    def estimate_prepared(self, patch: PreparedPatch) -> SurfaceEstimate:
        self.entered.set()
        assert self.release.wait(WAIT_S), "test never released the estimator"
        est = super().estimate_prepared(patch)
        self.log.append("estimate finished")
        return est


def test_latest_and_submit_never_wait_for_a_slow_estimator() -> None:
    gated = GatedEstimator()
    clock = FakeClock()
    with AsyncSurfacePipeline(gated, clock=clock, max_age_ms=50.0) as pipe:
        first = pipe.latest()
        assert first.stale and not first.usable and first.sequence == 0
        assert "no frame" in first.estimate.reason

        pipe.submit(plane_frame(0.0))
        assert gated.entered.wait(WAIT_S)  # the estimator is now stuck inside a frame
        during = pipe.latest()
        gated.log.append("latest returned")
        pipe.submit(plane_frame(1.0))  # also returns while the estimator is stuck
        pipe.submit(plane_frame(2.0))
        gated.log.append("submit returned")
        assert during.stale and during.sequence == 0

        gated.release.set()
        out = pipe.wait_for(1, timeout_s=WAIT_S)
        assert out is not None
        # The caller's calls completed before the estimator finished its first frame.
        assert gated.log[:3] == ["latest returned", "submit returned", "estimate finished"]
        assert out.estimate.valid and not out.stale and out.usable
        # Frame 1 is either estimated or replaced by frame 2 before it started; frame 2 always
        # ends up estimated (the newest frame wins, there is no backlog).
        last = pipe.wait_for(2, timeout_s=WAIT_S)
        if last is not None and last.estimate.timestamp == 1.0:
            last = pipe.wait_for(3, timeout_s=WAIT_S)
        assert last is not None and last.estimate.timestamp == 2.0
    stats = pipe.stats()
    assert stats.frames_received == 3 and stats.errors == 0
    assert stats.frames_dropped + stats.estimates_published == 3  # every frame estimated or dropped


def test_staleness_follows_the_requested_age() -> None:
    clock = FakeClock()
    with AsyncSurfacePipeline(clock=clock, max_age_ms=100.0) as pipe:
        pipe.submit(plane_frame())
        out = pipe.wait_for(1, timeout_s=WAIT_S)
        assert out is not None and out.estimate.valid
        clock.now += 0.04
        fresh = pipe.latest()
        assert not fresh.stale and fresh.age_s == pytest.approx(0.04)
        assert pipe.latest(max_age_ms=30.0).stale  # a stricter consumer sees it as stale
        clock.now += 0.1
        old = pipe.latest()
        assert old.stale and not old.usable and old.age_s == pytest.approx(0.14)
        assert old.estimate.valid  # stale is a flag on a kept estimate, not a deletion


def test_bad_frames_publish_invalid_estimates_and_the_pipeline_survives() -> None:
    with AsyncSurfacePipeline(clock=FakeClock()) as pipe:
        bad = CameraFrame(np.zeros((10, 10), np.float32), K, np.eye(4), 0.0)
        pipe.submit(bad)
        out = pipe.wait_for(1, timeout_s=WAIT_S)
        assert out is not None and not out.estimate.valid
        assert "invalid input" in out.estimate.reason and "PerceptionError" in out.estimate.reason
        pipe.submit(plane_frame(5.0))
        out = pipe.wait_for(2, timeout_s=WAIT_S)
        assert out is not None and out.estimate.valid and out.estimate.timestamp == 5.0
        assert pipe.stats().errors == 1


def test_source_driven_pipeline_with_pose_provider_matches_synchronous_estimate() -> None:
    frames = [plane_frame(float(k)) for k in range(3)]
    poses: list[float] = []

    def pose_provider(frame: CameraFrame) -> None:
        poses.append(frame.timestamp)
        return None

    pipe = AsyncSurfacePipeline(source=RecordedFrameSource(frames), pose_provider=pose_provider)
    pipe.start()
    assert pipe.join(timeout_s=WAIT_S)  # the finite source ends, its last frame is estimated
    assert poses == [0.0, 1.0, 2.0]
    latest = pipe.latest(max_age_ms=1e12)
    assert latest.estimate.valid and latest.estimate.timestamp == 2.0  # the newest frame always wins
    stats = pipe.stats()
    assert stats.frames_received == 3 and stats.frames_dropped + stats.estimates_published == 3
    sync = SurfaceEstimator().estimate(frames[2])
    np.testing.assert_array_equal(latest.estimate.normal_world, sync.normal_world)
    assert not pipe.running


def test_pipeline_rejects_bad_max_age() -> None:
    with pytest.raises(ConfigError, match="max_age_ms"):
        AsyncSurfacePipeline(max_age_ms=0.0)


def test_a_stop_that_times_out_keeps_the_thread_and_refuses_a_restart() -> None:
    """A source blocked in read(): stop() cannot join it. It says so (False, a warning), the pipeline
    still counts as running, and start() refuses, so two threads never read one camera; once the read
    returns, a second stop() joins it and the pipeline restarts."""

    class Blocking:
        def __init__(self) -> None:
            self.go = threading.Event()
            self.inside = threading.Event()

        def read(self):
            self.inside.set()
            self.go.wait(WAIT_S)
            return None

    src = Blocking()
    pipe = AsyncSurfacePipeline(source=src).start()
    assert src.inside.wait(WAIT_S)
    with pytest.warns(RuntimeWarning, match="still running"):
        assert pipe.stop(timeout_s=0.05) is False
    assert pipe.running
    with pytest.raises(PerceptionError, match="have not finished"):
        pipe.start()
    src.go.set()
    assert pipe.stop(timeout_s=WAIT_S) is True and not pipe.running
    src.go.clear()
    src.inside.clear()
    pipe.start()
    assert src.inside.wait(WAIT_S) and pipe.running
    src.go.set()
    assert pipe.stop(timeout_s=WAIT_S)
