"""VA-UFIC's compiled tick gives the Python tick's torques and state to round-off, hands its state
to the Python objects whenever they are read, and falls back to Python only when told why."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactex.control import joint_kernels
from tactex.control.friction import FrictionCompensator
from tactex.control.references import PoseForceReference
from tactex.control.state import RobotState
from tactex.control.va_ufic import VaUficController, VaUficParams
from tactex.errors import ControllerFault
from tactex.geometry import exp_so3
from tactex.geometry.so3 import exp_so3_rows, log_so3_rows
from tactex.perception.estimate import SurfaceEstimate

pytestmark = pytest.mark.skipif(not joint_kernels.available(), reason="numba is not installed (the fast extra)")

#: Compiled and Python ticks agree to this error relative to the largest torque (same operations;
#: the re-orientation's start normalises with numpy in Python).
RTOL = 1e-10

_JAC = np.random.default_rng(1).normal(size=(6, 7))
_M = np.random.default_rng(2).normal(size=(7, 7))
_MASS = _M @ _M.T + 7.0 * np.eye(7)
_ROT0 = exp_so3(np.array([math.pi, 0.0, 0.0]))  # tool z down


class _Counted:
    """The compiled tick, counting its calls: a test of equality must see it run."""

    def __init__(self, kernel):
        self.kernel, self.calls = kernel, 0

    def __call__(self, *args):
        self.calls += 1
        return self.kernel(*args)


def _controller(compiled: bool, tanks: bool = True, friction: bool = True) -> VaUficController:
    ctrl = VaUficController(VaUficParams(tanks_enabled=tanks),
                            port_feedforward=FrictionCompensator() if friction else None)
    if compiled:
        assert ctrl._compiled is not None
        ctrl._compiled.kernel = _Counted(ctrl._compiled.kernel)
    else:
        ctrl._compiled = None
    return ctrl


def _ticks(n: int, seed: int = 0):
    """(state, reference) pairs of a scripted run: contact on and off every 0.4 s, a late tick every
    97, the surface estimate tilting, invalid for 20 ticks in every 300, stale now and then."""
    rng = np.random.default_rng(seed)
    pos, rv = np.array([0.5, 0.0, 0.3]), np.array([math.pi, 0.0, 0.0])
    for i in range(n):
        t = i * 1e-3 + (2e-3 if i % 97 == 0 else 0.0)
        rv = rv + rng.normal(size=3) * 2e-3
        pos = pos + rng.normal(size=3) * 2e-4
        fz = 15.0 + 5.0 * math.sin(i / 50) + rng.normal() * 2.0 if (i // 400) % 2 == 0 else rng.normal() * 0.3
        wrench = np.array([rng.normal() * 2, rng.normal() * 2, fz, rng.normal() * 0.1, rng.normal() * 0.1, 0.0])
        state = RobotState(t=t, q=np.zeros(7), dq=rng.normal(size=7) * 0.05, tau_measured=np.zeros(7),
                           ee_position=pos.copy(), ee_rotation=exp_so3(rv), ee_twist=rng.normal(size=6) * 0.05,
                           jacobian=_JAC, mass_matrix=_MASS, coriolis=np.zeros(7), gravity=np.zeros(7),
                           wrench_tool=wrench)
        normal = exp_so3(np.array([0.3 * math.sin(i / 700), 0.2, 0.0])) @ np.array([0.0, 0.0, 1.0])
        age = 0.6 if i % 500 == 250 else 0.01  # older than surface_max_age now and then
        est = SurfaceEstimate(valid=(i % 300) > 20, timestamp=t - age, normal_world=normal,
                              curvature=0.02 + 0.01 * math.sin(i / 100))
        ref = PoseForceReference(np.array([0.5, 0.01 * math.sin(i / 200), 0.3]), _ROT0,
                                 np.array([0.0, 0.0, 15.0, 0.0, 0.0, 0.0]), np.array([0.05, 0.01, 0.0, 0.0, 0.0, 0.1]),
                                 surface=est)
        yield state, ref


def _state_of(ctrl: VaUficController) -> dict:
    ti, tf = ctrl.tank_i, ctrl.tank_f
    return {"tank_i": (ti.energy, ti.delivered, ti.harvested, *ti._last), "tank_f": (tf.energy, tf.delivered,
            tf.harvested, *tf._last, tf.damping_harvested_w), "rho": ctrl.shaper.rho, "offset": ctrl.position_offset,
            "rot_d": ctrl.rotation_desired, "integral": ctrl._integral, "w_filt": ctrl._w_filt, "d": ctrl._d_tool_f,
            "friction": None if ctrl.port_feedforward is None else ctrl.port_feedforward.last}


@pytest.mark.parametrize(("tanks", "friction"), [(True, True), (True, False), (False, True)])
def test_the_compiled_tick_gives_the_python_ticks_torques_and_state(tanks, friction):
    a, b = _controller(True, tanks, friction), _controller(False, tanks, friction)
    realigned = False
    taus_a, taus_b = [], []
    for i, (state, ref) in enumerate(_ticks(3000)):
        if i == 0:
            a.reset(state)
            b.reset(state)
        taus_a.append(a.torque(state, ref))
        taus_b.append(b.torque(state, ref))
        realigned |= bool(b.telemetry()["realigning"])
        if i == 1500:  # set-up code poking a tank between ticks reaches the compiled tick
            a.tank_i.energy = b.tank_i.energy = 1.2
    taus_a, taus_b = np.array(taus_a), np.array(taus_b)
    assert a._compiled.kernel.calls == 3000 and realigned
    np.testing.assert_allclose(taus_a, taus_b, rtol=0, atol=RTOL * np.abs(taus_b).max())
    ta, tb = a.telemetry(), b.telemetry()
    assert ta.keys() == tb.keys()
    for key in ta:
        assert ta[key] == pytest.approx(tb[key], rel=1e-9, abs=1e-9), key
    sa, sb = _state_of(a), _state_of(b)
    for key in sa:
        if sb[key] is None:
            assert sa[key] is None, key
        else:
            np.testing.assert_allclose(np.asarray(sa[key], dtype=float), np.asarray(sb[key], dtype=float),
                                       rtol=1e-9, atol=1e-12, err_msg=key)


def test_reads_in_the_loop_come_from_the_vector_and_match_python():
    """What a task reads every tick (tick telemetry, the offset, R_d, the friction wrench) is read
    from the compiled tick's vector without handing it back to the objects."""
    a, b = _controller(True), _controller(False)
    for i, (state, ref) in enumerate(_ticks(700)):
        if i == 0:
            a.reset(state)
            b.reset(state)
        a.torque(state, ref)
        b.torque(state, ref)
        ta, tb = a.tick_telemetry(), b.tick_telemetry()
        assert ta.keys() == tb.keys() and all(ta[k] == pytest.approx(tb[k], abs=1e-9) for k in ta)
        np.testing.assert_allclose(a.position_offset, b.position_offset, atol=1e-12)
        np.testing.assert_allclose(a.rotation_desired, b.rotation_desired, atol=1e-12)
        np.testing.assert_allclose(a.port_wrench_last(), b.port_wrench_last(), atol=1e-9)
        if i % 20 == 0:
            a.telemetry()
        assert a._compiled.live  # none of these reads unpacked the vector


