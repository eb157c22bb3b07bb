"""Every registered controller and task runs: one parameterised smoke test per registry (reset, a
short run, finite output of the right shape), so a new entry is tested the day it is added."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactex.control.controller import Controller
from tactex.control.registry import CONTROLLERS, controller, hold_reference
from tactex.errors import ConfigError
from tactex.experiments.tasks import TASKS, task_spec

SMOKE_TICKS = 100
#: Simulated time of a task's smoke run [s]: enough for its program to start, short for the suite.
SMOKE_BUDGET_S = 1.0


@pytest.fixture(scope="module")
def franka():
    """The simulated Franka above the plane (one scene for every controller; reset between them)."""
    from tactex.robots import MujocoBackend
    from tactex.sim import SceneConfig

    backend = MujocoBackend(SceneConfig(object_name="plane"))
    yield backend
    backend.close()


@pytest.mark.parametrize("name", sorted(CONTROLLERS))
def test_every_registered_controller_runs_on_the_simulated_franka(name: str, franka) -> None:
    ctrl = controller(name)
    assert isinstance(ctrl, Controller) and type(ctrl) is CONTROLLERS[name]
    franka.reset()
    state = franka.state()
    ctrl.reset(state)
    reference = hold_reference(name, state)
    p0 = state.ee_position.copy()
    for _ in range(SMOKE_TICKS):
        tau = ctrl.torque(state, reference)
        assert tau.shape == (7,) and np.isfinite(tau).all(), f"{name}: {tau!r}"
        franka.apply_torque(tau)
        state = franka.step()
    assert np.isfinite(state.q).all()
    # holding the pose it started at, the tool stays within a few millimetres in 0.1 s
    assert np.linalg.norm(state.ee_position - p0) < 0.01, name


def test_an_unknown_controller_lists_the_valid_names() -> None:
    with pytest.raises(ConfigError, match="valid: " + ", ".join(CONTROLLERS)):
        controller("pid")
    with pytest.raises(ConfigError, match="unknown controller 'pid'"):
        hold_reference("pid", None)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(TASKS))
def test_every_registered_task_runs_briefly_in_simulation(name: str) -> None:
    spec = task_spec(name)
    assert spec.name == name and "" in spec.baselines
    config = spec.config_cls(**{spec.budget_field: SMOKE_BUDGET_S})
    result = spec.run(config, progress=False)
    m = result.metrics
    assert not m.get("aborted"), m.get("aborted")
    assert math.isfinite(m["sim_time_s"]) and m["sim_time_s"] > 0.0
    assert math.isfinite(m["max_contact_force_n"] if name == "clean" else m["max_force_n"])
    t, q = np.asarray(result.series["t"]), np.asarray(result.series["q"])
    assert len(t) > 0 and q.shape == (len(t), 7) and np.isfinite(t).all() and np.isfinite(q).all()


def test_an_unknown_task_lists_the_valid_names() -> None:
    with pytest.raises(ConfigError, match="valid: " + ", ".join(TASKS)):
        task_spec("sand")
