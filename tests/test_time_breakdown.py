"""Where a cleaning run's time goes (issue 21): the per-tick accounting and the time to 95 % removed."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.errors import InputError
from tactex.tasks.clean.time_breakdown import BUCKETS, TimeBreakdown, time_to_fraction_removed

DT = 0.001


def test_contact_is_split_by_whether_the_dirt_went_down() -> None:
    tb = TimeBreakdown(DT, contact_threshold_n=0.5, dirt_known=True)
    tb.dirt(1.0)
    for _ in range(30):  # 30 ticks on the way to the camera
        tb.tick(0.0)
    tb.set_activity("explore")
    for _ in range(10):  # contact while the dirt goes down: on dirt
        tb.tick(10.0)
    tb.dirt(0.9)
    for _ in range(10):  # contact, dirt unchanged: clean surface
        tb.tick(10.0)
    tb.dirt(0.9)
    for _ in range(4):  # lost contact while exploring
        tb.tick(0.1)
    for _ in range(3):  # contact after the last reading: no evidence of removal
        tb.tick(10.0)
    s = tb.seconds()
    assert list(s) == [b for b in BUCKETS if b != "contact"]
    assert s["vision"] == pytest.approx(30 * DT)
    assert s["contact_dirt"] == pytest.approx(10 * DT)
    assert s["contact_clean"] == pytest.approx(13 * DT)
    assert s["explore_no_contact"] == pytest.approx(4 * DT)
    assert sum(s.values()) == pytest.approx(57 * DT)  # every tick in exactly one bucket


def test_breakdown_up_to_the_95pct_mark() -> None:
    tb = TimeBreakdown(DT, contact_threshold_n=0.5, dirt_known=True)
    tb.dirt(1.0)
    for _ in range(20):  # to the camera and back
        tb.tick(0.0)
    tb.set_activity("explore")
    for _ in range(10):
        tb.tick(10.0)
    tb.dirt(0.06)  # not yet 95 % removed
    assert tb.seconds_to_mark() is None
    for _ in range(5):
        tb.tick(10.0)
    tb.dirt(0.05)  # exactly 95 % removed: the mark, with these 5 contact ticks on dirt
    for _ in range(7):  # after the mark: in the whole run's buckets only
        tb.tick(10.0)
    tb.dirt(0.01)
    to_mark, whole = tb.seconds_to_mark(), tb.seconds()
    assert to_mark is not None and list(to_mark) == list(whole)
    assert to_mark["vision"] == pytest.approx(20 * DT) and to_mark["contact_dirt"] == pytest.approx(15 * DT)
    assert sum(to_mark.values()) == pytest.approx(35 * DT) and whole["contact_dirt"] == pytest.approx(22 * DT)
    # a real robot knows no dirt: no mark
    blind = TimeBreakdown(DT, 0.5, dirt_known=False)
    blind.tick(10.0)
    blind.dirt(0.0)
    assert blind.seconds_to_mark() is None


def test_without_the_true_dirt_contact_stays_unsplit() -> None:
    tb = TimeBreakdown(DT, contact_threshold_n=0.5, dirt_known=False)
    tb.set_activity("explore")
    for _ in range(5):
        tb.tick(8.0)
    tb.dirt(float("nan"))  # a real robot's reading: ignored
    tb.set_activity("lift_off")
    tb.tick(0.0)
    s = tb.seconds()
    assert "contact_dirt" not in s and "contact_clean" not in s
    assert s["contact"] == pytest.approx(5 * DT) and s["lift_off"] == pytest.approx(DT)


def test_breakdown_checks_its_inputs() -> None:
    with pytest.raises(InputError, match="dt_s"):
        TimeBreakdown(0.0, 0.5, True)
    with pytest.raises(InputError, match="touch_down"):
        TimeBreakdown(DT, 0.5, True).set_activity("coffee")
    for bad in (0.0, 1.5, float("nan")):
        with pytest.raises(InputError, match="mark_removed"):
            TimeBreakdown(DT, 0.5, True, mark_removed=bad)


def test_time_to_fraction_removed() -> None:
    t = np.arange(6) * 0.5
    remaining = np.array([1.0, 0.6, 0.2, 0.06, 0.05, 0.01])
    assert time_to_fraction_removed(t, remaining, 0.95) == pytest.approx(2.0)
    assert time_to_fraction_removed(t, remaining, 0.5) == pytest.approx(1.0)
    assert time_to_fraction_removed(t, np.full(6, 0.5), 0.95) is None  # never
    assert time_to_fraction_removed(t, np.full(6, np.nan), 0.95) is None  # no ground truth
    with pytest.raises(InputError, match="length"):
        time_to_fraction_removed(t, remaining[:3])
    with pytest.raises(InputError, match="removed_fraction"):
        time_to_fraction_removed(t, remaining, 1.5)
