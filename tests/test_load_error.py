"""The load check: a tool weight the robot's load setting misses, measured from a still hold and added to
every command (tactex.control.load_error, SafetyLayer.load_wrench_world)."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.control import Controller, SafetyLayer
from tactex.control.load_error import G_M_S2, LoadErrorEstimator
from tactex.errors import InputError
from tests.test_control_common import N_JOINTS, make_state

Q_MID = np.array([0.0, 0.0, 0.0, -1.5, 0.0, 1.8, 0.0])
#: the hold's torque for a tool 0.214 kg heavier than set: the robot must push it up at the TCP
HEAVIER = np.array([0.0, 0.0, 0.214 * G_M_S2, 0.01, -0.02, 0.0])


def _hold(estimator: LoadErrorEstimator, wrench: np.ndarray, ticks: int = 100, *, dq: float = 0.0,
          contact_n: float = 0.0, tau_nan: bool = False, ring: float = 0.0) -> None:
    """``ticks`` still states, each answered with the torque that holds ``wrench`` at the TCP; ``ring``: the
    arm swings (sinusoidal joint speed [rad/s]) and each command also carries the torque of that swing."""
    for k in range(ticks + 1):
        speed = dq + ring * np.sin(2 * np.pi * 5.0 * k * 1e-3)
        state = make_state(t=k * 1e-3, q=Q_MID, dq=np.full(N_JOINTS, speed), wrench_tool=[0.0, 0.0, contact_n, 0, 0, 0])
        accel = ring * 2 * np.pi * 5.0 * np.cos(2 * np.pi * 5.0 * (k + 0.5) * 1e-3)  # up to the next state
        tau = state.jacobian.T @ wrench + state.mass_matrix @ np.full(N_JOINTS, accel)
        estimator.add(state, np.full(N_JOINTS, np.nan) if tau_nan else tau)


def test_a_heavier_tool_is_found_as_its_missing_mass_and_accepted():
    est = LoadErrorEstimator()
    _hold(est, HEAVIER)
    found = est.estimate()
    assert found is not None and found.accepted and found.n_samples == 100
    np.testing.assert_allclose(found.wrench_world, HEAVIER, atol=1e-9)
    assert found.mass_kg == pytest.approx(0.214)
    assert "214 g heavier" in found.describe() and "compensated" in found.describe()


def test_the_hold_counts_while_the_arm_still_rings_after_a_move():
    # the swing's own torque (M·q̈) is taken off each command: the weight alone is left
    est = LoadErrorEstimator()
    _hold(est, HEAVIER, ring=0.1)
    found = est.estimate()
    assert found is not None and found.accepted
    assert found.mass_kg == pytest.approx(0.214, abs=0.005)


def test_a_lighter_tool_is_a_negative_mass():
    est = LoadErrorEstimator()
    _hold(est, -HEAVIER)
    found = est.estimate()
    assert found is not None and found.accepted and found.mass_kg == pytest.approx(-0.214)
    assert "lighter" in found.describe()


def test_a_force_that_is_not_a_weight_is_not_compensated():
    est = LoadErrorEstimator()
    _hold(est, np.array([2.0, 0.0, 0.3, 0.0, 0.0, 0.0]))  # sideways: friction, a touch
    found = est.estimate()
    assert found is not None and not found.accepted and "from the vertical" in found.reason


def test_a_small_force_is_inside_the_dead_band():
    est = LoadErrorEstimator(deadband_n=0.5)
    _hold(est, np.array([0.0, 0.0, 0.3, 0.0, 0.0, 0.0]))
    found = est.estimate()
    assert found is not None and not found.accepted and "dead band" in found.reason


@pytest.mark.parametrize("hold", [{"dq": 0.5}, {"contact_n": 3.0}, {"tau_nan": True}, {"ticks": 20}])
def test_no_estimate_from_a_moving_touching_non_finite_or_short_hold(hold):
    est = LoadErrorEstimator(min_samples=50)
    _hold(est, HEAVIER, **hold)
    assert est.estimate() is None


@pytest.mark.parametrize("kwargs", [{"deadband_n": 0.0}, {"max_tilt_deg": float("nan")}, {"max_contact_n": -1.0},
                                    {"max_joint_speed_rad_s": True}, {"min_samples": 0}, {"min_samples": 2.5}])
def test_estimator_options_are_checked(kwargs):
    with pytest.raises(InputError, match="load check"):
        LoadErrorEstimator(**kwargs)


class _Zero(Controller):
    name = "zero"

    def reset(self, state) -> None:
        pass

    def torque(self, state, reference):
        return np.zeros(N_JOINTS)


def test_the_safety_layer_adds_the_load_wrench_to_every_command():
    layer = SafetyLayer(_Zero())
    state = make_state(q=Q_MID)
    layer.reset(state)
    layer.load_wrench_world = HEAVIER
    for k in range(200):  # the rate limit lets the torque build up
        tau = layer.torque(make_state(t=k * 1e-3, q=Q_MID), None)
    np.testing.assert_allclose(tau, state.jacobian.T @ HEAVIER, atol=1e-9)
    layer.load_wrench_world = None
    assert np.abs(layer.torque(make_state(t=0.2, q=Q_MID), None)).max() < np.abs(tau).max()
