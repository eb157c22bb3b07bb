"""The twin's count of the dirt as a clean on it reports it: from what was left at the run's start (a twin keeps
its dirt between runs), and not known when the twin stops answering at the run's end."""

from __future__ import annotations

import math
import warnings

import pytest

from tactex.errors import SensorFault
from tactex.tasks.clean.robot_camera import RobotCapture
from tactex.tasks.robot import RealRobotParams


def _capture(answers: list) -> RobotCapture:
    cap = RobotCapture(camera=None, robot=RealRobotParams(robot_ip="127.0.0.1", camera="none"))

    def twin() -> float:
        a = answers.pop(0)
        if isinstance(a, Exception):
            raise a
        return a

    cap._twin_dirt = twin  # what twin_dirt_remaining gives on --camera twin
    return cap


def test_a_fresh_twin_counts_its_own_marking() -> None:
    cap = _capture([1.0, 0.4])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning on a fresh twin
        cap.refresh()
        cap.refresh(final=True)
    assert cap.dirt_remaining() == pytest.approx(0.4) and cap.metrics()["twin_dirt_at_start"] == 1.0


def test_a_twin_an_earlier_run_cleaned_counts_from_this_runs_start_and_says_so() -> None:
    cap = _capture([0.5, 0.1])
    with pytest.warns(RuntimeWarning, match=r"the twin holds 50.0 % of its marking at this run's start"):
        cap.refresh()
    cap.refresh(final=True)
    assert cap.dirt_remaining() == pytest.approx(0.2)  # 0.1 of the marking is 0.2 of what this run met


def test_a_twin_that_stops_answering_keeps_its_last_count_until_the_end_where_it_is_not_known() -> None:
    cap = _capture([1.0, SensorFault("twin gone"), SensorFault("twin gone")])
    cap.refresh()
    cap.refresh()  # a capture's ask that fails keeps the last answer
    assert cap.dirt_remaining() == 1.0
    cap.refresh(final=True)  # the run's last ask: nothing measured, not a clean 0 %
    assert math.isnan(cap.dirt_remaining())
