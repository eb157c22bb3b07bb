"""The clean's exploration step taken while the previous command executes (tactex.tasks.clean.step_ahead)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from tactex.ergodic.explorer import HedacExplorer
from tactex.tasks.clean.step_ahead import ERGODICITY_EVERY_STEPS, StepAhead


class _Path:
    """A stand-in explorer: numbered steps along x, a log of what was called."""

    def __init__(self) -> None:
        self.calls: list[tuple] = []
        self.k = 0

    def step(self, measured=None):
        self.k += 1
        self.calls.append(("step", None if measured is None else tuple(measured)))
        return SimpleNamespace(point=np.array([0.001 * self.k, 0.0, 0.0]), normal=np.array([0.0, 0.0, 1.0]))

    def update_target(self, target, keep_coverage=False):
        self.calls.append(("target", float(np.sum(target)), keep_coverage))


class _Wear:
    def __init__(self) -> None:
        self.reads = 0

    def remaining(self):
        self.reads += 1
        return np.full(4, 0.25)

    def island_left(self, point, radius_m):
        return bool(point[0] < 0.0025)


def _state(t: float):
    return SimpleNamespace(t=t, ee_position=np.array([0.1, 0.2, 0.3]))


def test_the_step_is_taken_only_on_the_tick_before_it_is_due() -> None:
    path = _Path()
    ahead = StepAhead(path, 0.001)
    ahead.arm(due_t=0.050, step_index=1, enabled=True)
    ahead(_state(0.047))  # the next tick (0.048) is not the step's
    assert path.calls == [] and ahead.take() is None
    ahead(_state(0.049))  # the next tick (0.050) is
    assert ahead.pending
    cmd, reads = ahead.take()
    assert cmd.point[0] == pytest.approx(0.001) and reads == {}
    assert not ahead.pending and ahead.take() is None


def test_nothing_is_stepped_ahead_when_disabled_or_while_a_step_waits() -> None:
    path = _Path()
    ahead = StepAhead(path, 0.001)
    ahead.arm(due_t=0.010, step_index=1, enabled=False)  # a stroke drives the agent, or the phase ends
    ahead(_state(0.009))
    assert path.calls == []
    ahead.arm(due_t=0.010, step_index=1, enabled=True)
    ahead(_state(0.009))
    ahead(_state(0.010))  # held at the due tick: the prepared step waits, no second one
    assert [c[0] for c in path.calls] == ["step"]


def test_the_measured_tcp_is_read_only_with_agent_feedback() -> None:
    for feedback, expected in ((False, None), (True, (0.1, 0.2, 0.3))):
        path = _Path()
        ahead = StepAhead(path, 0.001, agent_feedback=feedback)
        ahead.arm(0.002, 1, True)
        ahead(_state(0.001))
        assert path.calls == [("step", expected)]


def test_a_target_update_is_made_after_the_send_and_before_the_next_step() -> None:
    path = _Path()
    settled: list[int] = []
    ahead = StepAhead(path, 0.001, settle=lambda: settled.append(len(path.calls)))
    ahead.update_target_later(np.ones(3))
    assert path.calls == []  # nothing happens in the loop itself
    ahead.arm(0.002, 1, True)
    ahead(_state(0.001))
    assert path.calls == [("target", 3.0, True), ("step", None)]
    assert settled == [0]  # the wear accounting first, before anything reads the model


def test_model_and_ergodicity_reads_come_with_the_steps_that_use_them() -> None:
    path, wear = _Path(), _Wear()
    ahead = StepAhead(path, 0.001, wear=wear, model_update_steps=2, island_radius_m=0.01)
    ahead.arm(0.002, 1, True)
    ahead(_state(0.001))
    assert ahead.take()[1] == {}  # step 1: no model update
    ahead.arm(0.004, 2, True)
    ahead(_state(0.003))
    cmd, reads = ahead.take()
    assert cmd.point[0] == pytest.approx(0.002)
    assert reads["predicted"].sum() == pytest.approx(1.0) and reads["island_left"] is True  # at x = 2 mm
    assert "ergodicity" not in reads  # only an explorer has one
    # the same reads for a step taken in place; none of the model's while a stroke drives the agent
    assert set(ahead.read(cmd, 2)) == {"predicted", "island_left"} and ahead.read(cmd, 2, model=False) == {}


def test_an_explorer_reads_its_ergodicity_ahead_every_few_steps(tmp_path) -> None:
    from tactex.ergodic.config import HedacConfig
    from tactex.pointcloud.markings import marked_cloud
    from tactex.pointcloud.shapes import get_surface
    from tactex.spectral import build_basis

    cloud = marked_cloud(get_surface("plate"), "X", spacing_m=0.006)
    ex = HedacExplorer(cloud, build_basis(cloud, n_eigen=30, cache=False),
                       HedacConfig(n_eigen=30, agent_radius_m=0.015, compiled=False))
    ex.reset(cloud.points[np.flatnonzero(cloud.target > 0)[0]])
    ahead = StepAhead(ex, 0.001, read_residual=True, explorer=ex)
    ahead.arm(0.002, ERGODICITY_EVERY_STEPS, True)
    ahead(_state(0.001))
    cmd, reads = ahead.take()
    assert np.isfinite(reads["ergodicity"]) and 0.0 <= reads["residual"] <= 1.0
    assert np.isclose(np.linalg.norm(cmd.normal), 1.0)


def test_in_a_clean_the_explorer_steps_while_the_command_executes(monkeypatch) -> None:
    """Almost every contact step of a simulated clean, and every target update from the wear model, runs
    in ``after_send``: on a real robot, not between a state and its command. The in-place steps are the
    first of each contact phase (no command before it to run behind) and those after a stroke."""
    from tactex.tasks.clean import CleanConfig, run_clean

    where: dict[str, list[bool]] = {"step": [], "target": []}
    inside = [False]
    orig_call, orig_step, orig_target = StepAhead.__call__, HedacExplorer.step, HedacExplorer.update_target

    def call(self, state):
        inside[0] = True
        try:
            orig_call(self, state)
        finally:
            inside[0] = False

    def step(self, *a, **k):
        where["step"].append(inside[0])
        return orig_step(self, *a, **k)

    def update_target(self, *a, **k):
        if k.get("keep_coverage"):  # the wear model's updates in contact (a view replaces the target otherwise)
            where["target"].append(inside[0])
        return orig_target(self, *a, **k)

    monkeypatch.setattr(StepAhead, "__call__", call)
    monkeypatch.setattr(HedacExplorer, "step", step)
    monkeypatch.setattr(HedacExplorer, "update_target", update_target)
    # the explorer from the touch-down (no planned sweep, which would take most of the budget on the plate's X)
    m = run_clean(CleanConfig(object_name="plate", budget_s=12.0, n_eigen=60, sweep_corners=0), progress=False).metrics
    assert m["dirt_removed_fraction"] > 0.5
    steps = np.array(where["step"])
    assert steps.size > 100 and steps.mean() >= 0.95, (steps.size, steps.mean())
    assert where["target"] and all(where["target"])


def test_a_hold_lasts_at_most_its_steps_until_the_tool_catches_up() -> None:
    from tactex.tasks.step_hold import StepHold

    hold = StepHold(3)
    # a point the tool never reaches: three steps put off, then the agent goes on, step after step
    assert [hold.hold(True) for _ in range(8)] == [True, True, True] + [False] * 5
    assert hold.hold(False) is False  # caught up: the count restarts
    assert [hold.hold(True) for _ in range(4)] == [True, True, True, False]
    assert [StepHold(0).hold(True) for _ in range(2)] == [False, False]  # 0: never waits
    with pytest.raises(ValueError):
        StepHold(-1)
