"""A policy held to its limits while a run follows it.

:func:`~tactex.tasks.policies.check.check_policy` samples a policy before the arm moves; a policy of one's own
may still change its mind once the run has started (a state, a clock, an exception on a rare branch). The guard
calls it at every tick and raises a :class:`~tactex.errors.PolicyFault`, which stops the run with its data
kept, when ``at`` raises, returns anything but a :class:`PolicyPoint` of finite floats, or leaves the limits it
was checked against: a force set point outside the allowed range, or a speed (its rates, or how far its offsets
moved since the last call) over the limit by more than :data:`SPEED_SLACK`."""

from __future__ import annotations

import math

from tactex.errors import PolicyFault
from tactex.tasks.policies.base import ForceMotionPolicy, PolicyPoint, point_problem
from tactex.tasks.policies.check import PolicyLimits

__all__ = ["SPEED_SLACK", "PolicyGuard"]

#: A speed over the limit by more than this share at run time is a fault [-]: the check before the run holds
#: the limit itself at 2 ms samples; between them a smooth path may peak a little higher.
SPEED_SLACK = 0.5
#: An offset step this small is never a fault [m] (round-off of a path's sums).
STEP_FLOOR_M = 1e-6


class PolicyGuard(ForceMotionPolicy):
    """``policy`` as the run sees it, checked call by call against ``limits`` (module docstring)."""

    def __init__(self, policy: ForceMotionPolicy, limits: PolicyLimits) -> None:
        self.policy, self.limits = policy, limits
        self.duration_s = policy.duration_s
        self._last: tuple[float, float, float] | None = None  # (t [s], u, v [m]) of the last call
        self._max_speed = limits.max_speed_m_s * (1.0 + SPEED_SLACK)

    def at(self, t_s: float) -> PolicyPoint:
        try:
            point = self.policy.at(t_s)
        except Exception as exc:
            raise PolicyFault(f"the policy's at({t_s:.3f}) raised {type(exc).__name__}: {exc}") from exc
        if (problem := point_problem(point)) is not None:
            raise PolicyFault(f"at t = {t_s:.3f} s the policy's {problem}")
        u, v, du, dv, force = point
        lim = self.limits
        if not lim.min_force_n - 1e-9 <= force <= lim.max_force_n + 1e-9:
            raise PolicyFault(f"at t = {t_s:.3f} s the policy's force_n = {force:g} N left [{lim.min_force_n:g}, "
                              f"{lim.max_force_n:g}] N, the range it was checked in")
        rate = math.hypot(du, dv)
        if rate > self._max_speed:
            raise PolicyFault(f"at t = {t_s:.3f} s the policy's rates say {rate:.3f} m/s, over the task's "
                              f"{lim.max_speed_m_s:g} m/s it was checked against")
        last = self._last
        if last is not None and t_s > last[0]:
            step = math.hypot(u - last[1], v - last[2])
            if step > self._max_speed * (t_s - last[0]) + STEP_FLOOR_M:
                raise PolicyFault(f"at t = {t_s:.3f} s the policy's offsets moved {1e3 * step:.2f} mm in "
                                  f"{1e3 * (t_s - last[0]):.1f} ms ({step / (t_s - last[0]):.3f} m/s), over the "
                                  f"task's {lim.max_speed_m_s:g} m/s it was checked against")
        self._last = (t_s, u, v)
        return point

    def segment_index(self, t_s: float) -> int:
        return self.policy.segment_index(t_s)

    @property
    def segment_starts_s(self) -> tuple[float, ...]:
        return self.policy.segment_starts_s

    @property
    def constant_force_n(self) -> float | None:
        return self.policy.constant_force_n
