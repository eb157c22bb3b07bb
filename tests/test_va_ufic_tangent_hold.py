"""VA-UFIC's tangential hold (VaUficParams.tangent_hold): in contact the tool's tangent plane keeps a stiffness.

Pressing f_d on a convex part of radius r pushes the tool sideways by f_d·sin(d/r) once it is d off the top:
a tangential stiffness of −f_d/r. The paper's compliance (ρ_align ≈ 0, the tool's position fed back as the
desired one) opposes none of it; the hold does, so the tool stays where it touched down.
"""

from __future__ import annotations

import numpy as np
import pytest

from tactex.control import PoseForceReference, UficParams, VaUficController, VaUficParams
from tactex.errors import ConfigError
from tests.test_control_common import make_state

DOWN = np.diag([1.0, -1.0, -1.0])  # tool x = world x, tool y = −world y, tool z down
JAC = np.hstack([np.eye(6), np.zeros((6, 1))])  # torque = world wrench on the first 6 joints
TOUCH = np.array([0.5, 0.0, 0.3])
PRESS = np.array([0.0, 0.0, 15.0, 0.0, 0.0, 0.0])
UFIC = UficParams(latency_horizon_ticks=0.0, kp=0.0, ki=0.0)  # τ is the tool wrench as computed, no force loop


@pytest.fixture(params=["compiled", "python"], autouse=True)
def tick(request):
    """Each test on the compiled tick (when the fast extra is there) and on the Python reference."""
    return request.param


def _controller(hold: float, rho0: float = 0.0, tick: str = "compiled") -> VaUficController:
    ctrl = VaUficController(VaUficParams(rho_align_initial=rho0, tangent_hold=hold, damping_feedforward=False,
                                         ufic=UFIC))
    if tick == "python":
        ctrl._compiled = None
    return ctrl


def _tick(ctrl: VaUficController, position: np.ndarray, t: float, wrench: np.ndarray = PRESS) -> np.ndarray:
    state = make_state(position=position, rotation=DOWN, jacobian=JAC, wrench_tool=wrench, t=t)
    return ctrl.torque(state, PoseForceReference(TOUCH.copy(), DOWN, np.zeros(6)))


def _settle_wrench_filter(ctrl: VaUficController, position: np.ndarray, wrench: np.ndarray = PRESS) -> float:
    t = 0.0
    for _ in range(300):  # the controller reads the measured wrench through a low-pass
        t += 1e-3
        _tick(ctrl, position, t, wrench)
    return t


def test_while_compliant_the_tool_is_held_where_it_touched_down(tick) -> None:
    ctrl = _controller(0.5, tick=tick)
    t = _settle_wrench_filter(ctrl, TOUCH)
    assert ctrl.shaper.rho <= ctrl.va.compliant_below  # still compliant: the paper would feed the position back
    slid = TOUCH + np.array([0.004, -0.002, 0.0])  # 4 mm along tool x, 2 mm along tool y (world −y)
    tau = _tick(ctrl, slid, t + 1e-3)
    k = 0.5 * ctrl._k_max_t[0]  # half of K_max,t [N/m]
    assert tau[0] == pytest.approx(-k * 0.004, rel=1e-6)  # back towards the touch-down point, world x
    assert tau[1] == pytest.approx(k * 0.002, rel=1e-6)


def test_the_paper_s_law_with_no_hold(tick) -> None:
    ctrl = _controller(0.0, tick=tick)
    t = _settle_wrench_filter(ctrl, TOUCH)
    tau = _tick(ctrl, TOUCH + np.array([0.004, -0.002, 0.0]), t + 1e-3)
    assert tau[0] == pytest.approx(0.0, abs=1e-9) and tau[1] == pytest.approx(0.0, abs=1e-9)


def test_out_of_contact_there_is_no_anchor(tick) -> None:
    ctrl = _controller(0.5, tick=tick)
    t = _settle_wrench_filter(ctrl, TOUCH, np.zeros(6))  # free: no pressing force
    tau = _tick(ctrl, TOUCH + np.array([0.004, -0.002, 0.0]), t + 1e-3, np.zeros(6))
    assert tau[0] == pytest.approx(0.0, abs=1e-9) and tau[1] == pytest.approx(0.0, abs=1e-9)
    assert ctrl._anchor is None
    # touching down sets it; losing the contact clears it again
    t = _settle_wrench_filter(ctrl, TOUCH)
    ctrl._objects()
    assert ctrl._anchor is not None
    _settle_wrench_filter(ctrl, TOUCH, np.zeros(6))
    ctrl._objects()
    assert ctrl._anchor is None


def test_above_the_compliant_share_it_floors_the_variable_stiffness(tick) -> None:
    # ρ_align = 0.1 (past compliant_below): the paper's spring is 0.1 K_max; the hold keeps 0.5 K_max tangentially
    for hold, share in ((0.0, 0.1), (0.5, 0.5)):
        ctrl = _controller(hold, rho0=0.1, tick=tick)
        ctrl.shaper.rho_min = 0.0  # keep ρ_align where it is for the tick
        state = make_state(position=TOUCH + np.array([0.004, 0.0, 0.0]), rotation=DOWN, jacobian=JAC,
                           wrench_tool=PRESS, t=1e-3)
        ctrl._w_filt = PRESS.tolist()  # the filter already holds the pressing force
        tau = ctrl.torque(state, PoseForceReference(TOUCH.copy(), DOWN, np.zeros(6)))
        rho = ctrl.shaper.rho
        assert tau[0] == pytest.approx(-max(rho, share if hold else rho) * ctrl._k_max_t[0] * 0.004, rel=1e-3)


def test_tangent_hold_is_checked() -> None:
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ConfigError, match="tangent_hold"):
            VaUficParams(tangent_hold=bad)
