"""The twin's 1 kHz cadence: a state every period, and the client's whole window before the next step.

franky-sim's own loop (``SimulationServer.run_once``) processes the commands, steps, sends the state
and sleeps for what is left of the millisecond. Its states therefore leave at the end of a step
whose length varies with the machine's load, and the client's window (from a state to the next
processing of commands) is whatever the sleep happens to be. A real Franka sends a state on its own
clock every millisecond and uses the command that arrived before its next cycle.

:class:`TwinClock` gives the twin that shape. It sends each state on a fixed grid, one period after
the last. After each state the client has a fixed window, by default half the period: the budget
tactex plans for one FCI iteration of receiving the state, computing and sending the command
(docs/real_robot.md). Then the twin takes the commands and steps; an answer that comes earlier is
taken at once. A slow step delays the next state, not the client's window. A state that leaves late
re-anchors the grid: the next leaves at least :data:`MIN_SPACING` periods later, so that two states
never arrive together (a client that finds two states waiting counts a lost cycle it did not cause).

:class:`CommandRate` is libfranka's ``control_command_success_rate`` as the robot computes it: the
share of the last 100 cycles of a motion whose answer came within the window. Stock franky-sim
reports 1.0 always.
"""

from __future__ import annotations

import ctypes
import sys
import time

from tactex.errors import ConfigError

__all__ = ["MIN_SPACING", "CommandRate", "TwinClock", "fine_timer_slack", "linux_prctl"]

#: The shortest gap between two states, as a fraction of the period [-]: a state late by more than a
#: tenth of a period re-anchors the grid at itself, instead of the next ones following back to back.
MIN_SPACING = 0.9


class TwinClock:
    """When to take the client's command and when to send the next state (monotonic seconds).

    Args:
        period_s: the state period [s] (1 ms / the real-time factor); 0 runs unpaced (no waits).
        window_s: how long after a state has left the twin waits for the client's answer before it
            takes the commands and steps [s]; the rest of the period is the twin's.
        smoothing: weight of the newest send duration in its running mean [-].
    """

    def __init__(self, period_s: float, window_s: float, smoothing: float = 0.05) -> None:
        if not (period_s >= 0.0 and 0.0 <= window_s <= period_s and 0.0 < smoothing <= 1.0):
            raise ConfigError(f"TwinClock: need period_s ≥ 0, 0 ≤ window_s ≤ period_s and smoothing in (0, 1], got "
                              f"{period_s!r}, {window_s!r}, {smoothing!r}")
        self.period_s = float(period_s)
        self.window_s = float(window_s)
        self.smoothing = float(smoothing)
        self.last_sent = time.monotonic()
        self.next_send = self.last_sent + self.period_s
        self._send_s = 0.0  # running mean of a send's duration (the state's assembly and sendto) [s]

    def process_at(self) -> float:
        """When to take the client's commands and step: the client's window after the last state."""
        return self.last_sent + self.window_s

    def send_at(self) -> float:
        """When the next state's send should begin, so that it leaves on time."""
        return self.next_send - self._send_s

    def sent(self, send_s: float, done: float) -> None:
        """Record a send that took ``send_s`` [s] and finished at ``done``; schedule the next one."""
        self._send_s += self.smoothing * (send_s - self._send_s)
        self.last_sent = done
        self.next_send = max(self.next_send + self.period_s, done + MIN_SPACING * self.period_s)

    @staticmethod
    def wait_until(t: float) -> None:
        """Sleep until monotonic time ``t`` [s] (at once when it has passed)."""
        delay = t - time.monotonic()
        if delay > 0.0:
            time.sleep(delay)


class CommandRate:
    """The share of the last ``window`` cycles of a motion whose answer came within the client's
    window [0, 1], as libfranka's ``control_command_success_rate``; ``lowest``: its minimum over the
    current motion, or the last one once it has ended.

    Out of a motion the rate is 1.0 (libfranka's robot reports 0 when no control loop runs; a twin
    that did so would put a 0 in the first state a new control reads).
    """

    def __init__(self, window: int = 100) -> None:
        if not (isinstance(window, int) and window > 0):
            raise ConfigError(f"CommandRate: window must be a positive number of cycles, got {window!r}")
        self._ring = bytearray(b"\x01" * window)
        self._i = 0
        self._hits = window
        self.counting = False  # from a motion's first answer to its end
        self.lowest = 1.0

    @property
    def rate(self) -> float:
        return self._hits / len(self._ring)

    def cycle(self, in_motion: bool, answered: bool) -> None:
        """One cycle: ``answered`` whether the answer to the last state came within the window."""
        if not in_motion:
            if self.counting:  # the next motion starts full
                self._ring[:] = b"\x01" * len(self._ring)
                self._hits = len(self._ring)
            self.counting = False
            return
        if not self.counting:
            if not answered:  # the client has not answered its first state yet
                return
            self.counting = True
            self.lowest = 1.0
        hit = 1 if answered else 0
        self._hits += hit - self._ring[self._i]
        self._ring[self._i] = hit
        self._i = (self._i + 1) % len(self._ring)
        self.lowest = min(self.lowest, self._hits / len(self._ring))


def linux_prctl(option: int, value: int) -> bool:
    """``prctl(option, value)`` on Linux (the twin's timer slack, its child's parent-death signal); False
    elsewhere or when the call fails."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        # the process's own symbols, libc's among them: no library search (it would start ldconfig, which a
        # child between fork and exec must not do)
        return ctypes.CDLL(None, use_errno=True).prctl(option, ctypes.c_ulong(int(value)), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def fine_timer_slack(slack_ns: int = 1000) -> bool:
    """Let this thread's sleeps wake within ``slack_ns`` of their time (Linux's default slack is
    50 µs, a twentieth of the twin's period). Returns whether it was set."""
    return linux_prctl(29, slack_ns)  # PR_SET_TIMERSLACK
