"""The physical bound of one clean: the least time any method with this robot, pad and camera could take.

It counts what no method avoids: the first capture (every method needs the camera's dirt), the quickest
joint move from the capture posture to the hover over any dirty point and the fall from the hover to the
surface at the approach speed, and the sliding: the dirty area wiped once in stripes of the pad's
effective width at the sliding speed (:func:`tactex.tasks.ideal_time.ideal_time_s`). No turn, no overlap,
no second look, no lift-off is counted, so every real method takes longer; a method's time to 95 % over it
says how far that method is from the physics.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from tactex.pointcloud.cloud import SurfaceCloud
from tactex.tasks.ideal_time import dirty_area_m2, ideal_time_s

__all__ = ["CleanBound"]


@dataclass(frozen=True)
class CleanBound:
    """One clean's bound and its parts.

    Attributes:
        dirty_area_m2: the captured dirt's area [m²] (:func:`tactex.tasks.ideal_time.dirty_area_m2`).
        pad_effective_width_m: the stripe one pass of the pad wipes clean [m]: the lanes' spacing, which both
            the explorer's footprints and the rasters keep.
        speed_m_s: the sliding speed [m/s]: the agent's step over the step's duration.
        capture_s: robot time up to the end of the first capture [s].
        transit_s: the quickest joint move from the capture posture to a hover over dirt [s] (0 when no
            hover was planned).
        touch_down_s: the fall from the hover height at the approach speed [s].
    """

    dirty_area_m2: float
    pad_effective_width_m: float
    speed_m_s: float
    capture_s: float
    transit_s: float
    touch_down_s: float

    @classmethod
    def of(cls, cfg: Any, dirt: SurfaceCloud, capture_s: float, transit_s: float) -> CleanBound:
        """The bound of a clean with ``cfg`` (a :class:`~tactex.tasks.clean.config.CleanConfig`) on the captured
        ``dirt`` (its target: the dirt the methods are asked to clean), ``capture_s`` [s] into the run at the
        end of the capture and ``transit_s`` [s] from the capture posture to the quickest hover over dirt."""
        return cls(dirty_area_m2=dirty_area_m2(dirt), pad_effective_width_m=cfg.lane_spacing_m,
                   speed_m_s=cfg.max_velocity * dirt.spacing * cfg.explorer_rate_hz, capture_s=capture_s,
                   transit_s=transit_s, touch_down_s=cfg.hover_height_m / cfg.approach_speed_m_s)

    @property
    def sliding_s(self) -> float:
        """The area over the stripe's width and speed [s]."""
        return ideal_time_s(self.dirty_area_m2, self.pad_effective_width_m, self.speed_m_s)

    @property
    def time_s(self) -> float:
        """The bound [s]: capture, transit, touch-down and sliding."""
        return ideal_time_s(self.dirty_area_m2, self.pad_effective_width_m, self.speed_m_s,
                            self.capture_s + self.transit_s + self.touch_down_s)

    def parts_s(self) -> dict[str, float]:
        """The bound's parts [s], for ``metrics.json``."""
        return {"capture": self.capture_s, "transit": self.transit_s, "touch_down": self.touch_down_s,
                "sliding": self.sliding_s}
