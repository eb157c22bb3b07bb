"""A force-motion policy built in Python and handed to the wipe: a stroke in while the force builds
up from 6 N to 12 N, a zigzag patch, then a spiral at 10 N, the joins blended over 0.5 s.

The policy is checked against the wipe's limits (speed, acceleration, force range, the surface's
reach) before the arm moves. Run: .venv/bin/python examples/wipe_policy.py [OUT_DIR]
"""

from __future__ import annotations

import sys

from tactex.report.wipe_report import write_wipe_report
from tactex.tasks.policies import ForceRamp, LinePolicy, PolicySequence, SpiralPolicy, ZigzagPolicy
from tactex.tasks.wipe import WipeConfig, run_wipe


def main(out_dir: str = "runs/wipe_policy_example") -> None:
    policy = PolicySequence([
        LinePolicy(2.0, ForceRamp(6.0, 12.0), length_m=0.02, direction_deg=-90.0),
        ZigzagPolicy(8.0, ForceRamp(12.0, 12.0), width_m=0.05, length_m=0.03, lanes=3),
        SpiralPolicy(6.0, ForceRamp(10.0, 10.0), radius_m=0.025, turns=2.0),
    ], blend_s=0.5)
    result = run_wipe(WipeConfig(object_name="sine_panel", start_y_m=0.0), policy=policy, progress=True)
    m = result.metrics
    print(f"force MAE against the policy's set point {m['force_mae_n']:.2f} N, "
          f"peak {m['max_force_over_set_point']:.2f}× the set point, torque-rate clips {m['torque_rate_clip_ticks']}")
    for k, seg in enumerate(m["policy"]["segments"], start=1):
        print(f"segment {k} ({seg['kind']}, {seg['start_s']:.1f}–{seg['end_s']:.1f} s): "
              f"force MAE {seg['force_mae_n']:.2f} N, peak {seg['max_force_over_set_point']:.2f}× the set point")
    rep = write_wipe_report(result, out_dir)
    print(f"report: {rep.files['html']}")


if __name__ == "__main__":
    main(*sys.argv[1:2])
