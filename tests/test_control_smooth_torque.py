"""Torques a real arm can take: no 1 kHz chatter, no jump at a controller hand-over, no stop-and-go
transit. Each of these tripped the torque-rate limiter (1000 N·m/s) thousands of times per cleaning
run in simulation, and on a Franka is the vibration that trips reflexes."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.control.controller import Controller
from tactex.control.damping import implicit_damping_torque
from tactex.control.ga_line_force import GaLineForceParams
from tactex.control.joint_impedance import JointTarget
from tactex.control.safety import SafetyLayer, SafetyLimits
from tests.test_control_common import make_state
from tests.test_control_safety import Q_MID

DT = 1e-3
#: Largest eigenvalue of dt·M⁻¹·B for which one explicit step of M q̈ = −B q̇ decays without flipping sign.
NO_RINGING = 1.0


def _home_state():
    from tactex.robots import MujocoBackend
    from tactex.sim import SceneConfig

    backend = MujocoBackend(SceneConfig(object_name="plane"))
    state = backend.state()
    backend.close()
    return state


def _ga_joint_damping(state) -> np.ndarray:
    p = GaLineForceParams()
    d = np.array(p.damping_linear + p.damping_angular)
    rt = state.ee_rotation.T
    jac_tool = np.vstack([rt @ state.jacobian[:3], rt @ state.jacobian[3:]])
    return jac_tool.T @ (d[:, None] * jac_tool)


def test_explicit_ga_damping_rings_on_the_wrist_and_the_implicit_one_does_not() -> None:
    """TEC's 10 N·m·s/rad on the wrist rotation (~0.005 kg·m² with the tool) is at the 1 kHz limit
    when applied explicitly: the cause of the 500 Hz chatter in contact."""
    state = _home_state()
    m, b = state.mass_matrix, _ga_joint_damping(state)
    explicit = np.max(np.real(np.linalg.eigvals(DT * np.linalg.solve(m, b))))
    assert explicit > 1.8  # a forward-Euler step flips the wrist's velocity: chatter
    # the implicit damping is the linear map dq → −τ: recover it column by column
    b_dt = -np.column_stack([implicit_damping_torque(m, b, e, DT) for e in np.eye(7)])
    eig = np.real(np.linalg.eigvals(DT * np.linalg.solve(m, b_dt)))
    assert eig.min() > -1e-9 and eig.max() < NO_RINGING
    np.testing.assert_allclose(b_dt, b_dt.T, atol=1e-9)  # still a damper: symmetric, passive
    # on a heavy mode the same damping as the explicit one
    heavy = np.linalg.eigh(m)[1][:, -1]
    assert heavy @ b_dt @ heavy == pytest.approx(heavy @ b @ heavy, rel=0.2)


class _Constant(Controller):
    def __init__(self, tau) -> None:
        self.tau = np.asarray(tau, dtype=float)

    def torque(self, state, reference):
        return self.tau.copy()


def test_controller_hand_over_is_continuous_in_torque() -> None:
    """Two controllers 8 N·m apart at the switch: blended in, not a step into the rate limiter."""
    state = make_state(q=Q_MID)  # away from the joint limits' repulsion
    a = _Constant([2.0, 0, 0, 0, 0, 0, 0])
    b = _Constant([10.0, -6.0, 0, 0, 0, 0, 0])
    layer = SafetyLayer(a, SafetyLimits(handover_blend_s=0.05))
    layer.reset(state)
    out = []
    t = 0.0
    for k in range(200):
        if k == 50:
            layer.inner = b
            clips = layer.counts.get("torque_rate_limit", 0)  # the start from 0 N·m took a few ticks
        out.append(layer.torque(make_state(t=t, q=Q_MID), None))
        t += DT
    out = np.array(out)
    step = np.max(np.abs(np.diff(out[45:], axis=0)))
    assert step < 0.4 * SafetyLimits().tau_rate_max * DT  # minimum-jerk peak: 1.875 × 8 N·m / 50 ms · dt
    assert layer.counts.get("torque_rate_limit", 0) == clips
    np.testing.assert_allclose(out[49], a.tau)
    np.testing.assert_allclose(out[-1], b.tau)
    # without the blend the same switch is a step the rate limiter has to cut
    layer = SafetyLayer(a, SafetyLimits(handover_blend_s=0.0))
    layer.reset(state)
    for k in range(5):
        layer.torque(make_state(t=k * DT, q=Q_MID), None)
    clips = layer.counts.get("torque_rate_limit", 0)
    layer.inner = b
    layer.torque(make_state(t=5 * DT, q=Q_MID), None)
    assert layer.counts.get("torque_rate_limit", 0) == clips + 1


def test_joint_path_through_via_points_does_not_stop_at_them() -> None:
    rng = np.random.default_rng(3)
    q0 = np.zeros(7)
    via = np.cumsum(rng.uniform(0.02, 0.05, (6, 7)), axis=0)
    q1 = via[-1] + 0.04
    target = JointTarget(q0, q1, 0.0, 2.0, via=via)
    ts = np.linspace(0.0, 2.0, 2001)
    q = np.array([target.at(t)[0] for t in ts])
    dq = np.array([target.at(t)[1] for t in ts])
    np.testing.assert_allclose(q[0], q0, atol=1e-12)
    np.testing.assert_allclose(q[-1], q1, atol=1e-12)
    np.testing.assert_allclose(dq[[0, -1]], 0.0, atol=1e-12)
    # the velocity is the derivative of the position (finite differences) and never drops to 0 inside
    np.testing.assert_allclose(np.gradient(q, ts, axis=0)[5:-5], dq[5:-5], atol=2e-3)
    speed = np.linalg.norm(dq, axis=1)
    assert speed[500:-500].min() > 0.3 * speed.max()  # s in [0.25, 0.75]: no stop at a via point
    # each via point lies on the path
    for v in via:
        assert np.min(np.linalg.norm(q - v, axis=1)) < 5e-3
    # the path rate × the minimum-jerk peak 1.875 / duration bounds the joint speed (move_cartesian's timing)
    assert 0.5 * 1.875 * target.path_rate() / 2.0 < np.max(np.abs(dq)) <= 1.875 * target.path_rate() / 2.0 + 1e-9


@pytest.mark.slow
def test_transit_has_no_torque_rate_clip_and_bounded_acceleration() -> None:
    """A 25 cm Cartesian transit through IK waypoints: one smooth motion. Rest-to-rest per 2 cm
    waypoint it shook the tool at ~8 Hz with TCP accelerations of 5–7 m/s²."""
    from tactex.robots import MujocoBackend
    from tactex.robots.loop import ControlLoop
    from tactex.sim import SceneConfig

    loop = ControlLoop(MujocoBackend(SceneConfig(object_name="plane")))
    loop.hold(0.05)
    p0, r0 = loop.state.ee_position.copy(), loop.state.ee_rotation.copy()
    velocity, force = [], []

    def watch(state, reference, controller) -> None:
        velocity.append(state.ee_twist[:3].copy())
        force.append(state.wrench_tool[:3].copy())

    loop.on_tick = watch
    clips0 = loop.safety.counts.get("torque_rate_limit", 0)
    loop.move_cartesian(p0 + np.array([-0.1, 0.15, 0.15]), r0, settle_s=0.3)
    loop.retract(0.05, duration_s=0.4)  # chained joint moves: continuous torque at the boundary
    loop.hold(0.2)
    assert loop.safety.counts.get("torque_rate_limit", 0) == clips0
    acc = np.linalg.norm(np.diff(np.array(velocity), axis=0), axis=1) / DT
    assert acc.max() < 3.0  # [m/s²]
    f = np.array(force)
    f = f - f.mean(axis=0)
    spectrum = np.abs(np.fft.rfft(f * np.hanning(len(f))[:, None], axis=0)).sum(axis=1)
    freq = np.fft.rfftfreq(len(f), DT)
    # the F/T sees the motion's own inertial force (below ~3 Hz), no vibration above it
    assert spectrum[freq > 4.0].max() < 0.2 * spectrum.max()
