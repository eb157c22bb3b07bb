"""``line``: a straight stroke of ``length_m`` [m] at ``direction_deg`` [deg] from the tool's x axis
towards its y axis, from rest to rest (a minimum-jerk ramp)."""

from __future__ import annotations

import math

from tactex.tasks.policies.base import ForceRamp, PolicySegment
from tactex.tasks.policies.timing import min_jerk

__all__ = ["LinePolicy"]


class LinePolicy(PolicySegment):
    kind = "line"
    fields = ("length_m", "direction_deg")

    def __init__(self, duration_s: float, force: ForceRamp, length_m: float, direction_deg: float = 0.0) -> None:
        super().__init__(duration_s, force)
        self.length_m, self.direction_deg = length_m, direction_deg
        a = math.radians(direction_deg)
        self._dx, self._dy = length_m * math.cos(a), length_m * math.sin(a)

    def path(self, t_s: float) -> tuple[float, float, float, float]:
        s, ds = min_jerk(t_s / self.duration_s)
        return s * self._dx, s * self._dy, ds * self._dx / self.duration_s, ds * self._dy / self.duration_s
