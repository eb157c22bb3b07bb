"""VA-UFIC starting out of contact and 15° misaligned: re-orients from the surface normal, presses 15 N.

The SurfaceEstimate comes from the true plane normal at 30 Hz here; in a task it comes from
``tactex.perception``. Run: .venv/bin/python examples/control_va_ufic_align.py
"""

from __future__ import annotations

import numpy as np

from tactex.control import PoseForceReference, SafetyLayer, VaUficController
from tactex.perception.estimate import SurfaceEstimate
from tactex.robots.mujoco_backend import MujocoBackend
from tactex.sim.scene import SceneConfig


def main() -> None:
    backend = MujocoBackend(SceneConfig(object_name="tilted_plane"))
    pos, rot = backend.object_pose()
    normal = rot[:, 2]
    down = np.diag([1.0, -1.0, -1.0])
    state = backend.reset(q0=backend.solve_ik(pos + 0.03 * normal, down))
    ctrl = SafetyLayer(VaUficController())
    ctrl.reset(state)
    x0 = state.ee_position.copy()
    estimate = None
    for k in range(4000):
        if k % 33 == 0:
            estimate = SurfaceEstimate(valid=True, timestamp=state.t, normal_world=normal.copy(), curvature=0.0)
        ref = PoseForceReference(x0, down, np.array([0, 0, 15.0, 0, 0, 0]), surface=estimate)
        backend.apply_torque(ctrl.torque(state, ref))
        state = backend.step()
        if k % 250 == 0:
            tel = ctrl.telemetry()
            tilt = np.degrees(np.arccos(np.clip(state.ee_rotation[:, 2] @ -normal, -1, 1)))
            print(f"t={state.t:4.2f} s  force {state.wrench_tool[2]:6.2f} N  tilt {tilt:5.2f}°  "
                  f"ρ_align {tel['rho_align']:.3f}  ρ_frc {tel['rho_frc']:.2f}  "
                  f"S_t,i {tel['tank_i_energy_j']:.2f} J  S_t,f {tel['tank_f_energy_j']:.2f} J")


if __name__ == "__main__":
    main()
