"""Where a cleaning run's time goes: contact on dirt, contact on clean surface, transit, vision trips,
touch-downs (time to clean is the figure users compare with a raster, so the largest share is
what to shorten).

The task names what the robot is doing (:data:`ACTIVITIES`); each control tick is added to one
bucket (:data:`BUCKETS`). Contact ticks of the exploration are split by the ground-truth dirt of a
simulation: a window of ticks in which the dirt decreased counts as contact on dirt, one in which it
did not as contact on clean surface. A real robot does not know the dirt; its contact time stays in
``contact``. The same buckets are also kept up to the first dirt reading at or below ``1 − mark_removed``
(:meth:`TimeBreakdown.seconds_to_mark`): where the time before the 95 % mark went, the part of a run that
its time to 95 % measures.
"""

from __future__ import annotations

import numpy as np

from tactex.errors import InputError

__all__ = ["ACTIVITIES", "BUCKETS", "TimeBreakdown", "time_to_fraction_removed"]

#: What the robot can be doing in the cleaning program.
ACTIVITIES = ("vision", "transit", "touch_down", "explore", "lift_off")
#: The buckets a run's time is split into, in the order they are reported [s each].
BUCKETS = ("contact_dirt", "contact_clean", "contact", "explore_no_contact", "touch_down", "transit", "vision",
           "lift_off")


class TimeBreakdown:
    """Per-tick accounting of the robot's time into :data:`BUCKETS`.

    Args:
        dt_s: control period [s].
        contact_threshold_n: normal force that counts as contact [N].
        dirt_known: the backend reports the true dirt (a simulation); else contact is not split.
        mark_removed: fraction of the dirt removed at which :meth:`seconds_to_mark` is taken, in (0, 1] [-].
    """

    def __init__(self, dt_s: float, contact_threshold_n: float, dirt_known: bool,
                 mark_removed: float = 0.95) -> None:
        if not (np.isfinite(dt_s) and dt_s > 0):
            raise InputError(f"dt_s must be a positive period [s], got {dt_s!r}")
        if not (np.isfinite(mark_removed) and 0.0 < mark_removed <= 1.0):
            raise InputError(f"mark_removed must be a fraction in (0, 1], got {mark_removed!r}")
        self.mark_removed = float(mark_removed)
        self._at_mark: dict[str, int] | None = None
        self.dt = float(dt_s)
        self.threshold = float(contact_threshold_n)
        self.dirt_known = bool(dirt_known)
        self.activity = "vision"
        self._ticks = dict.fromkeys(BUCKETS, 0)
        self._pending = 0  # contact ticks since the last dirt reading
        self._dirt = np.nan  # the last dirt reading [fraction of the initial]

    def set_activity(self, activity: str) -> None:
        if activity not in ACTIVITIES:
            raise InputError(f"unknown activity '{activity}'; valid: {', '.join(ACTIVITIES)}")
        self.activity = activity

    def tick(self, normal_force_n: float) -> None:
        """Account one control period spent on the current activity."""
        if self.activity != "explore":
            self._ticks[self.activity] += 1
        elif normal_force_n >= self.threshold:
            if self.dirt_known:
                self._pending += 1
            else:
                self._ticks["contact"] += 1
        else:
            self._ticks["explore_no_contact"] += 1

    def dirt(self, remaining_fraction: float) -> None:
        """A dirt reading: the contact ticks since the last one were on dirt when it went down."""
        if not self.dirt_known:
            return
        if self._pending:
            removed = np.isfinite(self._dirt) and remaining_fraction < self._dirt
            self._ticks["contact_dirt" if removed else "contact_clean"] += self._pending
            self._pending = 0
        self._dirt = float(remaining_fraction)
        # the same reading and threshold as time_to_fraction_removed on the recorded series
        if self._at_mark is None and self._dirt <= 1.0 - self.mark_removed + 1e-12:
            self._at_mark = dict(self._ticks)

    def seconds(self) -> dict[str, float]:
        """Time per bucket [s]; buckets a run cannot have (contact unsplit in simulation, split on a
        real robot) are left out."""
        ticks = dict(self._ticks)
        if self._pending:  # ticks after the last reading: no evidence of removal
            ticks["contact_clean"] += self._pending
        return self._seconds(ticks)

    def seconds_to_mark(self) -> dict[str, float] | None:
        """:meth:`seconds` up to the first dirt reading at or below ``1 − mark_removed`` (the ticks up to and
        including that reading's), or None when the dirt never got there or is not known."""
        return None if self._at_mark is None else self._seconds(self._at_mark)

    def _seconds(self, ticks: dict[str, int]) -> dict[str, float]:
        skip = {"contact"} if self.dirt_known else {"contact_dirt", "contact_clean"}
        return {k: ticks[k] * self.dt for k in BUCKETS if k not in skip}


def time_to_fraction_removed(t_s: np.ndarray, remaining: np.ndarray, removed_fraction: float = 0.95) -> float | None:
    """First time [s] at which ``1 - remaining`` reaches ``removed_fraction``, or None if it never does."""
    t = np.asarray(t_s, dtype=float).reshape(-1)
    r = np.asarray(remaining, dtype=float).reshape(-1)
    if t.shape != r.shape:
        raise InputError(f"time and dirt series differ in length: {t.shape} vs {r.shape}")
    if not 0.0 < removed_fraction <= 1.0:
        raise InputError(f"removed_fraction must lie in (0, 1], got {removed_fraction}")
    hit = np.flatnonzero(np.isfinite(r) & (r <= 1.0 - removed_fraction + 1e-12))
    return float(t[hit[0]]) if hit.size else None
