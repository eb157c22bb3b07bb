"""Perception benchmark: full surface estimation on 640×480 depth frames (VA-UFIC §IV: 3 FPS).

Scene: the VA-UFIC §III sinusoidal surface seen by a D435i-class camera (640×480, fx = 383 px)
looking down from 0.25 m, moved along the wiping direction y over 60 frames, with Gaussian depth
noise of 1 mm (seeded). One "estimate" is the complete per-frame work of
``SurfaceEstimator.estimate``: validate the frame, find where the tool axis meets the surface,
cut the ROI cylinder, back-project it (stride ≥ 2), normals from integral images, region
growing, segment choice, PCA → SurfaceEstimate. The median over the frames is reported;
frames per second = 1000 / median ms. Rendering the frames is not timed.
"""

from __future__ import annotations

import time

import numpy as np

from tactex.perception import D435I_DEPTH_640x480, SurfaceEstimator, frame_to_cloud
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
    return {
        "perception": {
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
