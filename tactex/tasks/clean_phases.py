"""The cleaning program's phases as recorded in its time series: the task writes these codes and
the clean report reads them back (TEC §V-A: move, capture the view, approach, explore, retract)."""

from __future__ import annotations

__all__ = ["CLEAN_PHASES"]

#: Phase name → the code recorded in the series' ``phase`` column.
CLEAN_PHASES = {"move": 0, "capture": 1, "approach": 2, "explore": 3, "retract": 4}
