"""VA-UFIC's damping feed-forward: it removes the velocity lag and the impedance tank pays for it."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.control import PoseForceReference, UficParams, VaUficController, VaUficParams
from tests.test_control_common import make_state

DOWN = np.diag([1.0, -1.0, -1.0])
JAC = np.hstack([np.eye(6), np.zeros((6, 1))])  # torque = world wrench on the first 6 joints
V = 0.1  # reference and robot both move along world x [m/s]


def _tick(feedforward: bool) -> tuple[np.ndarray, VaUficController, float]:
    ufic = UficParams(latency_horizon_ticks=0.0, kp=0.0, ki=0.0)  # eq. 13 as computed
    params = VaUficParams(rho_align_initial=1.0, damping_feedforward=feedforward, ufic=ufic)
    ctrl = VaUficController(params)
    twist = np.array([V, 0, 0, 0, 0, 0])
    state = make_state(position=np.array([0.5, 0.0, 0.3]), rotation=DOWN, twist=twist, jacobian=JAC,
                       wrench_tool=np.array([0, 0, 15.0, 0, 0, 0]))
    ref = PoseForceReference(np.array([0.5, 0.0, 0.3]), DOWN, np.zeros(6), twist_world=twist)
    before = ctrl.tank_i.energy
    tau = ctrl.torque(state, ref)
    return tau, ctrl, before


def test_feedforward_cancels_the_damping_lag() -> None:
    tau_ff, ctrl, _ = _tick(True)
    tau_plain, _, _ = _tick(False)
    d_x = float(ctrl._d_tool[0])  # D_C of the tick (the compiled tick keeps it in its vector, viewed here)
    assert tau_plain[0] == pytest.approx(-d_x * V, rel=1e-9)  # eq. 8: −D ẋ
    assert tau_ff[0] == pytest.approx(0.0, abs=1e-9)  # −D(ẋ − ẋ_d) with the valve open


def test_impedance_tank_pays_for_the_feedforward_energy() -> None:
    _, ctrl, before = _tick(True)
    step = ctrl.tank_i.last
    d_x = float(ctrl._d_tool[0])  # D_C of the tick (the compiled tick keeps it in its vector, viewed here)
    # the feed-forward delivers ẋᵀ(D ẋ_d) to the robot through the tank's port ...
    assert step.port_power == pytest.approx(d_x * V * V, rel=1e-9)
    # ... and the tank balance is exact: ΔS = dt (harvest − port)
    dt = 1e-3
    assert ctrl.tank_i.energy - before == pytest.approx(dt * (step.harvest_power - step.port_power), abs=1e-12)
