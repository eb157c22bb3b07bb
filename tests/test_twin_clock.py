"""The twin's cadence and its command success rate (tactex.twin.clock), without franky-sim."""

from __future__ import annotations

import pytest

from tactex.errors import ConfigError
from tactex.twin.clock import MIN_SPACING, CommandRate, TwinClock


def test_on_time_sends_stay_on_the_grid():
    clock = TwinClock(1e-3, 0.5e-3)
    first = clock.next_send
    for k in range(1, 50):
        clock.sent(0.1e-3, done=clock.next_send + 0.05e-3)  # each state left 50 µs after its time
        assert clock.next_send == pytest.approx(first + k * 1e-3)


def test_a_late_state_is_followed_by_one_no_sooner_than_the_minimum_spacing():
    clock = TwinClock(1e-3, 0.5e-3)
    late = clock.next_send + 2.5e-3  # a step that stalled for 2.5 ms
    clock.sent(0.1e-3, done=late)
    assert clock.next_send == pytest.approx(late + MIN_SPACING * 1e-3)
    before = clock.next_send
    clock.sent(0.1e-3, done=clock.next_send)  # then on time again: a full period
    assert clock.next_send == pytest.approx(before + 1e-3)


def test_the_client_gets_its_window_after_every_state_and_the_send_leaves_on_time():
    clock = TwinClock(1e-3, 0.4e-3)
    for _ in range(400):
        clock.sent(0.15e-3, done=clock.next_send)
    assert clock.process_at() == pytest.approx(clock.last_sent + 0.4e-3)
    assert clock.send_at() == pytest.approx(clock.next_send - 0.15e-3, rel=1e-6)  # begins a send's length early
    late = clock.next_send + 3e-3
    clock.sent(0.15e-3, done=late)  # after a late state the window still starts at that state
    assert clock.process_at() == pytest.approx(late + 0.4e-3)


def test_unpaced_clock_never_waits():
    clock = TwinClock(0.0, 0.0)
    done = clock.next_send + 1.0
    clock.sent(0.1e-3, done=done)
    assert clock.next_send == done  # the next state as soon as the step is done
    assert clock.process_at() == done


def test_command_rate_counts_from_the_first_command_of_a_motion():
    rate = CommandRate(window=10)
    rate.cycle(in_motion=False, answered=False)
    rate.cycle(in_motion=True, answered=False)  # the client has not seen its first state yet
    assert rate.rate == 1.0 and not rate.counting
    for k in range(10):
        rate.cycle(in_motion=True, answered=k % 5 != 1)  # 2 of the 10 cycles without a command
    assert rate.rate == pytest.approx(0.8)
    for _ in range(10):
        rate.cycle(in_motion=True, answered=True)  # only the last 10 count
    assert rate.rate == 1.0
    rate.cycle(in_motion=True, answered=False)
    assert rate.rate == pytest.approx(0.9)
    assert rate.lowest == pytest.approx(0.8)
    rate.cycle(in_motion=False, answered=False)  # the motion ends: the next starts full
    assert rate.rate == 1.0 and rate.lowest == pytest.approx(0.8)  # the last motion's minimum stays
    rate.cycle(in_motion=True, answered=True)
    assert rate.lowest == 1.0  # until the next motion's first answer


@pytest.mark.parametrize("kwargs", [{"period_s": -1e-3, "window_s": 0.0}, {"period_s": 1e-3, "window_s": -1e-4},
                                    {"period_s": 1e-3, "window_s": 2e-3},
                                    {"period_s": 1e-3, "window_s": 5e-4, "smoothing": 0.0},
                                    {"period_s": float("nan"), "window_s": 0.0}])
def test_clock_checks(kwargs):
    with pytest.raises(ConfigError, match="TwinClock"):
        TwinClock(**kwargs)


@pytest.mark.parametrize("window", [0, -3, 2.5])
def test_rate_checks(window):
    with pytest.raises(ConfigError, match="window"):
        CommandRate(window)

