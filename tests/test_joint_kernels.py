"""The compiled joint-space kernels give the numpy reference's torques to round-off, and the
controllers run them (and fall back to numpy only when told why)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tactex.control import joint_kernels
from tactex.control.nullspace import PINV_DAMPING, NullspacePosture
from tactex.control.references import PoseForceReference
from tactex.control.safety import SafetyLayer
from tactex.control.ufic import UficController
from tactex.geometry import exp_so3
from tactex.robots.mujoco_backend import MujocoBackend
from tactex.sim.scene import SceneConfig

pytestmark = pytest.mark.skipif(not joint_kernels.available(), reason="numba is not installed (the fast extra)")

#: Compiled and numpy torques agree to this relative error (the same LU, other summation orders).
RTOL = 1e-10


class _Zero:
    name = "zero"

    def reset(self, state):
        pass

    def resume(self, state):
        pass

    def torque(self, state, reference):
        return np.zeros(7)


@pytest.fixture(scope="module")
def states():
    """Franka states in a few postures, with MuJoCo's model terms."""
    backend = MujocoBackend(SceneConfig())
    rng = np.random.default_rng(3)
    out = []
    try:
        state = backend.reset(seed=0)
        for _ in range(5):
            out.append(state)
            for _ in range(40):  # wander: random torques move the arm to other postures and velocities
                backend.apply_torque(rng.normal(0.0, 2.0, 7))
                state = backend.step()
    finally:
        backend.close()
    return out


@pytest.fixture
def counted(monkeypatch):
    """The kernels, counting their calls: a test of equality must see the compiled path run."""
    k = joint_kernels.kernels()
    calls = {"task": 0, "posture": 0}

    def task(*args):
        calls["task"] += 1
        return k.task_torque(*args)

    def posture(*args):
        calls["posture"] += 1
        return k.posture_torque(*args)

    monkeypatch.setattr(joint_kernels, "_kernels", joint_kernels.JointKernels(task, posture))
    return calls


def _numpy(ctrl):
    ctrl._kernels = None
    if hasattr(ctrl, "inner"):
        ctrl.inner._kernels = None
    return ctrl


def test_the_kernels_are_built_with_numba():
    k = joint_kernels.kernels()
    assert k is not None and k is joint_kernels.kernels()  # built once per process


def test_compiled_task_torque_equals_numpy(states, counted):
    rng = np.random.default_rng(0)
    compiled, numpy_ref = UficController(), _numpy(UficController())
    n = 0
    for state in states:
        for _ in range(5):
            f_world = tuple(rng.normal(0.0, 10.0, 6).tolist())
            a = compiled.joint_torque(state, f_world)
            b = numpy_ref.joint_torque(state, f_world)
            n += 1
            np.testing.assert_allclose(a, b, rtol=RTOL, atol=RTOL * np.abs(b).max())
    assert counted["task"] == n


def test_compiled_posture_torque_equals_numpy(states, counted):
    rng = np.random.default_rng(1)
    q_post = states[0].q + rng.normal(0.0, 0.2, 7)
    compiled = NullspacePosture(_Zero(), q_posture=q_post)
    numpy_ref = _numpy(NullspacePosture(_Zero(), q_posture=q_post))
    for state in states:
        a, b = compiled.torque(state, None), numpy_ref.torque(state, None)
        assert np.abs(b).max() > 0.1  # a real posture torque, not a trivial zero
        np.testing.assert_allclose(a, b, rtol=RTOL, atol=RTOL * np.abs(b).max())
    assert counted["posture"] == len(states)


def test_the_kernels_called_directly_equal_numpys_solves(states):
    """The kernels' own arithmetic (their written-out Cholesky solves), apart from the controllers'
    plumbing, against the same formulas with numpy's LU solves."""
    k = joint_kernels.kernels()
    state = states[3]
    jac, rot, mass = state.jacobian, state.ee_rotation, state.mass_matrix
    rng = np.random.default_rng(2)
    f = rng.normal(0.0, 10.0, 6)
    d, kk, h = np.array([40.0, 40.0, 60.0, 2.0, 2.0, 2.0]), np.array([800.0, 800.0, 0.0, 40.0, 40.0, 40.0]), 0.003
    jt = np.vstack([rot.T @ jac[:3], rot.T @ jac[3:]])
    ref = mass @ np.linalg.solve(mass + jt.T @ np.diag(h * (d + h * kk)) @ jt, jac.T @ f)
    got = k.task_torque(jac, rot, mass, f, d, kk, h)
    np.testing.assert_allclose(got, ref, rtol=RTOL, atol=RTOL * np.abs(ref).max())
    q_post = state.q + 0.1
    tau0 = 20.0 * (q_post - state.q) - 9.0 * state.dq
    tau_ns = tau0 - jac.T @ np.linalg.solve(jac @ jac.T + PINV_DAMPING**2 * np.eye(6), jac @ tau0)
    ref = mass @ np.linalg.solve(mass + (h * 9.0 + h * h * 20.0) * np.eye(7), tau_ns)
    got = k.posture_torque(jac, mass, q_post, state.q, state.dq, 20.0, 9.0, h, PINV_DAMPING)
    np.testing.assert_allclose(got, ref, rtol=RTOL, atol=RTOL * np.abs(ref).max())


