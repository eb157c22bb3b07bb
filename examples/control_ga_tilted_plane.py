"""TEC's GA line-and-force controller pressing 10 N on a 15° plane while the agent point slides.

Run: .venv/bin/python examples/control_ga_tilted_plane.py
"""

from __future__ import annotations

import numpy as np

from tactex.control import GaLineForceController, LineForceReference, SafetyLayer
from tactex.robots.mujoco_backend import MujocoBackend
from tactex.sim.scene import SceneConfig


def main() -> None:
    backend = MujocoBackend(SceneConfig(object_name="tilted_plane", tool_friction=0.0))
    pos, rot = backend.object_pose()
    normal = rot[:, 2]
    z = -normal
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    tool = np.column_stack([x, np.cross(z, x), z])
    state = backend.reset(q0=backend.solve_ik(pos + 0.01 * normal, tool))
    ctrl = SafetyLayer(GaLineForceController())
    ctrl.reset(state)
    for k in range(5000):
        agent = pos + 0.04 * np.sin(0.8 * state.t) * x  # the explorer's agent point on the surface
        backend.apply_torque(ctrl.torque(state, LineForceReference(agent, normal, 10.0)))
        state = backend.step()
        if k % 500 == 0:
            tilt = np.degrees(np.arccos(np.clip(state.ee_rotation[:, 2] @ z, -1, 1)))
            tel = "  ".join(f"{k} {v:.3g}" for k, v in ctrl.telemetry().items())
            print(f"t={state.t:4.1f} s  force {state.wrench_tool[2]:6.2f} N  tilt {tilt:5.2f}°  {tel}")
    print("safety events:", ctrl.counts)


if __name__ == "__main__":
    main()
