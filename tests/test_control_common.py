"""Shared synthetic robot states for the control tests, and the numpy conventions they rely on."""

from __future__ import annotations

import numpy as np

from tactex.control import RobotState
from tactex.control.frames import tool_to_world, world_to_tool
from tactex.geometry import exp_so3

N_JOINTS = 7
TOL = 1e-12


def make_state(
    *,
    t: float = 0.0,
    position: np.ndarray | None = None,
    rotation: np.ndarray | None = None,
    twist: np.ndarray | None = None,
    wrench_tool: np.ndarray | None = None,
    q: np.ndarray | None = None,
    dq: np.ndarray | None = None,
    jacobian: np.ndarray | None = None,
    seed: int = 0,
) -> RobotState:
    """A finite state with a fixed random full-rank Jacobian (seeded)."""
    rng = np.random.default_rng(seed)
    jac = rng.normal(size=(6, N_JOINTS)) if jacobian is None else jacobian
    return RobotState(
        t=t,
        q=np.zeros(N_JOINTS) if q is None else q,
        dq=np.zeros(N_JOINTS) if dq is None else dq,
        tau_measured=np.zeros(N_JOINTS),
        ee_position=np.array([0.5, 0.0, 0.3]) if position is None else np.asarray(position, float),
        ee_rotation=np.diag([1.0, -1.0, -1.0]) if rotation is None else rotation,  # tool z pointing down
        ee_twist=np.zeros(6) if twist is None else twist,
        jacobian=jac,
        mass_matrix=np.eye(N_JOINTS),
        coriolis=np.zeros(N_JOINTS),
        gravity=np.zeros(N_JOINTS),
        wrench_tool=np.zeros(6) if wrench_tool is None else np.asarray(wrench_tool, float),
    )


def test_tool_world_round_trip(rng):
    rot = exp_so3(rng.normal(size=3))
    v = rng.normal(size=6)
    np.testing.assert_allclose(world_to_tool(rot, tool_to_world(rot, v)), v, atol=TOL)


def test_pressing_wrench_points_along_tool_z_in_world():
    state = make_state(wrench_tool=np.array([0, 0, 10.0, 0, 0, 0]))
    np.testing.assert_allclose(state.wrench_world[:3], [0, 0, -10.0], atol=TOL)  # tool z points down