def test_a_matrix_that_is_not_positive_definite_gives_nan_not_an_exception():
    k = joint_kernels.kernels()
    jac, rot = np.ones((6, 7)), np.eye(3)
    tau = k.task_torque(jac, rot, -np.eye(7), np.ones(6), np.ones(6), np.ones(6), 0.003)
    assert tau.shape == (7,) and np.isnan(tau).all()


def test_the_kernels_can_be_built_again_in_one_process(monkeypatch):
    """A second build (after disable, e.g. in tests) compiles the helpers' Python forms again."""
    first = joint_kernels.kernels()
    monkeypatch.setattr(joint_kernels, "_kernels", None)
    monkeypatch.setattr(joint_kernels, "_failure", None)
    again = joint_kernels.kernels()
    assert again is not None and again is not first and again.va_ufic_tick is not None


def test_a_ufic_tick_is_the_same_with_and_without_the_kernels(states, counted):
    state = states[2]
    rot = exp_so3(np.array([0.05, -0.02, 0.01])) @ state.ee_rotation
    ref = PoseForceReference(state.ee_position + np.array([0.01, 0.0, -0.005]), rot,
                             np.array([0.0, 0.0, 15.0, 0.0, 0.0, 0.0]))
    a_ctrl, b_ctrl = NullspacePosture(UficController()), _numpy(NullspacePosture(UficController()))
    for c in (a_ctrl, b_ctrl):
        c.reset(state)
    a, b = a_ctrl.torque(state, ref), b_ctrl.torque(state, ref)
    np.testing.assert_allclose(a, b, rtol=RTOL, atol=RTOL * np.abs(b).max())
    assert counted == {"task": 1, "posture": 1}


def test_a_non_finite_controller_state_is_held_by_the_safety_layer_as_with_numpy(states):
    """numba's solve refuses NaN where numpy's returns it: both must end in the safety layer's hold."""
    state = states[1]
    ref = PoseForceReference(state.ee_position, state.ee_rotation, np.array([0.0, 0.0, 15.0, 0.0, 0.0, 0.0]))
    results = []
    for ctrl in (NullspacePosture(UficController()), _numpy(NullspacePosture(UficController()))):
        layer = SafetyLayer(ctrl)
        layer.reset(state)
        ctrl.inner._integral[2] = float("nan")  # a corrupted integrator
        tau = layer.torque(state, ref)
        results.append((tau, dict(layer.counts)))
    (tau_k, counts_k), (tau_n, counts_n) = results
    assert np.isfinite(tau_k).all() and counts_k == counts_n == {"nan_torque": 1}
    np.testing.assert_array_equal(tau_k, tau_n)


def test_arrays_the_kernel_was_not_built_for_warn_once_and_leave_numpy(states):
    state = states[1]
    ctrl = UficController()
    f_world = (1.0, -2.0, 15.0, 0.1, 0.0, -0.2)
    expected = ctrl.joint_torque(state, f_world)
    strided = np.zeros((6, 14))
    strided[:, ::2] = state.jacobian
    view = replace(state, jacobian=strided[:, ::2])  # a strided view: not the kernel's C-ordered type
    with pytest.warns(RuntimeWarning, match="strided.*runs numpy from now on"):
        got = ctrl.joint_torque(view, f_world)
    np.testing.assert_allclose(got, expected, rtol=RTOL, atol=1e-12)
    assert ctrl._kernels is None  # not tried again at every tick


def test_without_numba_the_controllers_use_numpy_and_the_lookup_is_not_repeated(monkeypatch):
    monkeypatch.setattr(joint_kernels, "_kernels", None)
    monkeypatch.setattr(joint_kernels, "_failure", None)
    looked = []
    monkeypatch.setattr(joint_kernels, "available", lambda: looked.append(1) or False)
    assert joint_kernels.kernels() is None and joint_kernels.kernels() is None
    assert looked == [1] and UficController()._kernels is None


