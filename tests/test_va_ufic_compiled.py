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
            ta, tb = a.telemetry(), b.telemetry()
            assert ta.keys() == tb.keys() and all(ta[k] == pytest.approx(tb[k], abs=1e-9) for k in ta)
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


def _flat(value) -> list[float]:
    """Numbers of a nested field, None as NaN (for comparing fields of any shape)."""
    if value is None:
        return [math.nan]
    if isinstance(value, (bool, int, float, np.floating)):
        return [float(value)]
    if isinstance(value, np.ndarray):
        return value.astype(float).ravel().tolist()
    return [x for v in value for x in _flat(v)]


def test_every_field_of_every_object_ends_as_in_python_after_resets_and_resumes():
    """A field the Python tick changes that the compiled tick does not carry would differ here."""
    a, b = _controller(True), _controller(False)
    for i, (state, ref) in enumerate(_ticks(2000)):
        if i == 0:
            a.reset(state)
            b.reset(state)
        if i in (600, 1300):  # the safety layer's resume after a retreat, mid-run
            a.resume(state)
            b.resume(state)
        if i == 1700:
            a.reset(state)
            b.reset(state)
        a.torque(state, ref)
        b.torque(state, ref)
    a._objects()
    pairs = [(a, b), (a.tank_i, b.tank_i), (a.tank_f, b.tank_f), (a.shaper, b.shaper),
             (a.port_feedforward, b.port_feedforward)]
    objects = {"_compiled", "_kernels", "_tank_i", "_tank_f", "_shaper", "_port_feedforward", "params", "va"}
    for x, y in pairs:
        vx, vy = vars(x), vars(y)
        assert vx.keys() == vy.keys()
        for key in vx.keys() - objects:
            if key == "_raw":  # its last item is the state object
                vx_key, vy_key = vx[key][:-1], vy[key][:-1]
            else:
                vx_key, vy_key = vx[key], vy[key]
            np.testing.assert_allclose(_flat(vx_key), _flat(vy_key), rtol=1e-9, atol=1e-12,
                                       err_msg=f"{type(x).__name__}.{key}")


def test_a_degenerate_rotation_is_held_by_the_safety_layer_not_an_exception():
    """A zero rotation divides by zero on the way to a re-orientation: NaN, as in Python, then the
    layer's hold; never a ZeroDivisionError out of the control loop."""
    from tactex.control.safety import SafetyLayer

    results = []
    for compiled in (True, False):
        layer = SafetyLayer(_controller(compiled))
        state, ref = next(_ticks(1))
        layer.reset(state)
        bad = RobotState(**{**{f: getattr(state, f) for f in state.__slots__}, "ee_rotation": np.zeros((3, 3))})
        ticks = [layer.torque(bad, ref) for _ in range(3)]
        assert all(np.isfinite(t).all() for t in ticks)
        results.append((np.array(ticks), dict(layer.counts)))
    np.testing.assert_allclose(results[0][0], results[1][0], atol=1e-9)
    assert results[0][1] == results[1][1]


def test_a_re_orientation_from_a_non_finite_rotation_is_refused_as_in_python():
    from tactex.errors import InputError

    rds = []
    for compiled in (True, False):
        ctrl = _controller(compiled)
        ticks = list(_ticks(30))
        ctrl.reset(ticks[0][0])
        for state, ref in ticks[:21]:  # the estimate turns valid at tick 21 (tilted: a re-orientation is due)
            ctrl.torque(state, ref)
        state, ref = ticks[21]
        nan_rot = state.ee_rotation.copy()
        nan_rot[0, 0] = np.nan
        bad = RobotState(**{**{f: getattr(state, f) for f in state.__slots__}, "ee_rotation": nan_rot})
        ctrl._objects()
        assert ctrl._realign is None and ctrl.shaper.rho <= ctrl.va.compliant_below  # a re-orientation is due
        with pytest.raises(InputError, match="finite 3×3 rotation"):
            ctrl.torque(bad, ref)
        rds.append(ctrl.rotation_desired)
    assert np.isfinite(rds[0]).all()
    np.testing.assert_allclose(rds[0], rds[1], atol=1e-12)


def test_settings_changed_through_the_properties_reach_the_compiled_tick():
    a, b = _controller(True), _controller(False)
    taus = []
    for i, (state, ref) in enumerate(_ticks(600)):
        if i == 0:
            a.reset(state)
            b.reset(state)
        if i == 200:
            for c in (a, b):
                c.tank_i.enabled = False
                c.tank_i.energy = 1.05
        taus.append((a.torque(state, ref), b.torque(state, ref)))
    ta, tb = np.array([t[0] for t in taus]), np.array([t[1] for t in taus])
    np.testing.assert_allclose(ta, tb, rtol=0, atol=RTOL * np.abs(tb).max())
    assert a.tank_i.energy == pytest.approx(b.tank_i.energy, abs=1e-9)


def test_a_tank_held_across_compiled_ticks_warns_when_its_write_would_be_lost():
    ctrl = _controller(True)
    ticks = _ticks(20)
    state, ref = next(ticks)
    ctrl.reset(state)
    held = ctrl.tank_i
    ctrl.torque(state, ref)  # the vector holds the truth from here
    held.energy = 1.5
    with pytest.warns(RuntimeWarning, match="that write is lost"):
        ctrl.tank_i  # noqa: B018 (the read hands the state back)


def test_without_a_feed_forward_there_is_no_port_wrench_either_way():
    for compiled in (True, False):
        ctrl = _controller(compiled, friction=False)
        state, ref = next(_ticks(1))
        ctrl.reset(state)
        ctrl.torque(state, ref)
        assert ctrl.port_wrench_last() is None


def test_a_controller_with_the_compiled_tick_pickles_and_copies():
    import copy
    import pickle

    a = _controller(True)
    ticks = list(_ticks(200))
    a.reset(ticks[0][0])
    for state, ref in ticks[:100]:
        a.torque(state, ref)
    copies = [copy.deepcopy(a), pickle.loads(pickle.dumps(a))]
    for b in copies:
        assert b._compiled is not None and not b._compiled.live
    for state, ref in ticks[100:200]:
        tau = a.torque(state, ref)
        for b in copies:
            np.testing.assert_array_equal(b.torque(state, ref), tau)
    assert all(b.tank_i.energy == a.tank_i.energy for b in copies)
