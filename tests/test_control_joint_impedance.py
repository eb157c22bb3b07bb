"""Joint impedance with implicit damping: stable at 1 kHz on light modes, the example's D elsewhere."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tactex.control.joint_impedance import JointImpedanceController, JointImpedanceParams, JointTarget
from tactex.errors import ConfigError, ControllerFault
from tests.test_control_common import make_state

DT = 1e-3


def _light_mode_inertia(rng, light: float = 0.01) -> np.ndarray:
    """A 7×7 inertia [kg·m²] with one light mode (two joints turning against each other)."""
    q, _ = np.linalg.qr(rng.normal(size=(7, 7)))
    return q @ np.diag([2.0, 1.5, 1.0, 0.8, 0.5, 0.3, light]) @ q.T


def _spectral_radius_of_damped_step(m: np.ndarray, d: np.ndarray) -> float:
    """v_{k+1} = v_k − dt M⁻¹ D v_k: the velocity map of one 1 kHz tick under damping torque −D v."""
    step = np.eye(len(m)) - DT * np.linalg.solve(m, d)
    return float(np.max(np.abs(np.linalg.eigvals(step))))


def test_explicit_damping_rings_on_a_light_mode_and_the_implicit_one_does_not(rng):
    m = _light_mode_inertia(rng)
    ctrl = JointImpedanceController()
    d = np.diag(ctrl.params.damping)
    assert _spectral_radius_of_damped_step(m, d) > 1.0  # the Franka example's gains, applied explicitly
    assert _spectral_radius_of_damped_step(m, ctrl.damping_matrix(m)) < 1.0


def test_implicit_damping_is_the_example_damping_on_heavy_modes_and_passive(rng):
    ctrl = JointImpedanceController()
    heavy = 1000.0 * np.eye(7)  # h·D/m = 3 ms · 50 / 1000: the latency horizon leaves heavy modes alone
    np.testing.assert_allclose(ctrl.damping_matrix(heavy), np.diag(ctrl.params.damping), rtol=1e-3)
    d = ctrl.damping_matrix(_light_mode_inertia(rng))
    np.testing.assert_allclose(d, d.T, atol=1e-9)
    assert np.linalg.eigvalsh(0.5 * (d + d.T)).min() > 0.0


def test_torque_uses_the_implicit_damping(rng):
    """latency_horizon_ticks = 0: stiffness explicit, damping backward Euler over one period."""
    m = _light_mode_inertia(rng)
    dq = rng.normal(size=7)
    state = replace(make_state(dq=dq), mass_matrix=m, coriolis=np.full(7, 0.1))
    ctrl = JointImpedanceController(JointImpedanceParams(latency_horizon_ticks=0.0))
    q_goal = np.full(7, 0.2)
    tau = ctrl.torque(state, JointTarget(np.zeros(7), q_goal, t_start=-10.0, duration_s=1.0))
    expected = np.asarray(ctrl.params.stiffness) * q_goal - ctrl.damping_matrix(m) @ dq + 0.1
    np.testing.assert_allclose(tau, expected, atol=1e-9)


def test_torque_is_the_impedance_applied_implicitly_over_the_latency_horizon(rng):
    """Default: τ = M (M + h·D + h²·K)⁻¹ (K e − D q̇) + C, h = 3 dt."""
    m = _light_mode_inertia(rng)
    dq = rng.normal(size=7)
    state = replace(make_state(dq=dq), mass_matrix=m, coriolis=np.full(7, 0.1))
    ctrl = JointImpedanceController()
    k, d, h = np.diag(ctrl.params.stiffness), np.diag(ctrl.params.damping), 3 * DT
    q_goal = np.full(7, 0.2)
    tau = ctrl.torque(state, JointTarget(np.zeros(7), q_goal, t_start=-10.0, duration_s=1.0))
    expected = m @ np.linalg.solve(m + h * d + h * h * k, k @ q_goal - d @ dq) + 0.1
    np.testing.assert_allclose(tau, expected, atol=1e-9)


def test_bad_period_and_shapes():
    with pytest.raises(ConfigError, match="dt"):
        JointImpedanceParams(dt=0.0)
    ctrl = JointImpedanceController(JointImpedanceParams(stiffness=(1.0,) * 6, damping=(1.0,) * 6))
    with pytest.raises(ControllerFault, match="shape"):
        ctrl.torque(make_state(), JointTarget(np.zeros(7), np.zeros(7), 0.0, 1.0))


def _move_torques(times_s: list[float]) -> tuple[np.ndarray, JointImpedanceController]:
    """Commands of a 0.4 s move of every joint by 0.3 rad, the arm held where it started, at ``times_s``, and
    the controller that gave them."""
    ctrl = JointImpedanceController()
    target = JointTarget(np.zeros(7), np.full(7, 0.3), t_start=0.0, duration_s=0.4)
    return np.array([ctrl.torque(make_state(t=t, q=np.zeros(7), dq=np.zeros(7)), target) for t in times_s]), ctrl


def test_a_stall_of_the_loop_holds_the_targets_clock_back_instead_of_stepping_the_command():
    """The robot's clock jumps 16 ms between two commands (the loop answered late): the command goes on
    from where it was, one period along the move, not 16 periods along it, and the move takes 15 ms longer."""
    smooth = [k * DT for k in range(200)]
    stalled = smooth[:100] + [t + 0.015 for t in smooth[100:]]
    (a, _), (b, ctrl) = _move_torques(smooth), _move_torques(stalled)
    np.testing.assert_allclose(b, a, atol=1e-12)
    assert ctrl.lag_s == pytest.approx(0.015, abs=1e-12)
    ctrl.torque(make_state(t=stalled[-1] + DT), JointTarget(np.zeros(7), np.zeros(7), 0.0, 0.0))
    assert ctrl.lag_s == 0.0  # a new target runs on the robot's clock again


def test_a_move_from_a_moving_arm_starts_at_its_speed_and_ends_at_rest_on_the_goal():
    q0, q1 = np.zeros(7), np.linspace(0.1, 0.4, 7)
    v0 = np.array([1.3, 0.0, -1.3, 0.2, 0.0, 0.0, -0.5])
    move = JointTarget(q0, q1, 2.0, 0.4, dq_start=v0)
    q, dq = move.at(2.0)
    np.testing.assert_allclose(q, q0, atol=1e-12)
    np.testing.assert_allclose(dq, v0, atol=1e-12)
    q, dq = move.at(2.4)
    np.testing.assert_allclose(q, q1, atol=1e-12)
    np.testing.assert_allclose(dq, 0.0, atol=1e-12)
    # continuous: the desired velocity is the derivative of the desired position (no jump anywhere in the move)
    ts = np.linspace(2.0, 2.4, 401)
    qs = np.array([move.at(t)[0] for t in ts])
    dqs = np.array([move.at(t)[1] for t in ts])
    np.testing.assert_allclose(np.gradient(qs, ts, axis=0)[1:-1], dqs[1:-1], atol=2e-3)
    # the start speed's acceleration starts at zero: the first millisecond changes the speed by a trace only
    assert float(np.max(np.abs(move.at(2.001)[1] - v0))) < 1e-3
    # a rest start is the plain minimum-jerk move
    rest = JointTarget(q0, q1, 2.0, 0.4, dq_start=np.zeros(7))
    assert rest.dq_start is None
    np.testing.assert_allclose(rest.at(2.1)[0], JointTarget(q0, q1, 2.0, 0.4).at(2.1)[0])


def test_the_start_speed_also_joins_a_move_through_via_postures():
    q0, q1 = np.zeros(7), np.full(7, 0.3)
    v0 = np.full(7, 0.8)
    move = JointTarget(q0, q1, 0.0, 0.5, via=np.full((1, 7), 0.1), dq_start=v0)
    np.testing.assert_allclose(move.at(0.0)[1], v0, atol=1e-12)
    np.testing.assert_allclose(move.at(0.5)[0], q1, atol=1e-12)


@pytest.mark.parametrize("dq_start", [np.zeros(6), np.array([np.nan, 0, 0, 0, 0, 0, 0])])
def test_a_bad_start_speed_is_refused(dq_start):
    from tactex.errors import InputError

    with pytest.raises(InputError, match="dq_start"):
        JointTarget(np.zeros(7), np.ones(7), 0.0, 1.0, dq_start=dq_start)
