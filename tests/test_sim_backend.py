"""MujocoBackend: protocol, gravity compensation, torque handling, F/T sensing, pressing, IK."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from tactex.errors import ControllerFault, InputError, SimulationError
from tactex.robots import MujocoBackend, RobotBackend
from tactex.sim import FRANKA_HOME_Q, FRANKA_TORQUE_LIMITS, SceneConfig
from tactex.sim.testing import SimpleImpedance

HOLD_TOL_RAD = 1e-4
FT_WEIGHT_REL_TOL = 0.01
PRESS_REL_TOL = 0.02
STIFFNESS_REL_TOL = 0.02
CONTACT_COMPLIANCE_TOL = 0.08
PLANE_Z = 0.01  # the plane object is a 1 cm plate on the table [m]
DOWN = np.diag([1.0, -1.0, -1.0])  # tool z pointing down, tool x along world x


@pytest.fixture(scope="module")
def plane_backend():
    return MujocoBackend(SceneConfig(object_name="plane"))


def test_implements_protocol(plane_backend):
    assert isinstance(plane_backend, RobotBackend)
    s = plane_backend.reset(seed=0)
    assert s.q.shape == (7,) and s.jacobian.shape == (6, 7) and s.mass_matrix.shape == (7, 7)
    assert s.wrench_tool.shape == (6,) and s.is_finite()
    np.testing.assert_allclose(s.q, FRANKA_HOME_Q)
    assert plane_backend.dt == pytest.approx(0.001)


def test_gravity_compensated_robot_holds_still_for_2s(plane_backend):
    s0 = plane_backend.reset(seed=0)
    for _ in range(2000):
        plane_backend.apply_torque(np.zeros(7))
        s = plane_backend.step()
    assert s.t == pytest.approx(2.0)
    assert np.abs(s.q - s0.q).max() < HOLD_TOL_RAD


def test_without_gravity_compensation_the_arm_sags():
    backend = MujocoBackend(SceneConfig(object_name="plane", gravity_compensation=False))
    s0 = backend.state()
    for _ in range(200):
        backend.step()
    assert np.abs(backend.state().q - s0.q).max() > 0.01


def test_state_is_consistent(plane_backend):
    plane_backend.reset(seed=0)
    tau = np.array([2.0, -3.0, 1.0, 2.0, 0.5, -0.5, 0.3])
    states = []
    for _ in range(50):
        plane_backend.apply_torque(tau)
        states.append(plane_backend.step())
    s = plane_backend.state()
    # the twist is the derivative of the TCP position (world frame, linear rows first); the
    # semi-implicit integrator moves q with the new velocity, so the difference matches the later twist
    v_fd = (states[-1].ee_position - states[-2].ee_position) / plane_backend.dt
    np.testing.assert_allclose(states[-1].ee_twist[:3], v_fd, atol=5e-3 * np.linalg.norm(v_fd))
    np.testing.assert_allclose(s.mass_matrix, s.mass_matrix.T, atol=1e-12)
    assert np.linalg.eigvalsh(s.mass_matrix).min() > 0
    np.testing.assert_allclose(s.tau_measured - s.gravity, tau, atol=1e-9)
    np.testing.assert_allclose(s.ee_rotation @ s.ee_rotation.T, np.eye(3), atol=1e-9)


def test_states_own_their_arrays_and_match_mujoco(plane_backend):
    """Controllers keep states: a state's arrays must not change when the simulation steps on, nor
    share memory with the next state or with MuJoCo's buffers."""
    b = plane_backend
    b.reset(seed=0)
    b.apply_torque(np.array([2.0, -3.0, 1.0, 2.0, 0.5, -0.5, 0.3]))
    s0 = b.step()
    fields = ("q", "dq", "tau_measured", "ee_position", "ee_rotation", "ee_twist", "jacobian", "mass_matrix",
              "coriolis", "gravity", "wrench_tool")
    snapshot = {f: getattr(s0, f).copy() for f in fields}
    # MuJoCo's own quantities at this instant
    m, d = b.model, b.data
    jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    mujoco.mj_jacSite(m, d, jacp, jacr, b._ids["tcp"])
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, full)
    jac = np.vstack([jacp, jacr])[:, :7]
    np.testing.assert_array_equal(s0.jacobian, jac)
    np.testing.assert_array_equal(s0.mass_matrix, full[:7, :7])
    np.testing.assert_array_equal(s0.q, d.qpos[:7])
    np.testing.assert_array_equal(s0.dq, d.qvel[:7])
    np.testing.assert_array_equal(s0.gravity, d.qfrc_gravcomp[:7])
    np.testing.assert_array_equal(s0.coriolis, d.qfrc_bias[:7] - d.qfrc_gravcomp[:7])
    np.testing.assert_array_equal(s0.ee_twist, jac @ d.qvel[:7])
    s1 = None
    for _ in range(5):
        s1 = b.step()
    for f in fields:
        a = getattr(s0, f)
        np.testing.assert_array_equal(a, snapshot[f], err_msg=f)
        assert not np.shares_memory(a, getattr(s1, f)), f
        for buf in (d.qpos, d.qvel, d.qfrc_gravcomp, d.qfrc_bias, d.qfrc_actuator, d.site_xpos, d.site_xmat,
                    d.sensordata, b._jac, b._mfull):
            assert not np.shares_memory(a, buf), f
    assert not np.array_equal(s0.q, s1.q)  # the arm moved meanwhile