def test_a_non_finite_force_is_the_same_controller_fault_as_in_python():
    a, b = _controller(True), _controller(False)
    ticks = list(_ticks(3))
    for ctrl in (a, b):
        ctrl.reset(ticks[0][0])
        ctrl.torque(*ticks[0])
    state, ref = ticks[1]
    bad = RobotState(**{**{f: getattr(state, f) for f in state.__slots__},
                        "wrench_tool": np.array([np.nan, 0.0, 10.0, 0.0, 0.0, 0.0])})
    messages = []
    for ctrl in (a, b):
        with pytest.raises(ControllerFault, match="non-finite measured force") as info:
            ctrl.torque(bad, ref)
        messages.append(str(info.value))
    assert messages[0] == messages[1]
    assert a.shaper.rho == b.shaper.rho and a.tank_i.energy == b.tank_i.energy  # the same partial tick


def test_another_port_feedforward_runs_the_python_tick():
    class Push:
        def reset(self):
            pass

        def wrench_tool(self, state, rho_align, dt):
            return (1.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    assert VaUficController(port_feedforward=Push())._compiled is None
    assert VaUficController()._compiled is not None


def test_arrays_the_tick_was_not_built_for_warn_and_leave_python():
    a, b = _controller(True), _controller(False)
    ticks = list(_ticks(40))
    for i, (state, ref) in enumerate(ticks):
        if i == 0:
            a.reset(state)
            b.reset(state)
        if i == 20:  # a float32 wrench: not a type the tick was compiled for
            state = RobotState(**{**{f: getattr(state, f) for f in state.__slots__},
                                  "wrench_tool": state.wrench_tool.astype(np.float32)})
            with pytest.warns(RuntimeWarning, match="runs its Python tick from now on"):
                tau_a = a.torque(state, ref)
        else:
            tau_a = a.torque(state, ref)
        tau_b = b.torque(state, ref)
        np.testing.assert_allclose(tau_a, tau_b, rtol=0, atol=RTOL * np.abs(tau_b).max())
    assert a._compiled is None


@pytest.mark.parametrize("angle", [0.0, 1e-13, 0.4, 2.0, math.pi - 1e-7, math.pi])
def test_the_ticks_rotation_helpers_equal_the_python_ones(angle):
    from tactex.control import va_ufic_tick as k

    joint_kernels.kernels()  # the module imports numba
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    rows = exp_so3_rows(*(angle * axis))
    np.testing.assert_allclose(k._exp_rows(*(angle * axis)), np.ravel(rows), atol=1e-15)
    np.testing.assert_allclose(k._log_rows(np.ravel(rows)), log_so3_rows(rows), atol=1e-12)
