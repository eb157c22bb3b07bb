"""Measured-friction compensation (tactex.control.friction) and its VA-UFIC port: the filter, the
bounds and gating, the lag it removes on a sliding point mass, and the impedance tank paying for it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactex.control import PoseForceReference, UficParams, VaUficController, VaUficParams
from tactex.control.friction import FrictionCompensator, FrictionCompensatorParams
from tactex.errors import ConfigError, ControllerFault
from tactex.tasks.wipe import WipeConfig
from tests.test_control_common import make_state

DT = 1e-3
MU, F_N = 0.4, 15.0  # the wipe scene's friction and force set point
K, MASS = 1000.0, 3.0  # Table I K_max (x, y) and UficParams' apparent mass
D = 2.0 * 0.7 * math.sqrt(MASS * K)  # UficParams.damping_tool in contact, x and y
DOWN = np.diag([1.0, -1.0, -1.0])
JAC = np.hstack([np.eye(6), np.zeros((6, 1))])  # torque = world wrench on the first 6 joints


def _state(f_tool, t: float = 0.0, twist=None):
    return make_state(t=t, wrench_tool=np.asarray(f_tool, dtype=float), rotation=DOWN, jacobian=JAC,
                      twist=None if twist is None else np.asarray(twist, dtype=float))


# -- parameters and inputs ------------------------------------------------------------------------
@pytest.mark.parametrize(("kwargs", "match"), [
    ({"gain": -0.1}, r"gain must lie in \[0, 1\], got -0.1"),
    ({"gain": 1.5}, r"gain must lie in \[0, 1\], got 1.5"),
    ({"gain": float("nan")}, r"gain must lie in \[0, 1\], got nan"),
    ({"cutoff_hz": 0.0}, r"cutoff_hz must be a finite number > 0, got 0.0"),
    ({"cutoff_hz": float("inf")}, r"cutoff_hz must be a finite number > 0, got inf"),
    ({"mu_max": -1.0}, r"mu_max must be a finite number > 0, got -1.0"),
    ({"max_force_n": 0.0}, r"max_force_n must be a finite number > 0, got 0.0"),
])
def test_params_validation(kwargs, match) -> None:
    with pytest.raises(ConfigError, match=match):
        FrictionCompensatorParams(**kwargs)


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"friction_gain": 2.0}, r"gain must lie in \[0, 1\], got 2.0"),
    ({"friction_cutoff_hz": -3.0}, r"cutoff_hz must be a finite number > 0, got -3.0"),
])
def test_wipe_config_validates_the_compensator(kwargs, match) -> None:
    with pytest.raises(ConfigError, match=match):
        WipeConfig(**kwargs)


@pytest.mark.parametrize(("f_tool", "rho", "dt", "match"), [
    ([np.nan, 0, 15, 0, 0, 0], 1.0, DT, "non-finite measured force"),
    ([0, 0, np.inf, 0, 0, 0], 1.0, DT, "non-finite measured force"),
    ([1, 0, 15, 0, 0, 0], 1.2, DT, r"ρ_align in \[0, 1\], got 1.2"),
    ([1, 0, 15, 0, 0, 0], float("nan"), DT, r"ρ_align in \[0, 1\], got nan"),
    ([1, 0, 15, 0, 0, 0], 1.0, 0.0, "dt > 0 .s., got 0.0"),
])
def test_bad_tick_inputs_raise(f_tool, rho, dt, match) -> None:
    with pytest.raises(ControllerFault, match=match):
        FrictionCompensator().wrench_tool(_state(f_tool), rho, dt)


# -- what it outputs ------------------------------------------------------------------------------
def test_step_response_is_the_first_order_low_pass() -> None:
    fc, g = 10.0, 0.9
    comp = FrictionCompensator(FrictionCompensatorParams(gain=g, cutoff_hz=fc))
    comp.wrench_tool(_state([0, 0, F_N, 0, 0, 0]), 1.0, DT)  # starts at the first measurement: 0
    step = np.array([3.0, -4.0])
    out = [np.asarray(comp.wrench_tool(_state([*step, F_N, 0, 0, 0]), 1.0, DT)) for _ in range(50)]
    a = 1.0 - math.exp(-2.0 * math.pi * fc * DT)
    for n in (1, 10, 50):
        expected = g * step * (1.0 - (1.0 - a) ** n)
        assert out[n - 1][:2] == pytest.approx(expected, rel=1e-12)
    assert all(np.all(w[2:] == 0.0) for w in out)  # never along the force axis, never a moment


def test_first_measurement_passes_without_transient_and_reset_forgets() -> None:
    comp = FrictionCompensator(FrictionCompensatorParams(gain=1.0))
    w = np.asarray(comp.wrench_tool(_state([2.0, 1.0, F_N, 0, 0, 0]), 1.0, DT))
    assert w[:2] == pytest.approx([2.0, 1.0], rel=1e-12)
    np.testing.assert_array_equal(comp.last, w)  # what the wipe logs is what was returned
    comp.reset()
    assert np.all(comp.last == 0.0)
    w = np.asarray(comp.wrench_tool(_state([-1.0, 0.5, F_N, 0, 0, 0]), 1.0, DT))
    assert w[:2] == pytest.approx([-1.0, 0.5], rel=1e-12)


def test_coulomb_cone_and_absolute_bounds_keep_the_direction() -> None:
    comp = FrictionCompensator(FrictionCompensatorParams(gain=1.0, mu_max=0.5, max_force_n=4.0))
    w = np.asarray(comp.wrench_tool(_state([6.0, 8.0, 5.0, 0, 0, 0]), 1.0, DT))  # |f_t| = 10 N > 0.5 · 5 N
    assert np.linalg.norm(w[:2]) == pytest.approx(2.5, rel=1e-12)
    assert w[:2] / np.linalg.norm(w[:2]) == pytest.approx([0.6, 0.8], rel=1e-12)
    comp.reset()
    w = np.asarray(comp.wrench_tool(_state([6.0, 8.0, 40.0, 0, 0, 0]), 1.0, DT))  # cone 20 N, absolute cap 4 N
    assert np.linalg.norm(w[:2]) == pytest.approx(4.0, rel=1e-12)


@pytest.mark.parametrize("f_z", [0.0, -3.0])
def test_no_pressing_force_no_compensation(f_z) -> None:
    comp = FrictionCompensator()
    assert np.all(np.asarray(comp.wrench_tool(_state([5.0, -2.0, f_z, 0, 0, 0]), 1.0, DT)) == 0.0)


@pytest.mark.parametrize("rho", [0.0, 0.25, 1.0])
def test_scales_with_rho_align(rho) -> None:
    comp = FrictionCompensator(FrictionCompensatorParams(gain=0.8))
    w = comp.wrench_tool(_state([3.0, 0.0, F_N, 0, 0, 0]), rho, DT)
    assert w[0] == pytest.approx(0.8 * rho * 3.0, rel=1e-12, abs=1e-15)


def test_filter_attenuates_sensor_noise_as_predicted() -> None:
    fc, sigma = 10.0, 0.5
    rng = np.random.default_rng(7)
    comp = FrictionCompensator(FrictionCompensatorParams(gain=1.0, cutoff_hz=fc))
    out = np.array([comp.wrench_tool(_state([6.0 + sigma * rng.normal(), 0, F_N, 0, 0, 0]), 1.0, DT)[0]
                    for _ in range(20000)])[1000:]
    a = 1.0 - math.exp(-2.0 * math.pi * fc * DT)
    assert np.mean(out) == pytest.approx(6.0, abs=0.02)
    # a first-order filter x += a(u − x) passes white noise with std σ·√(a / (2 − a))
    assert np.std(out) == pytest.approx(sigma * math.sqrt(a / (2.0 - a)), rel=0.1)


# -- the lag it removes -----------------------------------------------------------------------------
def _slide(gain: float | None, seconds: float = 2.0) -> np.ndarray:
    """A point mass on a spring-damper to a set point moving at 8 cm/s along a 30° line, with Coulomb
    friction μ·f_n (regularised over 1 mm/s); returns the steady error x − x_d [m]."""
    u = np.array([math.cos(math.pi / 6), math.sin(math.pi / 6)])
    v_d = 0.08 * u
    comp = None if gain is None else FrictionCompensator(FrictionCompensatorParams(gain=gain))
    x, v = np.zeros(2), v_d.copy()
    for k in range(int(seconds / DT)):
        t = k * DT
        speed = float(np.linalg.norm(v))
        f_fric = -MU * F_N * math.tanh(speed / 1e-3) * (v / speed if speed > 0 else np.zeros(2))
        f = -K * (x - v_d * t) - D * (v - v_d)
        if comp is not None:  # the tool pushes on the surface with −f_fric: that is what the sensor reads
            f = f + comp.wrench_tool(_state([*(-f_fric), F_N, 0, 0, 0], t=t), 1.0, DT)[:2]
        v = v + DT * (f + f_fric) / MASS
        x = x + DT * v
    return x - v_d * seconds


@pytest.mark.parametrize("gain", [None, 0.9, 1.0])
def test_compensation_removes_the_friction_lag(gain) -> None:
    err = _slide(gain)
    u = np.array([math.cos(math.pi / 6), math.sin(math.pi / 6)])
    lag = -float(err @ u)
    expected = (1.0 - (gain or 0.0)) * MU * F_N / K  # 6 mm uncompensated, 0.6 mm at g = 0.9
    assert lag == pytest.approx(expected, abs=0.02 * MU * F_N / K)
    assert abs(float(err @ np.array([-u[1], u[0]]))) < 1e-6  # no error across the motion


# -- VA-UFIC routes it through the impedance tank -----------------------------------------------------
class _Constant:
    def __init__(self, wrench) -> None:
        self.wrench = np.asarray(wrench, dtype=float)
        self.resets = 0

    def reset(self) -> None:
        self.resets += 1

    def wrench_tool(self, state, rho_align, dt) -> np.ndarray:
        return self.wrench


def _va_tick(hook, tank_x0: float = 7.0, v: float = 0.1):
    ufic = UficParams(latency_horizon_ticks=0.0, kp=0.0, ki=0.0)  # eq. 13 as computed
    params = VaUficParams(rho_align_initial=1.0, ufic=ufic, tank_i_x0=tank_x0)
    ctrl = VaUficController(params, port_feedforward=hook)
    twist = np.array([v, 0, 0, 0, 0, 0])
    state = _state([0, 0, F_N, 0, 0, 0], twist=twist)
    ref = PoseForceReference(state.ee_position.copy(), DOWN, np.zeros(6), twist_world=twist)
    before = ctrl.tank_i.energy
    return ctrl.torque(state, ref), ctrl, before


def test_port_feedforward_is_applied_and_paid_by_the_impedance_tank() -> None:
    w = np.array([5.0, -2.0, 0.0, 0.0, 0.0, 0.0])  # tool frame
    tau_plain, plain, _ = _va_tick(None)
    tau_hook, ctrl, before = _va_tick(_Constant(w))
    assert ctrl.tank_i.last.valve == pytest.approx(1.0)
    assert tau_hook - tau_plain == pytest.approx(JAC.T @ np.concatenate([DOWN @ w[:3], np.zeros(3)]), abs=1e-12)
    # the port delivers ẋᵀ(D ẋ_d + f_comp) now; the difference is the compensation's power, from the tank
    xdot_tool = DOWN.T @ np.array([0.1, 0.0, 0.0])
    extra = ctrl.tank_i.last.port_power - plain.tank_i.last.port_power
    assert extra == pytest.approx(float(xdot_tool @ w[:3]), rel=1e-12)
    assert ctrl.tank_i.energy - before == pytest.approx(
        DT * (ctrl.tank_i.last.harvest_power - ctrl.tank_i.last.port_power), abs=1e-12)


def test_an_empty_impedance_tank_cuts_the_compensation() -> None:
    w = np.array([5.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    x0 = math.sqrt(2.0 * 1.0) + 1e-9  # S_t,i just above its lower limit of 1 J: valve shut
    tau_plain, _, _ = _va_tick(None, tank_x0=x0)
    tau_hook, ctrl, _ = _va_tick(_Constant(w), tank_x0=x0)
    assert ctrl.tank_i.last.valve == pytest.approx(0.0, abs=1e-6)
    assert tau_hook == pytest.approx(tau_plain, abs=1e-5)
    assert ctrl.tank_i.energy >= ctrl.tank_i.lower


def test_controller_reset_resets_the_hook() -> None:
    hook = _Constant(np.zeros(6))
    ctrl = VaUficController(port_feedforward=hook)
    ctrl.reset(_state([0, 0, 0, 0, 0, 0]))
    assert hook.resets == 1