@pytest.mark.parametrize("value", [1000.0, 1e308])  # 1e308: the finiteness sum overflows, the torque does not
def test_torque_is_clipped_to_franka_limits(plane_backend, value):
    plane_backend.reset(seed=0)
    plane_backend.apply_torque(np.full(7, value))
    s = plane_backend.step()
    np.testing.assert_allclose(s.tau_measured - s.gravity, FRANKA_TORQUE_LIMITS)


@pytest.mark.parametrize("bad", [np.array([np.nan, 0, 0, 0, 0, 0, 0]), np.array([0, 0, 0, 0, 0, 0, np.inf])])
def test_nan_torque_is_refused(plane_backend, bad):
    with pytest.raises(ControllerFault, match="NaN"):
        plane_backend.apply_torque(bad)


def test_wrong_torque_shape_is_refused(plane_backend):
    with pytest.raises(ControllerFault, match=r"shape \(7,\)"):
        plane_backend.apply_torque(np.zeros(6))


def test_divergence_raises_simulation_error():
    backend = MujocoBackend(SceneConfig(object_name="plane"))
    for _ in range(5):
        backend.step()
    backend.data.qvel[3] = np.nan
    with pytest.raises(SimulationError, match=r"t = 0\.0060 s.*Hint"):
        backend.step()


def test_divergence_without_mujoco_auto_reset_raises_simulation_error():
    # without auto-reset MuJoCo only warns and the clock runs on: the joint states are checked instead
    backend = MujocoBackend(SceneConfig(object_name="plane"))
    backend.model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET
    backend.reset()
    for _ in range(5):
        backend.step()
    backend.data.qvel[3] = np.nan
    with pytest.raises(SimulationError, match=r"t = 0\.0060 s.*Hint"):
        backend.step()


def test_state_with_a_non_finite_torque_or_wrench_is_refused(plane_backend):
    plane_backend.reset(seed=0)
    plane_backend.data.qfrc_actuator[2] = np.inf  # what the state reports as the measured torque
    with pytest.raises(SimulationError, match="non-finite robot state"):
        plane_backend._make_state()
    plane_backend.reset(seed=0)
    plane_backend._wrench = np.full(6, np.nan)
    with pytest.raises(SimulationError, match="non-finite robot state"):
        plane_backend._make_state()
    plane_backend.reset(seed=0)


def test_reset_is_deterministic_for_a_seed():
    cfg = SceneConfig(object_name="plane", ft_noise_n=0.5, ft_noise_nm=0.02)
    runs = []
    for _ in range(2):
        b = MujocoBackend(cfg)
        b.reset(seed=3)
        for _ in range(100):
            b.apply_torque(np.full(7, 0.5))
            s = b.step()
        runs.append(np.concatenate([s.q, s.dq, s.wrench_tool]))
    np.testing.assert_array_equal(runs[0], runs[1])
    b.reset(seed=4)
    for _ in range(100):
        b.apply_torque(np.full(7, 0.5))
        s = b.step()
    assert not np.array_equal(runs[0][-6:], s.wrench_tool)


def test_reset_rejects_bad_q0(plane_backend):
    with pytest.raises(InputError, match="q0"):
        plane_backend.reset(q0=np.zeros(5))


def test_ft_reads_weight_of_a_hung_mass():
    mass = 1.5
    backend = MujocoBackend(SceneConfig(object_name="plane", payload_mass_kg=mass))
    s0 = backend.reset(seed=0)
    hold = SimpleImpedance()
    for _ in range(500):
        backend.apply_torque(hold.torque(backend.state(), s0.ee_position, s0.ee_rotation))
        s = backend.step()
    w = s.wrench_world
    # the tool holds the mass up: it exerts +m·g (upwards) on it
    assert w[2] == pytest.approx(mass * 9.81, rel=FT_WEIGHT_REL_TOL)
    assert np.linalg.norm(w[:2]) < FT_WEIGHT_REL_TOL * mass * 9.81


