"""TEC's GA line-and-force controller (eq. 34–47): line error, wrench mapping, non-interference."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.control import GaLineForceController, GaLineForceParams, LineForceReference
from tactex.control.ga_line_force import APPROACH_FADE_BAND
from tactex.errors import ConfigError, ControllerFault, InputError
from tactex.geometry import Line3, exp_so3, motor_between_lines, motor_log
from tests.test_control_common import make_state

TOL = 1e-9
DOWN = np.diag([1.0, -1.0, -1.0])  # tool z along world −z


def _ctrl(**kw) -> GaLineForceController:
    """The paper's law as computed (eq. 47, no latency shaping: the synthetic M = I is no arm's inertia)."""
    kw.setdefault("latency_horizon_ticks", 0.0)
    return GaLineForceController(GaLineForceParams(**kw))


def test_line_error_is_the_pygafro_motor_log_in_the_tool_frame(rng):
    rot = exp_so3(rng.normal(size=3))
    state = make_state(position=np.array([0.4, 0.1, 0.2]), rotation=rot)
    ref = LineForceReference(np.array([0.45, 0.05, 0.1]), rng.normal(size=3), 10.0)
    # reference computation through pygafro: target line in the tool frame, motor from the z-axis
    p_tool = rot.T @ (ref.point_world - state.ee_position)
    d_tool = rot.T @ (-ref.normal_world)
    target = Line3(p_tool, d_tool)
    z_axis = Line3(np.zeros(3), np.array([0.0, 0.0, 1.0]))
    m = z_axis.to_gafro().getMotor(target.to_gafro()).toTransformationMatrix()
    expected = motor_log(m[:3, :3], m[:3, 3])
    np.testing.assert_allclose(_ctrl().line_error(state, ref), expected, atol=TOL)
    rot_m, _ = motor_between_lines(z_axis, target)
    np.testing.assert_allclose(rot_m, m[:3, :3], atol=TOL)


def test_parallel_offset_pulls_towards_the_line_and_not_along_it():
    state = make_state(position=np.array([0.5, 0.0, 0.3]), rotation=DOWN)
    ref = LineForceReference(np.array([0.52, 0.01, 0.0]), np.array([0.0, 0.0, 1.0]), 0.0)
    w = _ctrl().line_wrench(state, ref)
    offset_tool = DOWN.T @ np.array([0.02, 0.01, 0.0])
    np.testing.assert_allclose(w[:3], np.array([750.0, 750.0, 300.0]) * offset_tool, atol=TOL)
    assert w[2] == pytest.approx(0.0, abs=TOL)  # nothing along the line: the force loop owns it
    np.testing.assert_allclose(w[3:], 0.0, atol=TOL)


def test_tilted_line_gives_no_torque_about_the_tool_axis(rng):
    ctrl = _ctrl()
    for _ in range(20):
        state = make_state(rotation=exp_so3(rng.normal(size=3)))
        ref = LineForceReference(state.ee_position + 0.05 * rng.normal(size=3), rng.normal(size=3), 5.0)
        w = ctrl.line_wrench(state, ref)
        assert w[5] == pytest.approx(0.0, abs=TOL)


def test_sliding_along_the_line_does_not_change_the_line_wrench(rng):
    """The paper's claim that tracking and pressing do not fight: the agent point may move along its
    line, and (when aligned) the tool may move along its own axis, without any line wrench change."""
    ctrl = _ctrl()
    rot = exp_so3(rng.normal(size=3))
    state = make_state(position=np.array([0.5, 0.1, 0.3]), rotation=rot)
    n = rng.normal(size=3)
    ref = LineForceReference(state.ee_position + 0.03 * rng.normal(size=3), n, 10.0)
    w0 = ctrl.line_wrench(state, ref)
    for s in (-0.2, 0.05, 0.3):
        moved = LineForceReference(ref.point_world + s * ref.normal_world, n, 10.0)
        np.testing.assert_allclose(ctrl.line_wrench(state, moved), w0, atol=TOL)
    # aligned tool (z along −n) offset sideways: sliding the TCP along its axis changes nothing
    z = -ref.normal_world
    x = np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    aligned = np.column_stack([x, np.cross(z, x), z])
    base = make_state(position=ref.point_world + 0.02 * x, rotation=aligned)
    wa = ctrl.line_wrench(base, ref)
    assert wa[2] == pytest.approx(0.0, abs=TOL)
    for s in (-0.1, 0.07):
        slid = make_state(position=base.ee_position + s * z, rotation=aligned)
        np.testing.assert_allclose(ctrl.line_wrench(slid, ref), wa, atol=TOL)


def test_torque_is_jacobian_transpose_of_the_world_wrench(rng):
    """τ = Jᵀ·blockdiag(R,R)·(K⊙V − D⊙v + W_C): with no motion and no integrator yet, check it exactly."""
    ctrl = _ctrl(ki=0.0, kd=0.0)
    rot = exp_so3(rng.normal(size=3))
    state = make_state(rotation=rot, wrench_tool=np.array([0, 0, 4.0, 0, 0, 0]), seed=7)
    ref = LineForceReference(state.ee_position + 0.01 * rng.normal(size=3), -rot[:, 2] + 0.1 * rng.normal(size=3), 10.0)
    tau = ctrl.torque(state, ref)
    w_tool = ctrl.line_wrench(state, ref) + np.array([0, 0, 0.5 * (10.0 - 4.0), 0, 0, 0])
    w_world = np.concatenate([rot @ w_tool[:3], rot @ w_tool[3:]])
    np.testing.assert_allclose(tau, state.jacobian.T @ w_world, atol=TOL)


def test_force_pid_presses_along_tool_z_and_integrates():
    ctrl = _ctrl(kp=0.5, ki=5.0, kd=0.0)
    jac = np.zeros((6, 7))
    jac[:6, :6] = np.eye(6)
    w = np.array([0, 0, 4.0, 0, 0, 0])  # in contact, pressing 4 N of the 10 N wanted
    ref = LineForceReference(np.array([0.5, 0.0, 0.3]), np.array([0.0, 0.0, 1.0]), 10.0)
    tau1 = ctrl.torque(make_state(rotation=DOWN, jacobian=jac, wrench_tool=w), ref)
    # tool z is world −z: error 6 N → world f_z = −(0.5·6 + 5·6·dt)
    assert tau1[2] == pytest.approx(-(3.0 + 5.0 * 6.0 * 1e-3), rel=1e-9)
    tau2 = ctrl.torque(make_state(t=1e-3, rotation=DOWN, jacobian=jac, wrench_tool=w), ref)
    assert tau2[2] == pytest.approx(-(3.0 + 5.0 * 6.0 * 2e-3), rel=1e-9)


def test_force_integrator_frozen_in_free_flight():
    """No contact (measured force under the threshold) while the tool moves in: only K_p·F pushes; no
    wind-up before impact, and what was integrated in contact leaks away. Out of contact and not
    moving in (joint friction holds the tool), the integrator builds up the push."""
    ctrl = _ctrl(kp=0.5, ki=5.0, kd=0.0, damping_linear=(150.0, 150.0, 0.0))
    jac = np.zeros((6, 7))
    jac[:6, :6] = np.eye(6)
    ref = LineForceReference(np.array([0.5, 0.0, 0.3]), np.array([0.0, 0.0, 1.0]), 10.0)
    moving_in = {"twist": np.array([0, 0, -0.01, 0, 0, 0]), "dq": np.array([0, 0, -0.01, 0, 0, 0, 0])}  # 1 cm/s
    for k in range(100):
        tau = ctrl.torque(make_state(t=k * 1e-3, rotation=DOWN, jacobian=jac, **moving_in), ref)
    assert tau[2] == pytest.approx(-5.0, rel=1e-12)
    stalled = _ctrl(kp=0.5, ki=5.0, kd=0.0)
    for k in range(100):
        stalled.torque(make_state(t=k * 1e-3, rotation=DOWN, jacobian=jac), ref)
    assert stalled._integral[2] == pytest.approx(10.0 * 0.1, rel=1e-9)
    w = np.array([0, 0, 4.0, 0, 0, 0])
    for k in range(100, 400):  # in contact, pressing 4 N: the integrator grows
        ctrl.torque(make_state(t=k * 1e-3, rotation=DOWN, jacobian=jac, wrench_tool=w), ref)
    held = ctrl._integral[2]
    # 6 N of error for 0.3 s, and 4 N more while the measurement catches up: the two ticks a step takes
    # through the medians (the 3-tick one's, and the 5-tick one's where they differ) and the 50 Hz wrench
    # low-pass's time constant
    assert held == pytest.approx(6.0 * 0.3 + 4.0 * (2e-3 + 1.0 / (2.0 * np.pi * 50.0)), rel=1e-4)
    for k in range(400, 600):  # contact lost for 0.2 s = one leak time constant
        ctrl.torque(make_state(t=k * 1e-3, rotation=DOWN, jacobian=jac, **moving_in), ref)
    assert ctrl._integral[2] == pytest.approx(held * (1 - 1e-3 / (1e-3 + 0.2)) ** 200, rel=1e-9)


def test_damping_opposes_tool_velocity():
    ctrl = _ctrl(kp=0.0, ki=0.0, kd=0.0)
    jac = np.zeros((6, 7))
    jac[:6, :6] = np.eye(6)
    twist = np.array([0.1, 0.0, 0.0, 0.0, 0.0, 0.2])
    state = make_state(rotation=DOWN, jacobian=jac, twist=twist, dq=np.append(twist, 0.0))  # J = [I 0]: q̇ = twist
    ref = LineForceReference(state.ee_position, np.array([0.0, 0.0, 1.0]), 0.0)
    tau = ctrl.torque(state, ref)
    np.testing.assert_allclose(tau[:6], [-150 * 0.1, 0, 0, 0, 0, -10 * 0.2], atol=TOL)


def test_wrong_reference_type_is_a_fault():
    with pytest.raises(ControllerFault, match="LineForceReference"):
        _ctrl().torque(make_state(), object())


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"stiffness_linear": (1.0, 2.0)}, "stiffness_linear"), ({"damping_angular": (-1.0, 0, 0)}, "damping_angular"),
     ({"kp": float("nan")}, "kp"), ({"dt": 0.0}, "dt"), ({"force_axes": (0, 0, 2, 0, 0, 0)}, "force_axes"),
     ({"wrench_median_ticks": 2}, "wrench_median_ticks"), ({"wrench_median_ticks": True}, "wrench_median_ticks"),
     ({"outlier_median_ticks": 4}, "outlier_median_ticks"), ({"outlier_n": -1.0}, "outlier_n"),
     ({"outlier_n": float("inf")}, "outlier_n")],
)
def test_params_validation(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        GaLineForceParams(**kwargs)


@pytest.mark.parametrize(
    ("point", "normal", "force", "match"),
    [([0, 0, np.nan], [0, 0, 1], 1.0, "point_world"), ([0, 0, 0], [0, 0, 0], 1.0, "normal_world"),
     ([0, 0, 0], [0, 0, 1], -1.0, "force_n"), ([0, 0, 0], [0, 1], 1.0, "normal_world")],
)
def test_reference_validation(point, normal, force, match):
    with pytest.raises(InputError, match=match):
        LineForceReference(np.asarray(point, float), np.asarray(normal, float), force)


@pytest.mark.parametrize("speed", [-0.1, float("nan"), float("inf")])
def test_reference_approach_speed_validation(speed):
    with pytest.raises(InputError, match="approach_speed_m_s"):
        LineForceReference(np.zeros(3), np.array([0.0, 0.0, 1.0]), 3.0, speed)


def test_line_wrench_is_a_descent_direction(rng):
    """Moving the tool a little along the commanded twist (tool frame, [t; ω]) brings its axis
    closer to the target line: the sign conventions of the GA → numpy mapping are right."""
    ctrl = _ctrl()
    eps = 1e-3
    for _ in range(50):
        rot = exp_so3(rng.normal(size=3))
        state = make_state(position=np.array([0.5, 0.0, 0.3]), rotation=rot)
        ref = LineForceReference(state.ee_position + 0.05 * rng.normal(size=3),
                                 -rot[:, 2] + 0.3 * rng.normal(size=3), 10.0)
        xi = ctrl.line_error(state, ref)
        moved = make_state(position=state.ee_position + eps * rot @ xi[:3], rotation=rot @ exp_so3(eps * xi[3:]))
        assert np.linalg.norm(ctrl.line_error(moved, ref)) < np.linalg.norm(xi)


def test_approach_speed_cap_acts_only_out_of_contact_and_above_the_cap():
    """Out of contact the pressing axis is damped only above approach_speed_max; in contact eq. 47 is unchanged."""
    params = GaLineForceParams(kp=0.0, ki=0.0, kd=0.0, latency_horizon_ticks=0.0)
    down = np.diag([1.0, -1.0, -1.0])
    jac = np.hstack([np.eye(6), np.zeros((6, 1))])
    ref = LineForceReference(np.array([0.5, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), 10.0)

    def fz_world(speed_down: float, f_meas: float) -> float:
        ctrl = GaLineForceController(params)
        state = make_state(position=np.array([0.5, 0.0, 0.1]), rotation=down, jacobian=jac,
                           twist=np.array([0, 0, -speed_down, 0, 0, 0]), dq=np.array([0, 0, -speed_down, 0, 0, 0, 0]),
                           wrench_tool=np.array([0, 0, f_meas, 0, 0, 0]))
        return float(ctrl.torque(state, ref)[2])

    d_z = params.damping_linear[2]
    # below the cap, or in contact: only the paper's damping (tool z is world −z, so +force_tool is −world)
    assert fz_world(0.02, 0.0) == pytest.approx(d_z * 0.02)
    assert fz_world(0.10, 10.0) == pytest.approx(d_z * 0.10)
    # out of contact and above the cap: the excess speed is damped as well
    expected = d_z * 0.10 + params.approach_damping_z * (0.10 - params.approach_speed_max)
    assert fz_world(0.10, 0.0) == pytest.approx(expected)
    # the cap fades out around approach_below × the set point (5 N here) instead of switching: a pad compressing
    # while the force ramps through 5 N sees no step in the command
    cap = params.approach_damping_z * (0.10 - params.approach_speed_max)
    assert fz_world(0.10, 5.0) == pytest.approx(d_z * 0.10 + 0.5 * cap)
    assert fz_world(0.10, 5.0 * (1 - APPROACH_FADE_BAND)) == pytest.approx(expected)
    assert fz_world(0.10, 5.0 * (1 + APPROACH_FADE_BAND)) == pytest.approx(d_z * 0.10)
    sweep = [fz_world(0.10, f) for f in np.arange(3.0, 7.0, 0.05)]
    assert np.abs(np.diff(sweep)).max() < 0.1 * cap


def test_commanded_approach_speed_is_a_damping_feed_forward_out_of_contact_only():
    """With ``approach_speed_m_s`` the pressing axis's damping pulls towards that speed instead of rest, the cap
    rises to it, and in contact the reference's speed is ignored (eq. 47 unchanged)."""
    params = GaLineForceParams(kp=0.0, ki=0.0, kd=0.0, latency_horizon_ticks=0.0)
    down = np.diag([1.0, -1.0, -1.0])
    jac = np.hstack([np.eye(6), np.zeros((6, 1))])
    d_z = params.damping_linear[2]

    def fz_world(speed_down: float, f_meas: float, v_cmd: float) -> float:
        ctrl = GaLineForceController(params)
        ref = LineForceReference(np.array([0.5, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), 3.0, v_cmd)
        state = make_state(position=np.array([0.5, 0.0, 0.1]), rotation=down, jacobian=jac,
                           twist=np.array([0, 0, -speed_down, 0, 0, 0]), dq=np.array([0, 0, -speed_down, 0, 0, 0, 0]),
                           wrench_tool=np.array([0, 0, f_meas, 0, 0, 0]))
        return float(ctrl.torque(state, ref)[2])  # world z; tool z is world −z

    # at rest it pushes towards the surface with D_z·v; at the commanded speed the push and the damping cancel
    assert fz_world(0.0, 0.0, 0.1) == pytest.approx(-d_z * 0.1)
    assert fz_world(0.1, 0.0, 0.1) == pytest.approx(0.0, abs=1e-9)
    # the cap acts above the commanded speed, not above approach_speed_max
    expected = d_z * 0.05 + params.approach_damping_z * 0.05
    assert fz_world(0.15, 0.0, 0.1) == pytest.approx(expected)
    # in contact: as without a commanded speed
    assert fz_world(0.0, 3.0, 0.1) == pytest.approx(fz_world(0.0, 3.0, 0.0))


def test_a_one_tick_wrench_dip_does_not_reach_the_torque():
    """A sliding pad's F/T shows one-tick dips of ~4 N; through K_d's high-frequency gain they stepped the
    joint torque by ~1 N·m (a torque-rate clip each). The 3-tick median drops them; a step passes one tick late."""
    forces = [10.0] * 40
    forces[20] = 6.0
    np.testing.assert_allclose(_pressing_torques(forces), _pressing_torques([10.0] * 40), atol=1e-12)


def _pressing_torques(forces_n, **params) -> np.ndarray:
    """Joint torques of a controller pressing 10 N at rest whose F/T reads ``forces_n`` along the tool axis."""
    jac = np.hstack([np.eye(6), np.zeros((6, 1))])
    ref = LineForceReference(np.array([0.5, 0.0, 0.3]), np.array([0.0, 0.0, 1.0]), 10.0)
    ctrl = _ctrl(**params)
    return np.array([ctrl.torque(make_state(t=k * 1e-3, rotation=DOWN, jacobian=jac,
                                            wrench_tool=np.array([0, 0, fz, 0, 0, 0])), ref)
                     for k, fz in enumerate(forces_n)])


def test_a_two_tick_slip_and_rebound_does_not_step_the_torque():
    """A sliding pad's F/T also dips for two ticks, a slip and its rebound (10 → 4 → 8.2 → 10 N measured in
    the clean with a mis-set tool). The 3-tick median passes the rebound twice and K_d's high-frequency gain
    turns it into a torque step of more than 1 N·m; the 5-tick median that replaces it where the two disagree
    by more than outlier_n removes the dip."""
    forces = [10.0] * 20 + [4.0, 8.2] + [10.0] * 20
    steady = _pressing_torques([10.0] * len(forces))
    short_only = _pressing_torques(forces, outlier_median_ticks=1)
    assert np.abs(np.diff(short_only[:, 2])).max() > 1.0  # the failure the long median is there for
    np.testing.assert_allclose(_pressing_torques(forces), steady, atol=1e-12)


def test_a_force_step_passes_the_outlier_median_two_ticks_late():
    """Where the two medians disagree only while a step is a tick old, the step reaches the command one
    tick later than through the 3-tick median alone, and whole."""
    forces = [10.0] * 20 + [14.0] * 20
    short_only = _pressing_torques(forces, outlier_median_ticks=1, kd=0.0)
    both = _pressing_torques(forces, kd=0.0)
    first = lambda taus: int(np.flatnonzero(np.abs(taus[:, 2] - taus[0, 2]) > 1e-9)[0])  # noqa: E731
    assert first(short_only) == 21 and first(both) == 22
    np.testing.assert_allclose(both[23:, 2] - both[22, 2], short_only[22:-1, 2] - short_only[21, 2], atol=1e-6)