def test_a_kernel_that_fails_to_build_warns_and_leaves_numpy(monkeypatch):
    import numba

    monkeypatch.setattr(joint_kernels, "_kernels", None)
    monkeypatch.setattr(joint_kernels, "_failure", None)

    def broken(*args, **kwargs):
        raise numba.core.errors.TypingError("no typing for this numba")

    monkeypatch.setattr(numba, "njit", broken)
    with pytest.warns(RuntimeWarning, match="running numpy.*no typing"):
        assert joint_kernels.kernels() is None
    assert joint_kernels.kernels() is None  # not tried again
    assert UficController()._kernels is None


def test_a_control_loop_builds_the_kernels_before_its_first_tick(monkeypatch):
    """Tasks build their controllers between moves, while a real robot's torque control runs: the
    kernels must already be there (building them takes seconds)."""
    from tactex.robots.loop import ControlLoop

    calls = []
    monkeypatch.setattr(joint_kernels, "kernels", lambda: calls.append("built"))
    backend = MujocoBackend(SceneConfig())
    try:
        ControlLoop(backend)
    finally:
        backend.close()
    assert calls  # asked for (by the loop and its safety layer) before any tick


@pytest.mark.parametrize("field", ["q", "dq", "tau_measured", "ee_position", "ee_rotation", "ee_twist", "jacobian",
                                   "mass_matrix", "coriolis", "gravity", "wrench_tool", "t"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_the_compiled_state_check_finds_a_non_finite_number_in_every_field(states, field, bad):
    from tactex.control.safety import _state_finite

    layer = SafetyLayer(_Zero())
    layer._finite_kernel = counted_kernel = _CountedKernel(layer._finite_kernel)
    assert layer._state_finite(states[0])
    if field == "t":
        state = replace(states[0], t=bad)
    else:
        a = getattr(states[0], field).copy()
        a.flat[a.size // 2] = bad
        state = replace(states[0], **{field: a})
    assert not layer._state_finite(state) and not _state_finite(state)
    assert counted_kernel.calls == 2


def test_a_state_the_compiled_check_was_not_built_for_warns_and_uses_numpy(states):
    layer = SafetyLayer(_Zero())
    state = replace(states[0], wrench_tool=states[0].wrench_tool.astype(np.float32))
    with pytest.warns(RuntimeWarning, match="checks with numpy from now on"):
        assert layer._state_finite(state)
    assert layer._finite_kernel is None


class _CountedKernel:
    def __init__(self, kernel):
        self.kernel, self.calls = kernel, 0

    def __call__(self, *args):
        self.calls += 1
        return self.kernel(*args)


class _Script:
    """Inner controller returning scripted torques."""

    name = "script"

    def __init__(self, taus):
        self.taus, self.i = taus, 0

    def reset(self, state):
        pass

    def resume(self, state):
        pass

    def torque(self, state, reference):
        self.i += 1
        return self.taus[self.i - 1]

    def telemetry(self):
        return {}


def test_the_compiled_limits_equal_the_python_ones_with_the_same_events(states):
    """Torques beyond the limits, jumps beyond the rate limit, joints past the margins, a NaN."""
    rng = np.random.default_rng(5)
    taus = [rng.normal(0.0, 40.0, 7) for _ in range(300)]
    taus[150] = np.full(7, np.nan)
    base = states[0]
    q_lo = SafetyLayer(_Zero())._q_lo_margin
    results = []
    for compiled in (True, False):
        layer = SafetyLayer(_Script(taus))
        if compiled:
            layer._limit_kernel = counted = _CountedKernel(layer._limit_kernel)
        else:
            layer._limit_kernel = None
        layer.reset(base)
        out = []
        for i in range(300):
            q = base.q.copy()
            if 100 <= i < 140:  # joint 3 past its lower margin
                q[3] = q_lo[3] - 0.01 * (i - 99)
            out.append(layer.torque(replace(base, t=i * 1e-3, q=q), None))
        results.append((np.array(out), [(e.kind, e.detail) for e in layer.events], dict(layer.counts)))
    (a, ev_a, counts_a), (b, ev_b, counts_b) = results
    np.testing.assert_array_equal(a, b)
    assert ev_a == ev_b and counts_a == counts_b
    assert counted.calls == 300  # every tick, the NaN's too (the kernel finds it, then the layer holds)
    assert {"torque_limit", "torque_rate_limit", "joint_limit", "nan_torque"} <= set(counts_a)
