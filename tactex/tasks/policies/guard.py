"""A policy held to its limits while a run follows it.

:func:`~tactex.tasks.policies.check.check_policy` samples a policy before the arm moves; a policy of one's own
may still change its mind once the run has started (a state, a clock, an exception on a rare branch). The guard
calls it at every tick and raises a :class:`~tactex.errors.PolicyFault`, which stops the run with its data
kept, when ``at`` raises, returns anything but a :class:`PolicyPoint` of finite floats, or leaves the limits it
was checked against: a force set point outside the allowed range; a speed (its rates, or how far its offsets
moved since the last call) or an acceleration (how much its rates changed) over the limit by more than
:data:`SLACK`; rates that are not how its offsets moved. It does not check what only the whole path shows (the
reach, the joins' blends, that the same time gives the same answer): the check before the run does."""

from __future__ import annotations

import math

from tactex.errors import PolicyFault
from tactex.tasks.policies.base import ForceMotionPolicy, PolicyPoint, point_problem
from tactex.tasks.policies.check import MAX_JOIN_JUMP_M_S, RATE_AGREEMENT, PolicyLimits

__all__ = ["SLACK", "PolicyGuard"]

#: A speed or acceleration over the limit by more than this share at run time is a fault [-]: the check before
#: the run holds the limits themselves at 2 ms samples; between them a smooth path may peak a little higher.
SLACK = 0.2
#: An offset step this small is never a fault [m] (round-off of a path's sums).
STEP_FLOOR_M = 1e-6


class PolicyGuard(ForceMotionPolicy):
    """``policy`` as the run sees it, checked call by call against ``limits`` (module docstring)."""

    def __init__(self, policy: ForceMotionPolicy, limits: PolicyLimits) -> None:
        self.policy, self.limits = policy, limits
        self.duration_s = policy.duration_s
        self._last: PolicyPoint | None = None  # the last call's point, at ...
        self._last_t = 0.0  # ... this time [s]
        self._max_speed = limits.max_speed_m_s * (1.0 + SLACK)
        self._max_accel = limits.max_accel_m_s2 * (1.0 + SLACK)
        # the rates may differ from the offsets' mean speed over a tick by what the check allows, and by what an
        # allowed acceleration changes them within the tick (added per call)
        self._agreement = RATE_AGREEMENT * limits.max_speed_m_s + MAX_JOIN_JUMP_M_S

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
        if last is not None and t_s > self._last_t:
            dt = t_s - self._last_t
            step = math.hypot(u - last.u_m, v - last.v_m)
            if step > self._max_speed * dt + STEP_FLOOR_M:
                raise PolicyFault(f"at t = {t_s:.3f} s the policy's offsets moved {1e3 * step:.2f} mm in "
                                  f"{1e3 * dt:.1f} ms ({step / dt:.3f} m/s), over the task's {lim.max_speed_m_s:g} "
                                  "m/s it was checked against")
            change = math.hypot(du - last.du_m_s, dv - last.dv_m_s)
            if change > self._max_accel * dt + MAX_JOIN_JUMP_M_S:
                raise PolicyFault(f"at t = {t_s:.3f} s the policy's rates changed by {change:.3f} m/s in "
                                  f"{1e3 * dt:.1f} ms, over the task's {lim.max_accel_m_s2:g} m/s² it was checked "
                                  "against")
            moved_u, moved_v = (u - last.u_m) / dt, (v - last.v_m) / dt
            gap = math.hypot(moved_u - 0.5 * (du + last.du_m_s), moved_v - 0.5 * (dv + last.dv_m_s))
            if gap > self._agreement + self._max_accel * dt:
                raise PolicyFault(f"at t = {t_s:.3f} s the policy's offsets moved at {moved_u:.3f}, {moved_v:.3f} m/s "
                                  f"while its rates said {du:.3f}, {dv:.3f} m/s: at() must return the rates of its "
                                  "own path")
        self._last, self._last_t = point, t_s
        return point

    def segment_index(self, t_s: float) -> int:
        return self.policy.segment_index(t_s)

    @property
    def segment_starts_s(self) -> tuple[float, ...]:
        return self.policy.segment_starts_s

    @property
    def constant_force_n(self) -> float | None:
        return self.policy.constant_force_n
