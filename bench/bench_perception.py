"""Perception benchmark: full surface estimation on 640×480 depth frames (VA-UFIC §IV: 3 FPS).

Scene: the VA-UFIC §III sinusoidal surface seen by a D435i-class camera (640×480, fx = 383 px)
looking down from 0.25 m, moved along the wiping direction y over 60 frames, with Gaussian depth
noise of 1 mm (seeded). One "estimate" is the complete per-frame work of
``SurfaceEstimator.estimate``: validate the frame, find where the tool axis meets the surface,
cut the ROI cylinder, back-project it (stride ≥ 2), normals from integral images, region
growing, segment choice, PCA → SurfaceEstimate. The median over the frames is reported;
frames per second = 1000 / median ms. Rendering the frames is not timed.

``async_*``: a 1 kHz loop calls ``AsyncSurfacePipeline.latest()`` while the pipeline's two
threads estimate frames arriving at 30 Hz: the cost of ``latest()`` and the loop period show what
the estimator costs a control loop sharing the interpreter (GIL) with it.
"""

from __future__ import annotations

import time

import numpy as np

from tactex.perception import AsyncSurfacePipeline, D435I_DEPTH_640x480, SurfaceEstimator, frame_to_cloud
from tactex.perception.synthetic import VaUficSinusoid, look_at, render_frame

TARGETS = {
    "perception.fps_640x480": (">=", 30.0),
    "perception.estimate_ms_median": ("<=", 33.0),
}

N_FRAMES = 60
NOISE_M = 0.001


def _frames(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    surf = VaUficSinusoid()
    out = []
    for k, y in enumerate(np.linspace(-0.15, 0.15, n)):
        z0 = float(surf.h(np.array([0.0]), np.array([y]))[0])
        frame, _ = render_frame(
            D435I_DEPTH_640x480, look_at([0.0, y, z0 + 0.25], [0.0, y, z0], up=(0.0, 1.0, 0.0)), [surf],
            timestamp=k / 30.0,
        )
        depth = frame.depth_m + rng.normal(0.0, NOISE_M, frame.depth_m.shape).astype(np.float32)
        depth[frame.depth_m == 0] = 0.0
        out.append((frame.__class__(depth, frame.intrinsics, frame.world_T_camera, frame.timestamp), surf, y))
    return out


class _PacedSource:
    """Replays frames at a camera rate (30 Hz), like a live device's blocking read."""

    def __init__(self, frames, period_s: float, duration_s: float) -> None:
        self.frames, self.period_s = frames, period_s
        self.end = time.monotonic() + duration_s
        self.k = 0

    def read(self):
        if time.monotonic() >= self.end:
            return None
        time.sleep(self.period_s)
        frame = self.frames[self.k % len(self.frames)]
        self.k += 1
        return frame


def _baseline_loop(duration_s: float) -> float:
    """p99 period [ms] of the same 1 kHz loop with no perception running (machine noise)."""
    periods = []
    t_prev = time.perf_counter()
    t_end = time.monotonic() + duration_s
    while time.monotonic() < t_end:
        t0 = time.perf_counter()
        time.sleep(max(0.0, 0.001 - (time.perf_counter() - t0)))
        now = time.perf_counter()
        periods.append(now - t_prev)
        t_prev = now
    return float(np.percentile(periods, 99)) * 1e3


def _async_loop(frames, duration_s: float = 3.0) -> dict:
    """A 1 kHz consumer loop calling latest() while the two perception threads run at 30 Hz."""
    baseline = _baseline_loop(duration_s)
    pipe = AsyncSurfacePipeline(source=_PacedSource(frames, 1.0 / 30.0, duration_s))
    calls, periods = [], []
    pipe.start()
    t_prev = time.perf_counter()
    t_end = time.monotonic() + duration_s
    while time.monotonic() < t_end:
        t0 = time.perf_counter()
        pipe.latest(max_age_ms=100.0)
        calls.append(time.perf_counter() - t0)
        time.sleep(max(0.0, 0.001 - (time.perf_counter() - t0)))
        now = time.perf_counter()
        periods.append(now - t_prev)
        t_prev = now
    pipe.join(5.0)
    pipe.stop()
    stats = pipe.stats()
    return {
        "async_latest_us_p50": float(np.percentile(calls, 50)) * 1e6,
        "async_latest_us_p99": float(np.percentile(calls, 99)) * 1e6,
        "async_latest_us_max": float(np.max(calls)) * 1e6,
        "async_loop_period_ms_p99": float(np.percentile(periods, 99)) * 1e3,
        "baseline_loop_period_ms_p99": baseline,
        "async_estimates_per_s": stats.estimates_published / duration_s,
    }


def run(args) -> dict:
    n = 20 if getattr(args, "quick", False) else N_FRAMES
    data = _frames(n)
    est = SurfaceEstimator()
    for frame, _, _ in data[:3]:  # warm-up (imports, caches)
        est.estimate(frame)
    total, prep, stage2, errors, roi, valid = [], [], [], [], [], 0
    for frame, surf, y in data:
        t0 = time.perf_counter()
        patch = est.prepare(frame)
        t1 = time.perf_counter()
        e = est.estimate_prepared(patch)
        t2 = time.perf_counter()
        prep.append(t1 - t0)
        stage2.append(t2 - t1)
        total.append(t2 - t0)
        roi.append(e.roi_points)
        if e.valid:
            valid += 1
            p = np.array([[0.0, y, 0.0]])
            n_true = surf.normal(np.c_[p[:, :2], surf.h(p[:, 0], p[:, 1])])[0]
            errors.append(np.degrees(np.arccos(np.clip(e.normal_world @ n_true, -1.0, 1.0))))
    t0 = time.perf_counter()
    for frame, _, _ in data[:10]:
        frame_to_cloud(frame, in_world=True, with_colors=False)
    cloud_ms = (time.perf_counter() - t0) / 10 * 1e3
    med = float(np.median(total)) * 1e3
    loop = _async_loop([f for f, _, _ in data], 1.5 if getattr(args, "quick", False) else 3.0)
    return {
        "perception": {
            **loop,
            "fps_640x480": 1e3 / med,
            "estimate_ms_median": med,
            "estimate_ms_p90": float(np.percentile(total, 90)) * 1e3,
            "prepare_ms_median": float(np.median(prep)) * 1e3,
            "normals_segment_pca_ms_median": float(np.median(stage2)) * 1e3,
            "roi_points_median": float(np.median(roi)),
            "frames": len(data),
            "valid_fraction": valid / len(data),
            "normal_error_deg_median": float(np.median(errors)) if errors else None,
            "normal_error_deg_max": float(np.max(errors)) if errors else None,
            "full_frame_to_cloud_ms": cloud_ms,
        }
    }
