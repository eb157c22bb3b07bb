"""The safety layer: NaN guard, limits, force trip and retreat, joint-limit repulsion, events."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tactex.control import FRANKA_Q_MAX, FRANKA_TAU_MAX, Controller, SafetyLayer, SafetyLimits
from tactex.control.safety import LIMIT_MARGIN
from tactex.errors import ConfigError, ControllerFault
from tests.test_control_common import N_JOINTS, make_state

TAU_MAX = np.asarray(FRANKA_TAU_MAX)
RATE_STEP = 1000.0 * 1e-3  # the robot's limit per 1 ms tick [N·m]
KEEP = 1.0 - LIMIT_MARGIN  # the share of each limit the layer uses
Q_MID = np.array([0.0, 0.0, 0.0, -1.5, 0.0, 1.8, 0.0])


class Constant(Controller):
    """Returns a fixed torque (or raises / returns NaN when told)."""

    name = "constant"

    def __init__(self, tau, fail: str = "") -> None:
        self.tau = np.asarray(tau, dtype=float)
        self.fail = fail
        self.resets = 0
        self.resumes = 0

    def reset(self, state) -> None:
        self.resets += 1

    def resume(self, state) -> None:
        self.resumes += 1

    def torque(self, state, reference):
        if self.fail == "raise":
            raise ControllerFault("inner failed on purpose")
        if self.fail == "nan":
            return np.full(N_JOINTS, np.nan)
        return self.tau.copy()


def _layer(tau, **kw):
    inner = Constant(tau, kw.pop("fail", ""))
    layer = SafetyLayer(inner, SafetyLimits(**kw) if kw else None)
    layer.reset(make_state(q=Q_MID))
    return layer, inner


def _state(k: int, **kw):
    kw.setdefault("q", Q_MID)
    return make_state(t=k * 1e-3, **kw)


def test_rate_and_torque_limits():
    layer, _ = _layer(np.array([200.0, -200.0, 5.0, 0.5, 30.0, -30.0, 0.0]))
    prev = np.zeros(N_JOINTS)
    for k in range(300):
        tau = layer.torque(_state(k), None)
        assert (np.abs(tau) < TAU_MAX).all()  # a margin below the robot's limits, never at them
        assert (np.abs(tau - prev) < RATE_STEP).all()
        assert (np.abs(tau - prev) <= KEEP * RATE_STEP + 1e-12).all()
        prev = tau
    np.testing.assert_allclose(tau, [87.0 * KEEP, -87.0 * KEEP, 5.0, 0.5, 12.0 * KEEP, -12.0 * KEEP, 0.0])
    kinds = [e.kind for e in layer.events]
    assert kinds.count("torque_limit") == 1 and "torque_rate_limit" in kinds  # reported once, when it starts
    assert layer.counts["torque_limit"] > 200


def test_a_restart_blends_in_from_the_robots_own_last_command():
    # a torque held before a pause, then torque control restarts with the robot's tau_J_d at 0: the
    # controller's torque comes back as a hand-over blend from 0, never a ramp at the rate limit (a
    # late first command would make two of its steps one step for the robot)
    layer, _ = _layer(np.array([3.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]))
    for k in range(200):
        layer.torque(_state(k), None)
    assert layer._tau_prev[0] == pytest.approx(3.0)
    clips = layer.counts.get("torque_rate_limit", 0)
    layer.reseed(np.zeros(N_JOINTS))
    prev, steps = np.zeros(N_JOINTS), []
    for k in range(200, 300):
        tau = layer.torque(_state(k), None)
        steps.append(np.abs(tau - prev).max())
        prev = tau
    assert tau[0] == pytest.approx(3.0)  # the blend ends at the controller's torque
    assert max(steps) < 0.5 * KEEP * RATE_STEP  # two steps in one stay below the robot's limit
    assert steps[0] < 0.01 and layer.counts.get("torque_rate_limit", 0) == clips


def test_a_restart_from_a_non_finite_robot_value_starts_from_zero():
    layer, _ = _layer(np.array([3.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]))
    for k in range(200):
        layer.torque(_state(k), None)
    layer.reseed(np.full(N_JOINTS, np.nan))
    tau = layer.torque(_state(200), None)
    assert np.isfinite(tau).all() and abs(tau[0]) < 0.01


def test_nan_wrench_is_replaced_and_reported():
    layer, _ = _layer(np.ones(N_JOINTS))
    layer.torque(_state(0, wrench_tool=np.array([0, 0, 3.0, 0, 0, 0])), None)
    tau = layer.torque(_state(1, wrench_tool=np.array([np.nan, 0, 0, 0, 0, np.inf])), None)
    assert np.isfinite(tau).all()
    assert layer.events[-1].kind == "nan_wrench" and layer.events[-1].t == pytest.approx(1e-3)


def test_nan_state_holds_and_decays():
    layer, _ = _layer(np.full(N_JOINTS, 0.5))
    for k in range(10):
        tau = layer.torque(_state(k), None)
    bad = replace(_state(10), q=np.full(N_JOINTS, np.nan))
    held = layer.torque(bad, None)
    assert np.isfinite(held).all()
    assert (np.abs(held) < np.abs(tau)).all() and (np.abs(held) > 0.9 * np.abs(tau)).all()
    assert any(e.kind == "nan_state" for e in layer.events)


@pytest.mark.parametrize("fail", ["raise", "nan"])
def test_inner_fault_holds(fail):
    layer, _ = _layer(np.ones(N_JOINTS), fail=fail)
    tau = layer.torque(_state(0), None)
    assert np.isfinite(tau).all()
    assert layer.events[-1].kind == ("controller_fault" if fail == "raise" else "nan_torque")


def test_force_trip_retreat_and_resume():
    limits = {"max_contact_force": 20.0, "force_trip_ticks": 3, "retreat_time": 0.05}
    layer, inner = _layer(np.full(N_JOINTS, 0.3), **limits)
    over = np.array([0, 0, 50.0, 0, 0, 0])
    for k in range(2):  # shorter than the debounce: no trip
        layer.torque(_state(k, wrench_tool=over), None)
    assert not layer.retreating
    layer.torque(_state(2, wrench_tool=over), None)
    assert layer.retreating and "force_limit" in [e.kind for e in layer.events]
    # during the retreat the command is the compliant pull back along −tool z (J = I on the first 6 rows)
    jac = np.zeros((6, N_JOINTS))
    jac[:6, :6] = np.eye(6)
    tau = layer.torque(_state(3, jacobian=jac), None)
    assert not np.allclose(tau, 0.3)
    resets, resumes = inner.resets, inner.resumes
    for k in range(4, 60):
        layer.torque(_state(k), None)
    # resumed, not reset: a controller with tanks keeps their energy (see test_control_ufic)
    assert not layer.retreating and inner.resumes == resumes + 1 and inner.resets == resets
    assert [e.kind for e in layer.events].count("retreat_end") == 1


def test_a_lost_wrench_sensor_retreats_until_it_is_back():
    """A dead F/T sensor: the last finite reading bridges wrench_loss_ticks ticks, then the layer
    retreats (a frozen reading could neither trip the force limit nor close a force loop); one event
    per dropout however long it lasts; the inner controller resumes retreat_time after the sensor is back."""
    limits = {"wrench_loss_ticks": 5, "retreat_time": 0.02}
    layer, inner = _layer(np.full(N_JOINTS, 0.3), **limits)
    layer.torque(_state(0, wrench_tool=np.array([0, 0, 15.0, 0, 0, 0])), None)
    dead = np.full(6, np.nan)
    for k in range(1, 6):  # within the bridge: the inner controller keeps running
        tau = layer.torque(_state(k, wrench_tool=dead), None)
        assert not layer.retreating
    np.testing.assert_allclose(tau, 0.3)
    layer.torque(_state(6, wrench_tool=dead), None)
    assert layer.retreating
    for k in range(7, 3000):  # three seconds without a sensor
        assert np.isfinite(layer.torque(_state(k, wrench_tool=dead), None)).all()
        assert layer.retreating
    kinds = [e.kind for e in layer.events if e.kind not in ("torque_rate_limit", "torque_limit")]
    assert kinds == ["nan_wrench", "wrench_lost"] and layer.counts["nan_wrench"] == 2999
    assert len(layer.events) < 10
    resumes = inner.resumes
    for k in range(3000, 3030):  # the sensor is back: retreat_time (20 ticks) later the controller resumes
        layer.torque(_state(k), None)
        assert layer.retreating == (k < 3019)
    assert inner.resumes == resumes + 1 and "retreat_end" in [e.kind for e in layer.events]


def test_a_lost_sensor_backs_off_only_from_contact_and_only_for_retreat_time():
    """Lost in contact: the pull back acts for retreat_time, then damping alone (at rest: no torque).
    Lost in free space: no pull at all. (A pull for as long as the sensor stayed dead carried a real
    arm 0.77 m in 6 s.)"""
    jac = np.zeros((6, N_JOINTS))
    jac[:6, :6] = np.eye(6)
    dead = np.full(6, np.nan)
    for last, pulls in ((np.array([0, 0, 15.0, 0, 0, 0]), True), (np.zeros(6), False)):
        layer, _ = _layer(np.zeros(N_JOINTS), wrench_loss_ticks=2, retreat_time=0.05, tau_rate_max=1e6)
        layer.torque(_state(0, jacobian=jac, wrench_tool=last), None)
        taus = [layer.torque(_state(k, jacobian=jac, wrench_tool=dead), None) for k in range(1, 200)]
        assert layer.retreating
        pulled = [k for k, tau in enumerate(taus, start=1) if abs(tau[2]) > 1.0]
        if pulls:  # from the loss (tick 3) to retreat_time later
            assert pulled[0] == 3 and 50 <= pulled[-1] <= 54
        else:
            assert pulled == []
        np.testing.assert_allclose(taus[-1], 0.0, atol=1e-9)  # damping alone, the arm at rest


def test_a_lost_sensor_holds_a_real_arm_in_free_space():
    from dataclasses import replace as dc_replace

    from tactex.control.joint_impedance import JointTarget
    from tactex.robots import MujocoBackend
    from tactex.robots.loop import ControlLoop
    from tactex.sim import SceneConfig

    backend = MujocoBackend(SceneConfig(object_name="plane"))
    loop = ControlLoop(backend)
    loop.hold(0.1)
    p0 = loop.state.ee_position.copy()
    step = backend.step
    backend.step = lambda: dc_replace(step(), wrench_tool=np.full(6, np.nan))
    q = loop.state.q.copy()
    target = JointTarget(q, q, loop.t, 0.0)
    while loop.t < 2.0:
        loop.tick(target)
    assert loop.safety.retreating and "wrench_lost" in [e.kind for e in loop.safety.events]
    assert np.linalg.norm(loop.state.ee_position - p0) < 0.005


def test_a_flickering_sensor_reports_at_most_one_event_a_second():
    layer, _ = _layer(np.zeros(N_JOINTS))
    good, dead = np.array([0, 0, 5.0, 0, 0, 0]), np.full(6, np.nan)
    for k in range(2000):  # two seconds of NaN every other tick
        layer.torque(_state(k, wrench_tool=dead if k % 2 else good), None)
    assert [e.kind for e in layer.events].count("nan_wrench") == 2 and layer.counts["nan_wrench"] == 1000


def test_wrench_loss_ticks_validation():
    for bad in (0, -1, 2.5, True):
        with pytest.raises(ConfigError, match="wrench_loss_ticks"):
            SafetyLimits(wrench_loss_ticks=bad)


def test_retreat_pulls_away_from_the_surface():
    layer, _ = _layer(np.zeros(N_JOINTS), max_contact_force=20.0, force_trip_ticks=1, tau_rate_max=1e6)
    jac = np.zeros((6, N_JOINTS))
    jac[:6, :6] = np.eye(6)
    down = np.diag([1.0, -1.0, -1.0])  # tool z = world −z
    tau = layer.torque(_state(0, jacobian=jac, rotation=down, wrench_tool=np.array([0, 0, 30.0, 0, 0, 0])), None)
    assert tau[2] > 0.0  # world +z: away from the surface


def test_joint_limit_repulsion():
    layer, _ = _layer(np.zeros(N_JOINTS), tau_rate_max=1e6)
    q = Q_MID.copy()
    q[0] = FRANKA_Q_MAX[0] - 0.02  # 0.02 rad from the upper limit
    tau = layer.torque(_state(0, q=q), None)
    assert tau[0] == pytest.approx(-50.0 * (0.1 - 0.02))
    assert np.allclose(tau[1:], 0.0)
    assert layer.events[-1].kind == "joint_limit"


def test_wrong_joint_count_is_a_config_error():
    layer, _ = _layer(np.zeros(N_JOINTS))
    bad = replace(_state(0), q=np.zeros(6), dq=np.zeros(6))
    with pytest.raises(ConfigError, match="joints"):
        layer.torque(bad, None)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"tau_max": (1.0, 2.0)}, "same length"), ({"tau_rate_max": 0.0}, "tau_rate_max"),
     ({"max_contact_force": -1.0}, "max_contact_force"), ({"force_trip_ticks": 0}, "force_trip_ticks"),
     ({"q_min": (1.0,) * 7, "q_max": (0.0,) * 7}, "q_max > q_min")],
)
def test_limits_validation(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        SafetyLimits(**kwargs)


@pytest.mark.parametrize(
    "name", ["hold_decay_time", "joint_limit_margin", "joint_limit_stiffness", "joint_limit_damping", "retreat_force",
             "retreat_damping", "retreat_angular_damping"],
)
def test_safety_limits_reject_nan_and_negative(name):
    from tactex.control import SafetyLimits
    from tactex.errors import ConfigError

    for bad in (float("nan"), -1.0):
        with pytest.raises(ConfigError, match=name):
            SafetyLimits(**{name: bad})


class Recorder(Controller):
    """Returns a given torque and records the wrench it was given."""

    name = "recorder"

    def __init__(self, tau) -> None:
        self.tau = np.asarray(tau, dtype=float)
        self.wrenches: list[np.ndarray] = []

    def torque(self, state, reference):
        self.wrenches.append(state.wrench_tool.copy())
        return self.tau.copy()


def test_nan_wrench_is_replaced_by_the_last_finite_one_exactly():
    inner = Recorder(np.zeros(N_JOINTS))
    layer = SafetyLayer(inner)
    layer.reset(make_state(q=Q_MID))
    good = np.array([0.1, -0.2, 3.0, 0.01, 0.02, -0.03])
    layer.torque(_state(0, wrench_tool=good), None)
    layer.torque(_state(1, wrench_tool=np.array([0, 0, np.nan, 0, 0, 0])), None)
    layer.torque(_state(2, wrench_tool=np.array([np.inf, 0, 0, 0, 0, 0])), None)
    np.testing.assert_array_equal(inner.wrenches[1], good)
    np.testing.assert_array_equal(inner.wrenches[2], good)
    assert [e.kind for e in layer.events] == ["nan_wrench"]  # one event per dropout, every tick counted
    assert layer.counts["nan_wrench"] == 2
    layer.reset(make_state(q=Q_MID))  # after a reset the fallback is a zero wrench
    layer.torque(_state(0, wrench_tool=np.array([np.nan] * 6)), None)
    np.testing.assert_array_equal(inner.wrenches[-1], np.zeros(6))


def _extreme_vectors(rng, n: int, count: int):
    """Vectors mixing ordinary values, ±1e308 (a sum can overflow), inf and NaN."""
    pool = np.array([0.0, 1.5, -2.0, 1e308, -1e308, 1.7e308, np.inf, -np.inf, np.nan])
    return [np.where(rng.random(n) < 0.3, rng.choice(pool, n), rng.normal(size=n)) for _ in range(count)]


def test_non_finite_wrench_verdict_is_numpys_sum(rng):
    """The wrench counts as non-finite exactly when numpy's sum of it is not finite (NaN/inf, or an
    overflowing sum: the safe side)."""
    with np.errstate(over="ignore", invalid="ignore"):
        for w in _extreme_vectors(rng, 6, 300):
            layer, _ = _layer(np.zeros(N_JOINTS))
            layer.torque(_state(0, wrench_tool=w), None)
            tripped = any(e.kind == "nan_wrench" for e in layer.events)
            assert tripped == (not np.isfinite(np.add.reduce(w))), w


def test_non_finite_torque_verdict_is_numpys_sum(rng):
    with np.errstate(over="ignore", invalid="ignore"):
        for tau in _extreme_vectors(rng, N_JOINTS, 300):
            layer, _ = _layer(tau)
            out = layer.torque(_state(0), None)
            assert np.isfinite(out).all()
            held = any(e.kind == "nan_torque" for e in layer.events)
            assert held == (not np.isfinite(np.add.reduce(tau))), tau


def test_wrong_torque_shape_holds():
    layer, _ = _layer(np.ones(N_JOINTS + 1))
    tau = layer.torque(_state(0), None)
    np.testing.assert_array_equal(tau, np.zeros(N_JOINTS))
    assert layer.events[-1].kind == "nan_torque"


def test_hold_decays_by_exp_dt_over_t_each_tick():
    limits = SafetyLimits()
    layer, _ = _layer(np.full(N_JOINTS, 0.5))
    for k in range(5):
        tau = layer.torque(_state(k), None)
    bad = replace(_state(5), dq=np.full(N_JOINTS, np.inf))
    held1 = layer.torque(bad, None)
    held2 = layer.torque(replace(bad, t=6e-3), None)
    decay = np.exp(-limits.dt / limits.hold_decay_time)
    np.testing.assert_allclose(held1, tau * decay, rtol=1e-15)
    np.testing.assert_allclose(held2, tau * decay**2, rtol=1e-15)


class Random(Controller):
    """Wild commands: large, stepping, sometimes NaN, sometimes a fault."""

    name = "random"

    def __init__(self, rng) -> None:
        self.rng = rng

    def reset(self, state) -> None:
        pass

    def torque(self, state, reference):
        u = self.rng.random()
        if u < 0.01:
            raise ControllerFault("random fault")
        if u < 0.02:
            return np.full(N_JOINTS, np.nan)
        scale = 10.0 ** self.rng.uniform(-2, 3)  # 0.01 to 1000 N·m
        return self.rng.normal(scale=scale, size=N_JOINTS)


@pytest.mark.parametrize("seed", range(4))
def test_no_command_ever_reaches_the_robots_limits(seed):
    """Over randomised states (joints near and past their limits, wrenches that trip the force limit or
    drop out, NaN states) and randomised commands (huge, stepping, NaN, faults, controller hand-overs),
    every command stays strictly below the robot's torque limits and its torque rate strictly below
    1000 N·m/s: the layer clips a margin below them, on its compiled and its Python path alike."""
    rng = np.random.default_rng(seed)
    inners = [Random(rng), Random(rng)]
    layer = SafetyLayer(inners[0], SafetyLimits(force_trip_ticks=3, retreat_time=0.02))
    layer.reset(make_state(q=Q_MID))
    q_lo, q_hi = np.asarray(layer.limits.q_min), np.asarray(layer.limits.q_max)
    prev = np.zeros(N_JOINTS)
    for k in range(6000):
        if rng.random() < 0.005:
            layer.inner = inners[rng.integers(2)]  # a hand-over: blended, on the Python path
        q = rng.uniform(q_lo - 0.05, q_hi + 0.05)
        wrench = rng.normal(scale=rng.choice([1.0, 60.0]), size=6)
        if rng.random() < 0.02:
            wrench[:] = np.nan
        state = make_state(t=k * 1e-3, q=q, dq=rng.normal(scale=2.0, size=N_JOINTS), wrench_tool=wrench,
                           seed=int(rng.integers(1000)))
        if rng.random() < 0.005:
            state.q[0] = np.nan
        tau = layer.torque(state, None)
        assert np.isfinite(tau).all()
        assert (np.abs(tau) < TAU_MAX).all(), (k, tau)
        assert (np.abs(tau - prev) / 1e-3 < 1000.0).all(), (k, tau - prev)
        prev = tau
    assert layer.counts.get("torque_rate_limit", 0) > 100 and layer.counts.get("torque_limit", 0) > 10


def test_a_restart_blends_in_from_the_robots_own_command():
    # torque control restarts after a pause: the robot's hold commanded 3 N·m on joint 1, the controller wants
    # -2 N·m there; a step of 5 N·m in one tick is over the rate limit. Reseeded with the restart's time, the
    # command ramps from the robot's over handover_blend_s, and nothing is clipped
    want = np.array([-2.0, 1.5, 0.0, 0.0, 0.0, 0.0, 0.0])
    robot = np.array([3.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    layer, _ = _layer(want)
    for k in range(5):
        layer.torque(_state(k), None)
    layer.counts.clear()  # the start's own ramp from 0 is not what is tested
    layer.reseed(robot)
    prev = robot
    for k in range(5, 200):
        tau = layer.torque(_state(k), None)
        assert (np.abs(tau - prev) <= KEEP * RATE_STEP + 1e-12).all()
        prev = tau
    np.testing.assert_allclose(prev, want)
    assert "torque_rate_limit" not in layer.counts


def test_a_hand_over_blend_advances_a_period_per_command_across_a_stall():
    # a restart's blend towards 5 N·m, then the loop stalls and the robot's clock runs on 25 ms between two
    # commands: the blend goes on by one period's share, not by 25 ms of it (a step of several N·m)
    want = np.array([5.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    layer, _ = _layer(want)
    for k in range(100):
        layer.torque(_state(k), None)
    layer.counts.clear()
    layer.reseed(np.zeros(N_JOINTS))
    prev = np.zeros(N_JOINTS)
    for k in [*range(100, 110), *range(135, 200)]:  # 25 ms without a command after k = 109
        tau = layer.torque(_state(k), None)
        assert (np.abs(tau - prev) <= KEEP * RATE_STEP + 1e-12).all(), (k, tau - prev)
        prev = tau
    np.testing.assert_allclose(prev, want)
    assert "torque_rate_limit" not in layer.counts


@pytest.mark.parametrize("compiled", [True, False])
def test_a_joint_entering_its_limit_band_at_speed_gets_no_step_of_damping(compiled):
    # joint 1 crosses into its repulsion band at 0.7 rad/s: the band's damping fades in with the depth, so the
    # command changes by a few hundredths of a N·m per tick (switched on at the edge: 2 × 0.7 = 1.4 N·m at once)
    layer, _ = _layer(np.zeros(N_JOINTS), tau_rate_max=1e6)
    if not compiled:
        layer._limit_kernel = None
    edge = FRANKA_Q_MAX[0] - 0.1
    taus = []
    for k in range(60):
        q = Q_MID.copy()
        q[0] = edge - 0.01 + 0.7 * k * 1e-3
        dq = np.zeros(N_JOINTS)
        dq[0] = 0.7
        taus.append(layer.torque(_state(k, q=q, dq=dq), None)[0])
    assert np.abs(np.diff(taus)).max() < 0.1
    depth = 0.7 * 59e-3 - 0.01  # past the ramp: the whole damping
    assert taus[-1] == pytest.approx(-(50.0 * depth + 2.0 * 0.7), rel=1e-9)


def test_the_layer_keeps_the_peak_contact_force_of_every_tick():
    """What a task's metrics quote as the run's peak |F|, moves included: the layer sees every tick's wrench."""
    layer, _ = _layer(np.zeros(N_JOINTS))
    assert layer.peak_force_n == 0.0
    for k, f in enumerate([(0, 0, 5.0), (3.0, 4.0, 12.0), (0, 0, 2.0)]):
        layer.torque(_state(k, wrench_tool=np.array([*f, 0.0, 0.0, 0.0])), None)
    assert layer.peak_force_n == pytest.approx(13.0)
    layer.inner = Constant(np.zeros(N_JOINTS))  # another controller (a move, then the task): the peak stays
    layer.torque(_state(3, wrench_tool=np.array([0, 0, 1.0, 0, 0, 0])), None)
    assert layer.peak_force_n == pytest.approx(13.0)
    layer.reset(make_state(q=Q_MID))
    assert layer.peak_force_n == 0.0
