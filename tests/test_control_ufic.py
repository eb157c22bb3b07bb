"""UFIC (eq. 1–13), VA-UFIC (eq. 14–73) on synthetic states, and the Cartesian impedance baseline."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from tactex.control import (
    CartesianImpedanceController,
    PoseForceReference,
    UficController,
    UficParams,
    VaUficController,
    VaUficParams,
    desired_rotation_from_normal,
)
from tactex.errors import ConfigError, ControllerFault, InputError
from tactex.geometry import exp_so3
from tactex.perception.estimate import SurfaceEstimate
from tests.test_control_common import make_state

TOL = 1e-9
DOWN = np.diag([1.0, -1.0, -1.0])
JAC = np.hstack([np.eye(6), np.zeros((6, 1))])  # torque = world wrench on the first 6 joints
F15 = np.array([0, 0, 15.0, 0, 0, 0])


def _ref(position, rotation=DOWN, wrench=F15, surface=None):
    return PoseForceReference(np.asarray(position, float), rotation, wrench, surface=surface)


def test_ufic_spring_damper_and_force_feedforward():
    params = UficParams(latency_horizon_ticks=0.0, kp=0.0, ki=0.0)
    ctrl = UficController(params)
    state = make_state(position=np.array([0.51, 0.0, 0.3]), rotation=DOWN, jacobian=JAC,
                       twist=np.array([0.1, 0, 0, 0, 0, 0]))
    tau = ctrl.torque(state, _ref([0.5, 0.0, 0.3]))
    d = params.damping_tool()
    # x: spring −1000·0.01 and damping −D_x·0.1; z: 15 N along tool z = world −z
    assert tau[0] == pytest.approx(-1000 * 0.01 - d[0] * 0.1)
    assert tau[2] == pytest.approx(-15.0)
    np.testing.assert_allclose(tau[3:6], 0.0, atol=TOL)


def test_ufic_force_pi_sign_is_negative_feedback():
    ctrl = UficController(UficParams(latency_horizon_ticks=0.0, kp=0.6, ki=0.3))
    state = make_state(rotation=DOWN, jacobian=JAC, wrench_tool=np.array([0, 0, 10.0, 0, 0, 0]))
    tau = ctrl.torque(state, _ref(state.ee_position))
    # measured 10 N < 15 N wanted: command more than the feed-forward (along tool z = world −z)
    assert tau[2] == pytest.approx(-(15.0 + 0.6 * 5.0 + 0.3 * 5.0 * 1e-3))


def test_ufic_rejects_wrong_reference():
    with pytest.raises(ControllerFault, match="PoseForceReference"):
        UficController().torque(make_state(), object())


def test_reference_validation():
    with pytest.raises(InputError, match="rotation_world"):
        PoseForceReference(np.zeros(3), 2.0 * np.eye(3))
    with pytest.raises(InputError, match="wrench_tool"):
        PoseForceReference(np.zeros(3), np.eye(3), np.zeros(5))


def test_desired_rotation_from_normal_eq_23_27(rng):
    rot = exp_so3(rng.normal(size=3))
    z = rng.normal(size=3)
    z /= np.linalg.norm(z)
    r = desired_rotation_from_normal(rot, z)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=TOL)
    assert np.linalg.det(r) == pytest.approx(1.0)
    np.testing.assert_allclose(r[:, 2], z, atol=TOL)
    x_proj = rot[:, 0] - (rot[:, 0] @ z) * z
    np.testing.assert_allclose(r[:, 0], x_proj / np.linalg.norm(x_proj), atol=TOL)


@pytest.mark.parametrize("z", [np.zeros(3), np.array([np.nan, 0, 1.0]), np.array([0.0, 1.0])])
def test_desired_rotation_from_normal_rejects_bad_normals(z):
    with pytest.raises(InputError, match="tool_z_world"):
        desired_rotation_from_normal(DOWN, z)


def test_ufic_feeds_the_desired_wrench_forward_on_every_axis():
    """Eq. 11: f_f = f_d + K_p f̃ + K_i ∫f̃; force_axes selects the fed-back error only. A tangential
    set point on an axis without feedback is applied, not dropped."""
    ctrl = UficController(UficParams(latency_horizon_ticks=0.0, kp=0.6, ki=0.0))
    state = make_state(rotation=DOWN, jacobian=JAC, wrench_tool=np.array([2.0, 0, 15.0, 0, 0, 0]))
    tau = ctrl.torque(state, _ref(state.ee_position, wrench=np.array([5.0, 0, 15.0, 0, 0, 0])))
    assert tau[0] == pytest.approx(5.0)  # tool x = world x: f_d only (the 3 N error on x is not fed back)
    assert tau[2] == pytest.approx(-15.0)


def _estimate(t, normal, curvature=0.0, valid=True):
    if not valid:
        return SurfaceEstimate.invalid(t, "no segment")
    return SurfaceEstimate(valid=True, timestamp=t, normal_world=np.asarray(normal, float), curvature=curvature,
                           theta_rad=0.0)


def test_va_ufic_compliant_start_feeds_back_position():
    """ρ_align(0) = 0: the translation error is zeroed by feeding the actual position back (no spring)."""
    ctrl = VaUficController(VaUficParams(ufic=UficParams(latency_horizon_ticks=0.0, kp=0.0, ki=0.0)))
    state = make_state(position=np.array([0.55, 0.02, 0.3]), rotation=DOWN, jacobian=JAC)
    tau = ctrl.torque(state, _ref([0.5, 0.0, 0.3]))
    assert tau[0] == pytest.approx(0.0, abs=TOL) and tau[1] == pytest.approx(0.0, abs=TOL)
    tel = ctrl.telemetry()
    assert tel["rho_align"] < 0.01 and tel["rho_frc"] == 1.0
    assert tau[2] == pytest.approx(-15.0 * tel["tank_f_multiplier"])


def test_va_ufic_full_stiffness_when_aligned():
    ufic = UficParams(latency_horizon_ticks=0.0, kp=0.0, ki=0.0)
    ctrl = VaUficController(VaUficParams(rho_align_initial=1.0, ufic=ufic))
    state = make_state(position=np.array([0.51, 0.0, 0.3]), rotation=DOWN, jacobian=JAC)
    tau = ctrl.torque(state, _ref([0.5, 0.0, 0.3]))
    tel = ctrl.telemetry()
    assert tel["tank_i_valve"] == 1.0
    assert tau[0] == pytest.approx(-1000.0 * tel["rho_align"] * 0.01, rel=1e-9)


def test_va_ufic_realigns_to_the_surface_normal_over_T():
    normal = np.array([0.0, math.sin(0.3), math.cos(0.3)])  # surface tilted 0.3 rad about x
    params = VaUficParams(realign_time=0.5)
    ctrl = VaUficController(params)
    for k in range(700):
        t = k * 1e-3
        state = make_state(t=t, rotation=DOWN, jacobian=JAC)
        ctrl.torque(state, _ref(state.ee_position, surface=_estimate(t, normal)))
        if k == 1:
            assert ctrl.telemetry()["realigning"] == 1.0
        if k == 250:  # halfway through T: half the angle (eq. 28–29)
            assert math.acos(ctrl.rotation_desired[:, 2] @ -normal) == pytest.approx(0.15, abs=2e-3)
    np.testing.assert_allclose(ctrl.rotation_desired[:, 2], -normal, atol=1e-9)
    assert ctrl.telemetry()["realigning"] == 0.0


def _float_body(ctrl, normal, steps):
    """A free unit-inertia body (J = [I₆ | 0]) under VA-UFIC, surface seen tilted by ``normal``: no
    contact, no external force. Returns the largest rise of S_overall (eq. 46/69) over its start [J]."""
    from dataclasses import replace

    p, rot, v, w = np.array([0.5, 0, 0.3]), DOWN.copy(), np.zeros(3), np.zeros(3)
    s0, rise = None, 0.0
    for k in range(steps):
        t = k * 1e-3
        state = replace(make_state(t=t, position=p, rotation=rot, twist=np.concatenate([v, w]), jacobian=JAC),
                        dq=np.concatenate([v, w, [0.0]]))
        tau = ctrl.torque(state, _ref([0.5, 0, 0.3], wrench=np.zeros(6), surface=_estimate(t, normal)))
        s = ctrl.telemetry()["storage_overall_j"]
        s0 = s if s0 is None else s0
        rise = max(rise, s - s0)
        v, w = v + 1e-3 * tau[:3], w + 1e-3 * tau[3:6]  # semi-implicit Euler
        p, rot = p + 1e-3 * v, exp_so3(w * 1e-3) @ rot
    return rise


def test_va_ufic_pays_the_realignment_from_the_impedance_tank():
    """Moving R_d (eq. 28–29) pulls the constant rotational spring: the energy it puts in comes from
    the impedance tank, so the total storage never rises (before: +0.86 J over the re-orientation)."""
    normal = np.array([0.0, math.sin(0.3), math.cos(0.3)])
    ctrl = VaUficController()
    rise = _float_body(ctrl, normal, 2500)
    assert ctrl.tank_i.delivered > 0.5  # the tank paid for the move
    assert rise < 0.02  # integration error only (the same body without re-orientation: 0.035 J)
    np.testing.assert_allclose(ctrl.rotation_desired[:, 2], -normal, atol=1e-9)  # and the move completed


def test_va_ufic_realignment_waits_for_an_empty_tank():
    normal = np.array([0.0, math.sin(0.3), math.cos(0.3)])
    ctrl = VaUficController(VaUficParams(tank_i_x0=1.42))  # 1.008 J over a 1 J lower limit
    rise = _float_body(ctrl, normal, 1500)
    assert ctrl.tank_i.energy >= 1.0 and rise < 0.02
    # R_d advances only as fast as the damping refills the tank: 0.5 s past T = 1 s (where a full tank
    # has long finished the 0.3 rad) it is about half-way
    tilt = math.acos(float(np.clip(ctrl.rotation_desired[:, 2] @ np.array([0.0, 0.0, -1.0]), -1.0, 1.0)))
    assert tilt < 0.22
    assert ctrl.telemetry()["realigning"] == 1.0


def test_va_ufic_resume_keeps_the_tanks_reset_refills_them():
    ctrl = VaUficController(VaUficParams(rho_align_initial=1.0))
    for k in range(400):  # the tool dragged along a stretched spring: the port drains the tank
        state = make_state(t=k * 1e-3, position=np.array([0.7, 0, 0.3]), rotation=DOWN, jacobian=JAC,
                           twist=np.array([-0.02, 0, 0, 0, 0, 0]))
        ctrl.torque(state, _ref([0.5, 0, 0.3]))
    drained, delivered = ctrl.tank_i.energy, ctrl.tank_i.delivered
    assert drained < 24.0 and delivered > 0.0
    ctrl._rot_d = exp_so3(np.array([0.2, 0.0, 0.0])).tolist()  # as if vision had re-oriented it
    rot_d = ctrl.rotation_desired
    ctrl.resume(make_state(t=1.0))
    assert ctrl.tank_i.energy == drained and ctrl.tank_i.delivered == delivered
    np.testing.assert_array_equal(ctrl.rotation_desired, rot_d)  # R_d stays: re-reading it would swing the spring
    assert np.all(ctrl.position_offset == 0.0) and ctrl.telemetry() == {}  # the rest restarts
    ctrl.reset(make_state(t=1.0))
    assert ctrl.tank_i.energy == pytest.approx(24.5) and ctrl.tank_i.delivered == 0.0
    assert ctrl.rotation_desired is None


@pytest.mark.parametrize("case", ["none", "invalid", "stale", "nan"])
def test_va_ufic_ignores_unusable_estimates(case):
    normal = np.array([0.0, math.sin(0.3), math.cos(0.3)])
    ctrl = VaUficController()
    t = 2.0
    est = {"none": None, "invalid": _estimate(t, normal, valid=False), "stale": _estimate(t - 1.0, normal),
           "nan": SurfaceEstimate(valid=True, timestamp=t, normal_world=np.full(3, np.nan), curvature=0.0)}[case]
    tau = ctrl.torque(make_state(t=t, rotation=DOWN, jacobian=JAC), _ref([0.5, 0, 0.3], surface=est))
    tel = ctrl.telemetry()
    assert np.isfinite(tau).all()
    assert tel["surface_usable"] == 0.0 and tel["realigning"] == 0.0 and tel["theta_rad"] == 0.0


def test_va_ufic_high_curvature_makes_it_compliant():
    ctrl = VaUficController(VaUficParams(rho_align_initial=1.0))
    normal = np.array([0.0, 0.0, 1.0])
    for k in range(3000):
        t = k * 1e-3
        est = _estimate(t, normal, 0.2)
        ctrl.torque(make_state(t=t, rotation=DOWN, jacobian=JAC), _ref([0.5, 0, 0.3], surface=est))
    tel = ctrl.telemetry()
    assert tel["alignment_h"] < 0.0  # C = γ·l_s = 2 > C_m
    assert tel["rho_align"] < 0.05


def test_va_ufic_tanks_disabled_open_every_valve():
    ctrl = VaUficController(VaUficParams(tanks_enabled=False, tank_i_x0=1.5, rho_align_initial=1.0))
    for k in range(400):  # the tool moving along a stretched spring: the port would drain the tank
        state = make_state(t=k * 1e-3, position=np.array([0.7, 0, 0.3]), rotation=DOWN, jacobian=JAC,
                           twist=np.array([-0.02, 0, 0, 0, 0, 0]))
        ctrl.torque(state, _ref([0.5, 0, 0.3]))
    tel = ctrl.telemetry()
    assert tel["tank_i_valve"] == 1.0 and tel["tank_i_energy_j"] < 1.0  # shadow tank ran below its limit


@pytest.mark.parametrize(("kwargs", "match"), [({"c_margin": 0.0}, "c_margin"), ({"xi": -1.0}, "xi"),
                                               ({"rho_align_initial": 2.0}, "rho_align_initial"),
                                               ({"stiffness_const": (1.0,)}, "stiffness_const")])
def test_va_ufic_params_validation(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        VaUficParams(**kwargs)


def test_ufic_params_validation():
    with pytest.raises(ConfigError, match="stiffness_max"):
        UficParams(stiffness_max=(1.0, 2.0))
    with pytest.raises(ConfigError, match="dt"):
        UficParams(dt=0.0)


def test_cartesian_impedance_baseline():
    ctrl = CartesianImpedanceController()
    rd = DOWN
    state = make_state(position=np.array([0.5, 0.0, 0.31]), rotation=exp_so3(np.array([0, 0, 0.1])) @ rd,
                       jacobian=JAC)
    tau = ctrl.torque(state, PoseForceReference(np.array([0.5, 0.0, 0.3]), rd, np.zeros(6)))
    assert tau[2] == pytest.approx(-150.0 * 0.01)
    assert tau[5] == pytest.approx(-10.0 * 0.1)


def test_ufic_damps_the_approach_more_than_the_contact():
    # switched at once, on the raw wrench (no low-pass)
    params = UficParams(latency_horizon_ticks=0.0, kp=0.0, ki=0.0, damping_switch_s=0.0, wrench_cutoff_hz=1e9)
    ctrl = UficController(params)
    twist = np.array([0.0, 0.0, -0.1, 0, 0, 0])  # moving along the tool axis (world −z) at 0.1 m/s
    ref = _ref([0.5, 0.0, 0.3], wrench=np.zeros(6))
    free = ctrl.torque(make_state(rotation=DOWN, jacobian=JAC, twist=twist), ref)
    touching = ctrl.torque(make_state(t=1e-3, rotation=DOWN, jacobian=JAC, twist=twist,
                                      wrench_tool=np.array([0, 0, 5.0, 0, 0, 0])), ref)
    d_contact = 2 * 0.7 * math.sqrt(3.0 * 1000.0)
    assert free[2] == pytest.approx(250.0 * 0.1)
    assert touching[2] == pytest.approx(d_contact * 0.1)
    # by default the tool-axis damping moves to the new value with the time constant damping_switch_s
    ctrl = UficController(replace(params, damping_switch_s=0.02))  # starts with the contact damping
    free = ctrl.torque(make_state(rotation=DOWN, jacobian=JAC, twist=twist), ref)
    assert free[2] == pytest.approx((d_contact + 1e-3 / (1e-3 + 0.02) * (250.0 - d_contact)) * 0.1)
    with pytest.raises(ConfigError, match="approach_damping_z"):
        UficParams(approach_damping_z=-1.0)


def test_va_ufic_reports_storage_functions():
    ctrl = VaUficController(VaUficParams(rho_align_initial=1.0))
    dq = np.linspace(0.1, 0.7, 7)
    state = make_state(position=np.array([0.51, 0.0, 0.3]), rotation=DOWN, jacobian=JAC, dq=dq)
    ctrl.torque(state, _ref([0.5, 0.0, 0.3]))
    tel = ctrl.telemetry()
    assert tel["kinetic_energy_j"] == pytest.approx(0.5 * float(dq @ dq))  # mass matrix = I in make_state
    assert tel["spring_energy_var_j"] == pytest.approx(0.5 * tel["rho_align"] * 1000.0 * 0.01**2)
    assert tel["storage_overall_j"] == pytest.approx(
        tel["spring_energy_const_j"] + tel["tank_i_energy_j"] + tel["tank_f_energy_j"] + tel["kinetic_energy_j"])
