"""``figure8``: u = (width_m / 2) sin θ, v = (height_m / 2) sin 2θ, crossing itself at the start, θ
from 0 to 2π ``turns`` timed by a minimum-jerk ramp (it starts and ends at rest)."""

from __future__ import annotations

import math

from tactex.tasks.policies.base import ForceRamp, PolicySegment
from tactex.tasks.policies.timing import min_jerk

__all__ = ["Figure8Policy"]


class Figure8Policy(PolicySegment):
    kind = "figure8"
    fields = ("width_m", "height_m", "turns")

    def __init__(self, duration_s: float, force: ForceRamp, width_m: float, height_m: float,
                 turns: float = 1.0) -> None:
        super().__init__(duration_s, force)
        self.width_m, self.height_m, self.turns = width_m, height_m, turns
        self._theta_end = 2.0 * math.pi * turns

    def path(self, t_s: float) -> tuple[float, float, float, float]:
        s, ds = min_jerk(t_s / self.duration_s)
        th, dth = self._theta_end * s, self._theta_end * ds / self.duration_s
        a, b = self.width_m / 2.0, self.height_m / 2.0
        return a * math.sin(th), b * math.sin(2 * th), a * dth * math.cos(th), 2 * b * dth * math.cos(2 * th)
