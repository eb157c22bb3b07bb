"""``zigzag``: a raster patch. ``lanes`` strokes of ``width_m`` [m] along the tool's x axis, back and
forth, stepping ``length_m / (lanes − 1)`` along the tool's −y between them; the tool stops at each
corner (minimum-jerk legs), so no corner is a velocity jump."""

from __future__ import annotations

from tactex.errors import ConfigError
from tactex.tasks.policies.base import ForceRamp, PolicySegment
from tactex.tasks.policies.timing import polyline_at

__all__ = ["ZigzagPolicy"]


class ZigzagPolicy(PolicySegment):
    kind = "zigzag"
    fields = ("width_m", "length_m", "lanes")

    def __init__(self, duration_s: float, force: ForceRamp, width_m: float, length_m: float, lanes: int) -> None:
        super().__init__(duration_s, force)
        if isinstance(lanes, bool) or not isinstance(lanes, int) or lanes < 1:
            raise ConfigError(f"zigzag: lanes must be a whole number ≥ 1, got {lanes!r}")
        self.width_m, self.length_m, self.lanes = width_m, length_m, lanes
        step = length_m / (lanes - 1) if lanes > 1 else 0.0
        pts = [(0.0, 0.0)]
        for k in range(lanes):
            x_end = width_m if k % 2 == 0 else 0.0
            pts.append((x_end, -k * step))
            if k < lanes - 1:
                pts.append((x_end, -(k + 1) * step))
        self.corners = pts

    def path(self, t_s: float) -> tuple[float, float, float, float]:
        return polyline_at(self.corners, self.duration_s, t_s)
