"""``circle``: ``turns`` turns of a circle of ``radius_m`` [m] through the start, its centre ``radius_m``
along the tool's −y (the §III sinusoid's circle without the drift), timed by a minimum-jerk ramp of
the angle (it starts and ends at rest)."""

from __future__ import annotations

import math

from tactex.tasks.policies.base import ForceRamp, PolicySegment
from tactex.tasks.policies.timing import min_jerk

__all__ = ["CirclePolicy"]


class CirclePolicy(PolicySegment):
    kind = "circle"
    fields = ("radius_m", "turns")

    def __init__(self, duration_s: float, force: ForceRamp, radius_m: float, turns: float = 1.0) -> None:
        super().__init__(duration_s, force)
        self.radius_m, self.turns = radius_m, turns
        self._theta_end = 2.0 * math.pi * turns

    def path(self, t_s: float) -> tuple[float, float, float, float]:
        s, ds = min_jerk(t_s / self.duration_s)
        theta, dtheta = self._theta_end * s, self._theta_end * ds / self.duration_s
        r = self.radius_m
        return (r * math.sin(theta), r * (math.cos(theta) - 1.0),
                r * dtheta * math.cos(theta), -r * dtheta * math.sin(theta))
