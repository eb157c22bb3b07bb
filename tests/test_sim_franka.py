"""The MuJoCo Franka equals pygafro's: forward kinematics, Jacobian, mass matrix, gravity."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from tactex.sim.franka import FRANKA_TORQUE_LIMITS, franka_links, gafro_comparison_xml, gafro_robot

FK_TOL = 1e-6  # [m] and rotation-matrix entries
JAC_TOL = 1e-6
MASS_REL_TOL = 1e-3
GRAVITY_TOL = 1e-6  # [N·m]


@pytest.fixture(scope="module")
def pair():
    model = mujoco.MjModel.from_xml_string(gafro_comparison_xml())
    return model, mujoco.MjData(model), gafro_robot()


def _configs(model, n=8, seed=7):
    rng = np.random.default_rng(seed)
    return [rng.uniform(model.jnt_range[:, 0], model.jnt_range[:, 1]) for _ in range(n)]


def _gafro_jacobian(robot, q, p_ee):
    """pygafro's geometric Jacobian (motor generators: rotation e23, e13, e12 ↔ ωx, −ωy, ωz; translation
    e1i.. = velocity of the point at the world origin) as world-frame rows [v at the TCP; ω]."""
    cols = robot.getEEGeometricJacobian(list(q))
    g = np.array([[c.get_e23(), c.get_e13(), c.get_e12(), c.get_e1i(), c.get_e2i(), c.get_e3i()] for c in cols]).T
    omega = np.array([g[0], -g[1], g[2]])
    v_origin = g[3:]
    v_ee = v_origin + np.cross(omega.T, p_ee).T
    return np.vstack([v_ee, omega])


def test_gafro_jacobian_convention_matches_its_own_fk(pair):
    # Pins the conversion above to pygafro's own forward kinematics (finite differences).
    _, _, robot = pair
    q = np.array([0.1, -0.5, 0.2, -2.0, 0.3, 1.6, 0.4])
    p = np.array(robot.getEEMotor(list(q)).toTransformationMatrix())[:3, 3]
    jac = _gafro_jacobian(robot, q, p)
    rot = np.array(robot.getEEMotor(list(q)).toTransformationMatrix())[:3, :3]
    eps = 1e-6
    for i in range(7):
        dq = np.zeros(7)
        dq[i] = eps
        tp = np.array(robot.getEEMotor(list(q + dq)).toTransformationMatrix())
        tm = np.array(robot.getEEMotor(list(q - dq)).toTransformationMatrix())
        v = (tp[:3, 3] - tm[:3, 3]) / (2 * eps)
        dr = (tp[:3, :3] - tm[:3, :3]) / (2 * eps) @ rot.T
        omega = np.array([dr[2, 1], dr[0, 2], dr[1, 0]])
        np.testing.assert_allclose(jac[:3, i], v, atol=1e-6)
        np.testing.assert_allclose(jac[3:, i], omega, atol=1e-6)


def test_forward_kinematics_matches_pygafro(pair):
    model, data, robot = pair
    sid = model.site("ee").id
    for q in _configs(model):
        data.qpos[:] = q
        mujoco.mj_forward(model, data)
        t = np.array(robot.getEEMotor(list(q)).toTransformationMatrix())
        np.testing.assert_allclose(data.site_xpos[sid], t[:3, 3], atol=FK_TOL)
        np.testing.assert_allclose(data.site_xmat[sid].reshape(3, 3), t[:3, :3], atol=FK_TOL)


def test_jacobian_matches_pygafro(pair):
    model, data, robot = pair
    sid = model.site("ee").id
    jp, jr = np.zeros((3, 7)), np.zeros((3, 7))
    for q in _configs(model):
        data.qpos[:] = q
        mujoco.mj_forward(model, data)
        mujoco.mj_jacSite(model, data, jp, jr, sid)
        np.testing.assert_allclose(np.vstack([jp, jr]), _gafro_jacobian(robot, q, data.site_xpos[sid]), atol=JAC_TOL)


def test_mass_matrix_and_gravity_match_pygafro(pair):
    model, data, robot = pair
    mass = np.zeros((7, 7))
    for q in _configs(model):
        data.qpos[:] = q
        data.qvel[:] = 0
        mujoco.mj_forward(model, data)
        mujoco.mj_fullM(model, data, mass)
        ref = robot.getMassMatrix(list(q))
        assert np.linalg.norm(mass - ref) / np.linalg.norm(ref) <= MASS_REL_TOL
        gravity = robot.getJointTorques(q, np.zeros(7), np.zeros(7)).ravel()
        np.testing.assert_allclose(data.qfrc_bias, gravity, atol=GRAVITY_TOL)


def test_limits_are_frankas(pair):
    model, _, robot = pair
    np.testing.assert_allclose(model.jnt_range[:, 0], robot.getJointLimitsMin())
    np.testing.assert_allclose(model.jnt_range[:, 1], robot.getJointLimitsMax())
    np.testing.assert_allclose([link.torque_limit for link in franka_links()], FRANKA_TORQUE_LIMITS)
