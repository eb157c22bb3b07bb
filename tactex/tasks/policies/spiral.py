"""``spiral``: an Archimedean spiral out from the start, r = radius_m · θ / (2π turns), θ from 0 to
2π turns, timed by a minimum-jerk ramp of θ (it starts and ends at rest)."""

from __future__ import annotations

import math

from tactex.tasks.policies.base import ForceRamp, PolicySegment
from tactex.tasks.policies.timing import min_jerk

__all__ = ["SpiralPolicy"]


class SpiralPolicy(PolicySegment):
    kind = "spiral"
    fields = ("radius_m", "turns")

    def __init__(self, duration_s: float, force: ForceRamp, radius_m: float, turns: float) -> None:
        super().__init__(duration_s, force)
        self.radius_m, self.turns = radius_m, turns
        self._theta_end = 2.0 * math.pi * turns

    def path(self, t_s: float) -> tuple[float, float, float, float]:
        s, ds = min_jerk(t_s / self.duration_s)
        theta, dtheta = self._theta_end * s, self._theta_end * ds / self.duration_s
        dr = self.radius_m / self._theta_end if self._theta_end else 0.0  # dr/dθ [m/rad]
        r = dr * theta
        c, sn = math.cos(theta), math.sin(theta)
        return r * c, r * sn, dtheta * (dr * c - r * sn), dtheta * (dr * sn + r * c)