def test_ft_without_payload_reads_zero_in_any_pose(plane_backend):
    q = FRANKA_HOME_Q + np.array([0.3, 0.2, -0.4, 0.3, 0.8, -0.5, 0.6])
    plane_backend.reset(seed=0, q0=q)
    for _ in range(20):
        s = plane_backend.step()
    np.testing.assert_allclose(s.wrench_tool, 0.0, atol=1e-3)


def _press(backend, force_n, seconds=2.0):
    """Hold the TCP above the plane in x, y, orientation and push with force_n along −z world."""
    target = np.array([0.5, 0.0, PLANE_Z + 0.003])
    q = backend.solve_ik(target, DOWN)
    backend.reset(seed=0, q0=q)
    ctrl = SimpleImpedance(free_axes=(2,))
    ff = np.array([0.0, 0.0, -force_n, 0.0, 0.0, 0.0])
    log = []
    for _ in range(int(seconds / backend.dt)):
        s = backend.state()
        backend.apply_torque(ctrl.torque(s, target, DOWN, ff))
        backend.step()
        log.append((s.wrench_tool[2], backend.pad_contact()[0], s.ee_position[2]))
    return np.array(log)


def test_pressing_force_is_measured_within_2_percent(plane_backend):
    log = _press(plane_backend, 15.0)
    steady = log[-500:]
    assert steady[:, 0].mean() == pytest.approx(15.0, rel=PRESS_REL_TOL)
    assert steady[:, 1].mean() == pytest.approx(15.0, rel=PRESS_REL_TOL)
    assert steady[:, 0].std() < 0.1


def test_pure_jacobian_transpose_force_gives_the_commanded_force(plane_backend):
    # The acceptance: τ = Jᵀ f with f along −z world (plus joint damping to settle).
    q = plane_backend.solve_ik(np.array([0.5, 0.0, PLANE_Z + 0.001]), DOWN)
    plane_backend.reset(seed=0, q0=q)
    f = np.array([0.0, 0.0, -15.0, 0.0, 0.0, 0.0])
    fz = []
    for _ in range(2000):
        s = plane_backend.state()
        plane_backend.apply_torque(s.jacobian.T @ f - 2.0 * s.dq)
        plane_backend.step()
        fz.append(s.wrench_tool[2])
    assert np.mean(fz[-500:]) == pytest.approx(15.0, rel=PRESS_REL_TOL)


def test_sponge_stiffness_is_physical(plane_backend):
    cfg = plane_backend.config
    slide = plane_backend.model.joint("pad_slide").qposadr[0]
    for force in (10.0, 20.0):
        log = _press(plane_backend, force)
        spring = -plane_backend.data.qpos[slide]  # the sponge's own compression
        assert spring == pytest.approx(force / cfg.tool_stiffness_n_per_m, rel=STIFFNESS_REL_TOL)
        # the TCP is the uncompressed pad tip: sponge and (stiffer) contact in series
        compression = PLANE_Z - log[-300:, 2].mean()
        assert compression == pytest.approx(force / cfg.tool_stiffness_n_per_m, rel=CONTACT_COMPLIANCE_TOL)


def test_sliding_contact_is_steady(plane_backend):
    # wiping at 2.5 cm/s with friction must not make the pad chatter (see tactex/sim/tool.py)
    target = np.array([0.5, 0.05, PLANE_Z + 0.003])
    plane_backend.reset(seed=0, q0=plane_backend.solve_ik(target, DOWN))
    ctrl = SimpleImpedance(free_axes=(2,))
    ff = np.array([0.0, 0.0, -15.0, 0.0, 0.0, 0.0])
    forces = []
    for i in range(3000):
        s = plane_backend.state()
        goal = target - np.array([0.0, 0.025 * max(0.0, s.t - 1.0), 0.0])
        plane_backend.apply_torque(ctrl.torque(s, goal, DOWN, ff))
        plane_backend.step()
        if i > 1500:
            forces.append((s.wrench_tool[2], plane_backend.pad_contact()[0], s.wrench_tool[1]))
    forces = np.array(forces)
    assert forces[:, 1].min() > 10.0  # never loses contact
    assert forces[:, 0].std() < 0.2
    assert abs(forces[:, 2].mean()) == pytest.approx(0.4 * 15.0, rel=0.1)  # Coulomb friction μ·F_n


