"""Where a cleaning run's time goes: contact on dirt, contact on clean surface, transit, vision trips,
touch-downs (issue 21: time to clean is the figure users compare).

The task names what the robot is doing (:data:`ACTIVITIES`); each control tick is added to one
bucket (:data:`BUCKETS`). Contact ticks of the exploration are split by the ground-truth dirt of a
simulation: a window of ticks in which the dirt decreased counts as contact on dirt, one in which it
did not as contact on clean surface. A real robot does not know the dirt; its contact time stays in
``contact``.
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
    """

    def __init__(self, dt_s: float, contact_threshold_n: float, dirt_known: bool) -> None:
        if not (np.isfinite(dt_s) and dt_s > 0):
            raise InputError(f"dt_s must be a positive period [s], got {dt_s!r}")
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

    def seconds(self) -> dict[str, float]:
        """Time per bucket [s]; buckets a run cannot have (contact unsplit in simulation, split on a
        real robot) are left out."""
        ticks = dict(self._ticks)
        if self._pending:  # ticks after the last reading: no evidence of removal
            ticks["contact_clean"] += self._pending
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
