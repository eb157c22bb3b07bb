"""VA-UFIC turns toward a planned normal while aligned (VaUficParams.follow_planned_rate), paid by its tank.

The paper re-orients the tool only while compliant; a re-planned wipe knows the surface ahead (the first pass
explored it) and hands it over as a planned estimate, which the aligned controller follows at a bounded rate.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactex.control import PoseForceReference, UficParams, VaUficController, VaUficParams
from tactex.perception.estimate import SurfaceEstimate
from tests.test_control_common import make_state

DOWN = np.diag([1.0, -1.0, -1.0])  # tool z points down (world −z)
JAC = np.hstack([np.eye(6), np.zeros((6, 1))])
TILT = math.radians(10.0)
# the surface tilted 10° about world x: its outward normal, and the inward one the tool should take
NORMAL = np.array([0.0, -math.sin(TILT), math.cos(TILT)])
DT, TICKS = 1e-3, 100


def _run(rate: float, planned: bool, python: bool, tau: float = 0.0) -> tuple[VaUficController, float]:
    ufic = UficParams(latency_horizon_ticks=0.0, kp=0.0, ki=0.0)
    ctrl = VaUficController(VaUficParams(rho_align_initial=1.0, follow_planned_rate=rate, follow_planned_tau=tau,
                                         ufic=ufic))
    if python:
        ctrl._compiled = None
    before = ctrl.tank_i.energy
    for k in range(1, TICKS + 1):
        t = k * DT
        est = SurfaceEstimate(valid=True, timestamp=t, normal_world=NORMAL, curvature=0.0, planned=planned)
        state = make_state(position=np.array([0.5, 0.0, 0.3]), rotation=DOWN, jacobian=JAC, t=t,
                           wrench_tool=np.array([0.0, 0.0, 10.0, 0.0, 0.0, 0.0]))
        ctrl.torque(state, PoseForceReference(np.array([0.5, 0.0, 0.3]), DOWN, np.zeros(6), surface=est))
    return ctrl, before


def _turned(ctrl: VaUficController) -> float:
    """The angle [rad] R_d's z axis has turned from the tool's start orientation."""
    z = ctrl.rotation_desired[:, 2]
    return math.acos(float(np.clip(z @ DOWN[:, 2], -1.0, 1.0)))


@pytest.mark.parametrize("python", [False, True])
def test_an_aligned_controller_turns_toward_a_planned_normal_at_its_rate(python) -> None:
    ctrl, before = _run(0.3, planned=True, python=python)  # tau 0: the cap all the way
    z = ctrl.rotation_desired[:, 2]
    # toward the inward normal, by the rate times the ticks after the first (R_d is set at the first tick)
    assert _turned(ctrl) == pytest.approx(0.3 * DT * (TICKS - 1), rel=0.02)
    assert np.cross(DOWN[:, 2], z) @ np.cross(DOWN[:, 2], -NORMAL) > 0  # the same way round
    # the tool stayed where it was: the constant rotational spring holds more energy, paid by the tank
    assert ctrl.tank_i.energy < before


@pytest.mark.parametrize("python", [False, True])
def test_the_camera_s_normal_or_a_zero_rate_leaves_an_aligned_tool_as_it_is(python) -> None:
    assert _turned(_run(0.3, planned=False, python=python)[0]) == pytest.approx(0.0, abs=1e-12)  # the paper
    assert _turned(_run(0.0, planned=True, python=python)[0]) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("python", [False, True])
def test_near_the_planned_normal_the_turn_slows_as_a_first_order_approach(python) -> None:
    # the 10° tilt is below rate × tau (0.3 rad/s × 2 s = 34°): the tilt decays by dt/tau each tick
    ctrl, _ = _run(0.3, planned=True, python=python, tau=2.0)
    remaining = TILT * (1.0 - DT / 2.0) ** (TICKS - 1)
    assert _turned(ctrl) == pytest.approx(TILT - remaining, rel=0.01)
    assert _turned(ctrl) < 0.3 * DT * (TICKS - 1)  # slower than the cap


@pytest.mark.parametrize("tau", [0.0, 0.35])
def test_the_compiled_tick_turns_as_the_python_one(tau) -> None:
    compiled, _ = _run(0.3, planned=True, python=False, tau=tau)
    python, _ = _run(0.3, planned=True, python=True, tau=tau)
    np.testing.assert_allclose(compiled.rotation_desired, python.rotation_desired, atol=1e-12)
    assert compiled.tank_i.energy == pytest.approx(python.tank_i.energy, abs=1e-12)
