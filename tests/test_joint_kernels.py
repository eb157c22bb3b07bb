"""The compiled joint-space kernels give the numpy reference's torques to round-off."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.control import joint_kernels
from tactex.control.nullspace import NullspacePosture
from tactex.control.references import PoseForceReference
from tactex.control.ufic import UficController
from tactex.geometry import exp_so3
from tactex.robots.mujoco_backend import MujocoBackend
from tactex.sim.scene import SceneConfig

pytestmark = pytest.mark.skipif(not joint_kernels.available(), reason="numba is not installed (the fast extra)")


@pytest.fixture(scope="module")
def states():
    """Franka states in a few postures, with MuJoCo's model terms."""
    backend = MujocoBackend(SceneConfig())
    rng = np.random.default_rng(3)
    out = []
    state = backend.reset(seed=0)
    for _ in range(5):
        out.append(state)
        for _ in range(40):  # wander: random torques move the arm to other postures and velocities
            backend.apply_torque(rng.normal(0.0, 2.0, 7))
            state = backend.step()
    return out


def test_the_kernels_are_built_with_numba():
    k = joint_kernels.kernels()
    assert k is not None and k is joint_kernels.kernels()  # built once per process


def test_compiled_task_torque_equals_numpy(states):
    rng = np.random.default_rng(0)
    compiled, numpy_ref = UficController(), UficController()
    numpy_ref._kernels = None
    assert compiled._kernels is not None
    for state in states:
        for _ in range(5):
            f_world = tuple(rng.normal(0.0, 10.0, 6).tolist())
            a = compiled.joint_torque(state, f_world)
            b = numpy_ref.joint_torque(state, f_world)
            np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-10 * np.abs(b).max())


def test_compiled_posture_torque_equals_numpy(states):
    class Zero:
        name = "zero"

        def reset(self, state):
            pass

        def torque(self, state, reference):
            return np.zeros(7)

    rng = np.random.default_rng(1)
    q_post = states[0].q + rng.normal(0.0, 0.2, 7)
    compiled, numpy_ref = NullspacePosture(Zero(), q_posture=q_post), NullspacePosture(Zero(), q_posture=q_post)
    numpy_ref._kernels = None
    assert compiled._kernels is not None
    for state in states:
        a, b = compiled.torque(state, None), numpy_ref.torque(state, None)
        assert np.abs(b).max() > 0.1  # a real posture torque, not a trivial zero
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-10 * np.abs(b).max())


def test_arrays_the_kernel_was_not_built_for_fall_back_to_numpy(states):
    state = states[1]
    ctrl = UficController()
    f_world = (1.0, -2.0, 15.0, 0.1, 0.0, -0.2)
    expected = ctrl.joint_torque(state, f_world)
    from dataclasses import replace

    strided = np.zeros((6, 14))
    strided[:, ::2] = state.jacobian
    view = replace(state, jacobian=strided[:, ::2])  # a strided view: not the kernel's C-ordered type
    np.testing.assert_allclose(ctrl.joint_torque(view, f_world), expected, rtol=1e-10, atol=1e-12)


def test_a_ufic_tick_is_the_same_with_and_without_the_kernels(states):
    state = states[2]
    rot = exp_so3(np.array([0.05, -0.02, 0.01])) @ state.ee_rotation
    ref = PoseForceReference(state.ee_position + np.array([0.01, 0.0, -0.005]), rot,
                             np.array([0.0, 0.0, 15.0, 0.0, 0.0, 0.0]))
    a_ctrl, b_ctrl = NullspacePosture(UficController()), NullspacePosture(UficController())
    b_ctrl._kernels = None
    b_ctrl.inner._kernels = None
    for c in (a_ctrl, b_ctrl):
        c.reset(state)
    a, b = a_ctrl.torque(state, ref), b_ctrl.torque(state, ref)
    np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-10 * np.abs(b).max())


def test_disable_makes_later_controllers_use_numpy(monkeypatch):
    monkeypatch.setattr(joint_kernels, "_kernels", None)
    monkeypatch.setattr(joint_kernels, "_failure", None)
    joint_kernels.disable("test")
    assert joint_kernels.kernels() is None and UficController()._kernels is None


def test_a_control_loop_builds_the_kernels_before_its_first_tick(monkeypatch):
    """Tasks build their controllers between moves, while a real robot's torque control runs: the
    kernels must already be there (building them takes seconds)."""
    from tactex.tasks.runner import ControlLoop

    calls = []
    monkeypatch.setattr(joint_kernels, "kernels", lambda: calls.append("built"))
    ControlLoop(MujocoBackend(SceneConfig()))
    assert calls == ["built"]


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
