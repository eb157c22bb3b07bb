"""The compiled joint-space kernels give the numpy reference's operators to round-off, the controllers
run them (and fall back to numpy only when told why), and an operator prepared after a command is
what the next tick applies while the arm stays at its posture."""

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
        return k.task_operator(*args)

    def posture(*args):
        calls["posture"] += 1
        return k.posture_operator(*args)

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


def test_the_kernels_called_directly_equal_the_numpy_reference(states):
    """The kernels' own arithmetic, apart from the controllers' plumbing."""
    k = joint_kernels.kernels()
    state = states[3]
    d, kk, h = np.array([40.0, 40.0, 60.0, 2.0, 2.0, 2.0]), np.array([800.0, 800.0, 0.0, 40.0, 40.0, 40.0]), 0.003
    ref = joint_kernels.latency_shaped_task_operator(state.jacobian, state.ee_rotation, state.mass_matrix, d, kk, h)
    got = k.task_operator(state.jacobian, state.ee_rotation, state.mass_matrix, d, kk, h)
    assert got.shape == (7, 6)
    np.testing.assert_allclose(got, ref, rtol=RTOL, atol=RTOL * np.abs(ref).max())
    ref = joint_kernels.posture_operator(state.jacobian, state.mass_matrix, 20.0, 9.0, h, PINV_DAMPING)
    got = k.posture_operator(state.jacobian, state.mass_matrix, 20.0, 9.0, h, PINV_DAMPING)
    assert got.shape == (7, 7)
    np.testing.assert_allclose(got, ref, rtol=RTOL, atol=RTOL * np.abs(ref).max())


def test_the_task_operator_is_the_latency_shaped_torque(states):
    """τ = B f equals the implicit impedance M (M + h·Jₜᵀ(D + hK)Jₜ)⁻¹ Jᵀ f written out with the
    library's own latency_shaped_torque, and B → Jᵀ as h → 0."""
    from tactex.control.damping import latency_shaped_torque

    state = states[4]
    d, kk = np.array([40.0, 40.0, 60.0, 2.0, 2.0, 2.0]), np.array([800.0, 800.0, 0.0, 40.0, 40.0, 40.0])
    f = np.random.default_rng(5).normal(0.0, 10.0, 6)
    jac, rot = state.jacobian, state.ee_rotation
    jac_tool = np.vstack([rot.T @ jac[:3], rot.T @ jac[3:]])
    for h in (0.003, 0.0):
        b = joint_kernels.latency_shaped_task_operator(jac, rot, state.mass_matrix, d, kk, h)
        expected = latency_shaped_torque(state.mass_matrix, jac.T @ f, jac_tool.T @ ((d + h * kk)[:, None] * jac_tool),
                                         None, h)
        np.testing.assert_allclose(b @ f, expected, rtol=1e-10, atol=1e-10 * np.abs(expected).max())
    np.testing.assert_allclose(b, jac.T, rtol=1e-12, atol=1e-12)


def test_a_prepared_operator_is_applied_while_the_posture_holds_and_rebuilt_after_a_jump(states, counted):
    """prepare() builds both operators; the next tick at a posture within tolerance reuses them (no
    kernel call between the state and its command), a tick far from it builds its own."""
    from tactex.control.prepared import POSTURE_TOLERANCE_RAD
    from tactex.control.ufic import UficParams

    state = states[2]
    ref = PoseForceReference(state.ee_position + np.array([0.01, 0.0, -0.005]), state.ee_rotation,
                             np.array([0.0, 0.0, 15.0, 0.0, 0.0, 0.0]))
    near = replace(state, q=state.q + 0.5 * POSTURE_TOLERANCE_RAD / np.sqrt(7))  # J, M and R as at ``state``
    far = replace(state, q=state.q + 3.0 * POSTURE_TOLERANCE_RAD)
    # D_C switched at once, so that one tick's damping is the next's (prepare uses the tick's own)
    params = UficParams(damping_switch_s=0.0)
    ctrl, fresh = NullspacePosture(UficController(params)), NullspacePosture(UficController(params))
    for c in (ctrl, fresh):
        c.reset(state)
    ctrl.torque(state, ref)
    ctrl.prepare(state)
    assert counted == {"task": 2, "posture": 2}  # built in the first tick (nothing prepared), then prepared
    tau_prepared = ctrl.torque(near, ref)
    assert counted == {"task": 2, "posture": 2}  # applied, not rebuilt
    assert np.isfinite(tau_prepared).all() and np.abs(tau_prepared).max() > 0.1
    # the operators applied are those built at ``state``: the same torque as a controller that builds
    # them in the tick from ``near``'s (identical) model terms
    fresh.torque(state, ref)
    np.testing.assert_allclose(tau_prepared, fresh.torque(near, ref), rtol=1e-12, atol=1e-12)
    assert counted == {"task": 4, "posture": 4}
    ctrl.torque(far, ref)
    assert counted == {"task": 5, "posture": 5}  # too far from the prepared posture: built in the tick
    ctrl.prepare(far)
    ctrl.reset(state)  # a reset forgets the prepared operators
    counted.update(task=0, posture=0)
    ctrl.torque(far, ref)
    assert counted == {"task": 1, "posture": 1}


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
    from tactex.tasks.runner import ControlLoop

    calls = []
    monkeypatch.setattr(joint_kernels, "kernels", lambda: calls.append("built"))
    backend = MujocoBackend(SceneConfig())
    try:
        ControlLoop(backend)
    finally:
        backend.close()
    assert calls == ["built"]


