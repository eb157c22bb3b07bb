"""Surface normal, θ and curvature along the VA-UFIC §III sinusoid, synchronously and asynchronously.

A D435i-class camera (640×480) looks down at h = 0.02 sin(π/0.19·y + 0.44) + 0.02 m from 0.25 m
and moves along y, as the wiping tool does. For each frame the estimate is compared with the
analytic normal. Then the same frames go through the two-thread pipeline.

    .venv/bin/python examples/perception_sinusoid.py
"""

from __future__ import annotations

import numpy as np

from tactex.perception import AsyncSurfacePipeline, D435I_DEPTH_640x480, SurfaceEstimator
from tactex.perception.synthetic import VaUficSinusoid, look_at, render_frame


def main() -> None:
    surf = VaUficSinusoid()
    estimator = SurfaceEstimator()
    frames = []
    print("   y [m]   normal error [deg]   theta [deg] (true)   l_s")
    for k, y in enumerate(np.linspace(-0.15, 0.15, 7)):
        z0 = float(surf.h(np.zeros(1), np.array([y]))[0])
        frame, _ = render_frame(
            D435I_DEPTH_640x480,
            look_at([0.0, y, z0 + 0.25], [0.0, y, z0], up=(0.0, 1.0, 0.0)),
            [surf],
            timestamp=k / 30.0,
        )
        frames.append(frame)
        est = estimator.estimate(frame)  # tool axis = optical axis (the paper's mount)
        n_true = surf.normal(np.array([[0.0, y, z0]]))[0]
        err = np.degrees(np.arccos(np.clip(est.normal_world @ n_true, -1.0, 1.0)))
        theta_true = np.degrees(np.arccos(n_true[2]))
        print(f"{y:8.3f}   {err:18.2f}   {np.degrees(est.theta_rad):8.2f} ({theta_true:6.2f})   {est.curvature:.2e}")

    with AsyncSurfacePipeline(estimator, max_age_ms=100.0) as pipe:
        for frame in frames:
            pipe.submit(frame)  # returns at once; a pending frame is replaced by a newer one
        out = pipe.wait_for(1, timeout_s=10.0)
        while out is not None and out.estimate.timestamp != frames[-1].timestamp:
            out = pipe.wait_for(out.sequence + 1, timeout_s=10.0)  # the newest frame is always estimated
        latest = pipe.latest()
        print(
            f"async: latest estimate from t={latest.estimate.timestamp:.3f} s, valid={latest.estimate.valid}, "
            f"age {latest.age_s * 1e3:.1f} ms, stale={latest.stale}; {pipe.stats()}"
        )


if __name__ == "__main__":
    main()
