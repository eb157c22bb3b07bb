"""A wipe stopped on the way to its start pose (before the policy runs) keeps its run folder: the
metrics say why and that the run is partial, and the series file is there, as for a stop during
the policy."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tactex.errors import RobotError, RunInterrupted
from tactex.experiments.run import run_task
from tactex.robots.loop import ControlLoop
from tactex.tasks.wipe import WipeConfig


def _stopping_transit(exc: BaseException, ticks: int = 20):
    """A ``move_joints`` (the move to the start, direct here) that runs ``ticks`` ticks of the real move, then
    has the robot stop."""
    real = ControlLoop.move_joints

    def move_joints(self, *args, **kwargs):
        n = [0]
        real_tick = self.tick

        def tick(reference, after_send=None):
            n[0] += 1
            if n[0] > ticks:
                raise exc
            return real_tick(reference, after_send)

        self.tick = tick
        try:
            return real(self, *args, **kwargs)
        finally:
            del self.tick
    return move_joints


def _read(out):
    metrics = json.loads((out / "metrics.json").read_text())
    with np.load(out / "series.npz", allow_pickle=False) as z:
        names = list(z.files)
    return metrics, names


def test_a_robot_stop_on_the_way_to_the_start_keeps_the_run(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(ControlLoop, "move_joints",
                        _stopping_transit(RobotError("communication_constraints_violation")))
    run_task("wipe", WipeConfig(duration_s=1.0), tmp_path / "run", progress=False, video=False, note=None)
    metrics, names = _read(tmp_path / "run")
    assert metrics["aborted"].startswith("RobotError: communication_constraints_violation")
    assert metrics["partial"] is True
    assert metrics["contact_fraction"] == 0.0 and metrics["first_contact_s"] is None
    assert {"t", "tcp", "force_z_n"} <= set(names)  # the state where the robot stopped


def test_ctrl_c_on_the_way_to_the_start_keeps_the_run_and_says_so(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(ControlLoop, "move_joints", _stopping_transit(KeyboardInterrupt()))
    with pytest.raises(RunInterrupted, match=r"metrics\.json"):
        run_task("wipe", WipeConfig(duration_s=1.0), tmp_path / "run", progress=False, video=False, note=None)
    metrics, _ = _read(tmp_path / "run")
    assert metrics["aborted"] == "KeyboardInterrupt" and metrics["partial"] is True


def test_a_robot_stop_on_the_policys_first_tick_keeps_the_run(tmp_path, monkeypatch) -> None:
    # the robot stops the control on the first command of the policy, before any state came back from it:
    # the run still holds the state where it stopped (the report reads every series from it)
    real_tick = ControlLoop.tick

    def tick(self, reference, after_send=None):
        if after_send is not None and after_send.__name__ == "after_send":  # the wipe's own ticks
            raise RobotError("communication_constraints_violation")
        return real_tick(self, reference, after_send)

    monkeypatch.setattr(ControlLoop, "tick", tick)
    run_task("wipe", WipeConfig(duration_s=1.0), tmp_path / "run", progress=False, video=False, note=None)
    metrics, names = _read(tmp_path / "run")
    assert metrics["aborted"].startswith("RobotError: communication_constraints_violation")
    assert metrics["partial"] is True and metrics["first_contact_s"] is None
    assert {"t", "tcp", "force_z_n"} <= set(names)