def test_ik_reaches_a_pose_and_reports_unreachable(plane_backend):
    target = np.array([0.45, 0.1, 0.1])
    rot = DOWN @ np.array([[np.cos(0.3), -np.sin(0.3), 0], [np.sin(0.3), np.cos(0.3), 0], [0, 0, 1]])
    q = plane_backend.solve_ik(target, rot)
    s = plane_backend.reset(seed=0, q0=q)
    np.testing.assert_allclose(s.ee_position, target, atol=1e-5)
    np.testing.assert_allclose(s.ee_rotation, rot, atol=1e-4)
    q_pos_only = plane_backend.solve_ik(target)
    assert np.all(q_pos_only >= plane_backend.model.jnt_range[:7, 0])
    with pytest.raises(SimulationError, match="reach"):
        plane_backend.solve_ik(np.array([2.0, 0.0, 0.5]), DOWN)
    with pytest.raises(InputError, match="position"):
        plane_backend.solve_ik(np.array([np.nan, 0.0, 0.5]))
    with pytest.raises(InputError, match="rotation"):
        plane_backend.solve_ik(target, np.eye(3) * 2)


def test_ik_settled_search_agrees_with_the_full_search(plane_backend):
    """settled_step_rad / max_iter (the quick search that screens many poses) end where the full search would:
    the same reachable poses (to 1e-3 rad, the pose within REACHED_*), the same unreachable ones refused."""
    from tactex.sim.ik import REACHED_POS_M, REACHED_ROT_RAD, rotation_error

    rng = np.random.default_rng(3)
    reached = refused = 0
    for i in range(24):
        target = np.array([0.3, -0.35, 0.02]) + rng.random(3) * np.array([0.5, 0.7, 0.5])
        tilt = rng.normal(size=3) * 0.4
        rot = DOWN if i % 2 else DOWN @ np.array([[1, 0, 0], [0, np.cos(tilt[0]), -np.sin(tilt[0])],
                                                  [0, np.sin(tilt[0]), np.cos(tilt[0])]])
        seed = FRANKA_HOME_Q + rng.normal(size=7) * 0.3
        try:
            q_full = plane_backend.solve_ik(target, rot, seed)
        except SimulationError:
            q_full = None
        try:
            q_quick = plane_backend.solve_ik(target, rot, seed, settled_step_rad=1e-5, max_iter=150)
        except SimulationError:
            q_quick = None
        assert (q_full is None) == (q_quick is None), f"target {i}: one search reached it, the other not"
        if q_full is None:
            refused += 1
            continue
        reached += 1
        assert np.max(np.abs(q_quick - q_full)) < 1e-3
        plane_backend.reset(seed=0, q0=q_quick)
        s = plane_backend.state()
        assert np.linalg.norm(s.ee_position - target) < REACHED_POS_M
        assert np.linalg.norm(rotation_error(rot, s.ee_rotation)) < REACHED_ROT_RAD
    assert reached >= 8 and refused >= 2  # both kinds were tried
    with pytest.raises(SimulationError, match="reach"):
        plane_backend.solve_ik(np.array([2.0, 0.0, 0.5]), DOWN, settled_step_rad=1e-5, max_iter=150)
    for bad in (0.0, -1e-5, np.nan):
        with pytest.raises(InputError, match="settled_step_rad"):
            plane_backend.solve_ik(np.array([0.45, 0.1, 0.1]), DOWN, settled_step_rad=bad)
    with pytest.raises(InputError, match="max_iter"):
        plane_backend.solve_ik(np.array([0.45, 0.1, 0.1]), DOWN, max_iter=0)


def test_move_object_moves_the_contact_surface(plane_backend):
    plane_backend.reset(seed=0)
    rot = np.eye(3)
    plane_backend.move_object("plane", np.array([0.5, 0.0, 0.05]), rot)
    pos, r = plane_backend.object_pose("plane")
    np.testing.assert_allclose(pos, [0.5, 0.0, 0.05])
    np.testing.assert_allclose(r, rot, atol=1e-12)
    with pytest.raises(InputError, match="no object named"):
        plane_backend.move_object("bowl", np.zeros(3))
    with pytest.raises(InputError, match="rotation"):
        plane_backend.move_object("plane", np.zeros(3), np.eye(3) * 2)
    plane_backend.reset(seed=0)
    np.testing.assert_allclose(plane_backend.object_pose()[0], [0.5, 0.0, PLANE_Z])