def test_the_ga_line_controller_applies_its_prepared_operators_as_it_would_build_them(states):
    """TEC's line controller: τ = S (Jᵀf − D_q q̇) with the operators prepared after the last command
    equals the torque with operators built in the tick, and equals the explicit implicit-impedance
    form written out with latency_shaped_torque."""
    from tactex.control.damping import latency_shaped_torque
    from tactex.control.ga_line_force import GaLineForceController
    from tactex.control.references import LineForceReference

    state = states[3]
    ref = LineForceReference(state.ee_position + np.array([0.004, -0.002, -0.01]), -state.ee_rotation[:, 2] +
                             np.array([0.05, 0.0, 0.0]), 10.0)
    prepared, fresh = GaLineForceController(), GaLineForceController()
    for c in (prepared, fresh):
        c.reset(state)
    prepared.prepare(state)
    built = []
    build = prepared.joint_operators
    prepared.joint_operators = lambda st: built.append(1) or build(st)
    near = replace(state, q=state.q + 1e-4)  # J, M and R as at ``state``
    a, b = prepared.torque(near, ref), fresh.torque(near, ref)
    assert built == []  # the prepared operators were applied
    assert np.abs(b).max() > 0.1
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(b).max())
    # the operators against the written-out form, for a wrench f and the state's q̇
    s_jt, s_d = fresh.joint_operators(state)
    f = np.random.default_rng(4).normal(0.0, 10.0, 6)
    jac, rot = state.jacobian, state.ee_rotation
    jt = np.vstack([rot.T @ jac[:3], rot.T @ jac[3:]])
    d_q, k_q = jt.T @ (fresh._d[:, None] * jt), jt.T @ (fresh._k[:, None] * jt)
    h = fresh.params.latency_horizon_ticks * fresh.params.dt
    expected = latency_shaped_torque(state.mass_matrix, jac.T @ f - d_q @ state.dq, d_q, k_q, h)
    np.testing.assert_allclose(s_jt @ f - s_d @ state.dq, expected, rtol=1e-10, atol=1e-10 * np.abs(expected).max())


def test_a_non_finite_posture_never_leaves_a_prepared_operator(states):
    """A NaN in the mass matrix gives NaN operators (numba's solve raises, the kernel runner returns
    NaN); they are not kept, and the safety layer does not prepare from such a state at all."""
    from tactex.control.prepared import PreparedOperator

    state = states[0]
    bad = replace(state, mass_matrix=np.full((7, 7), np.nan))
    ctrl = NullspacePosture(UficController())
    ctrl.reset(state)
    assert np.isnan(ctrl.posture_operator(bad)).all() and ctrl.posture_operator(bad).shape == (7, 7)
    assert np.isnan(ctrl.inner.task_operator(bad)).all() and ctrl.inner.task_operator(bad).shape == (7, 6)
    ctrl.prepare(state)
    ctrl.prepare(bad)  # drops what it had: nothing stale either
    assert ctrl._operator.get(state.q) is None and ctrl.inner._operator.get(state.q) is None
    op = PreparedOperator()
    op.store(state.q, (np.eye(7), np.full((7, 7), np.inf)))
    assert op.get(state.q) is None
    layer = SafetyLayer(NullspacePosture(UficController()))
    layer.reset(state)
    layer.prepare(bad)
    assert layer.inner._operator.get(state.q) is None
    layer.prepare(state)
    assert layer.inner._operator.get(state.q) is not None


def test_the_ufic_operator_is_rebuilt_while_the_damping_switches(states, counted):
    """Prepared with one tool-axis damping, applied only while D_C has moved by ≤ 1 %: at a touch-down
    the damping moves towards its contact value over damping_switch_s, and those ticks build their own."""
    state = states[2]
    ctrl = UficController()
    ctrl.reset(state)
    ctrl._d_tool_f = ctrl._d_free_f
    ctrl.prepare(state)
    assert counted["task"] == 1
    f_world = (1.0, -2.0, 15.0, 0.1, 0.0, -0.2)
    ctrl.joint_torque(state, f_world)
    assert counted["task"] == 1  # same damping: applied
    ctrl._d_tool_f = ctrl._d_contact_f
    ctrl.joint_torque(state, f_world)
    assert counted["task"] == 2  # the damping moved: built again in the tick
