"""Run folders of the closed-loop tasks: parameters, metrics, time series, plots and one HTML page.

``write_run_report(result, out_dir)`` takes a cleaning result (TEC §V-A) or a wiping result
(VA-UFIC §III) and writes

- ``config.json`` — the exact parameters of the run,
- ``metrics.json`` — the metrics contract (:data:`CLEAN_METRIC_KEYS` / :data:`WIPE_METRIC_KEYS`) and more,
- ``series.npz`` — the 100 Hz time series (plain arrays, no pickle) and ``cloud.npz`` — points and fields,
- ``explored.ply`` (wipe) — the explored contact points with normals and curvature, which
  ``tactex explore`` loads,
- ``events.json`` — safety events,
- PNG plots (clean: dirt, force band, phases, time breakdown, cloud fields, ergodicity; wipe: VA-UFIC Fig. 2 and 3a–d,
  explored curvature),
- ``report.html`` — an interactive 3-D view of the cloud (inline plotly, works offline) with the
  metrics and the PNGs embedded.

:func:`summary_table` prints tactex beside its baselines in the terminal; :func:`write_index_html`
links several run folders from one page.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tactex.errors import InputError
from tactex.report.clean_report import (
    DIRT_CMAP,
    DIRT_COLORSCALE,
    TIME_BUCKETS,
    contact_stretches,
    trips_with_a_view,
    vision_round_trips,
    write_clean_report,
)
from tactex.report.run_common import CLEAN_METRIC_KEYS, WIPE_METRIC_KEYS, RunReport, missing_metric_keys
from tactex.report.run_pages import (
    SUMMARY_COLUMNS,
    alignment_summary,
    run_remarks,
    safety_summary,
    summary_table,
    write_index_html,
)
from tactex.report.wipe_report import CURVATURE_COLORSCALE, DEFAULT_TANK_LIMITS, write_wipe_report
from tactex.tasks.clean_phases import CLEAN_PHASES

__all__ = [
    "CLEAN_METRIC_KEYS",
    "CLEAN_PHASES",
    "CURVATURE_COLORSCALE",
    "DEFAULT_TANK_LIMITS",
    "DIRT_CMAP",
    "DIRT_COLORSCALE",
    "SUMMARY_COLUMNS",
    "TIME_BUCKETS",
    "WIPE_METRIC_KEYS",
    "RunReport",
    "alignment_summary",
    "contact_stretches",
    "missing_metric_keys",
    "run_kind",
    "run_remarks",
    "safety_summary",
    "summary_table",
    "trips_with_a_view",
    "vision_round_trips",
    "write_clean_report",
    "write_index_html",
    "write_run_report",
    "write_wipe_report",
]


def run_kind(result: Any) -> str:
    """'clean' or 'wipe', from the fields the result carries."""
    if hasattr(result, "profile") and hasattr(result, "explored"):
        return "wipe"
    if hasattr(result, "fields") and hasattr(result, "agent_path"):
        return "clean"
    raise InputError(
        f"cannot report a {type(result).__name__}: expected a CleanResult (fields, agent_path) "
        "or a WipeResult (profile, explored)"
    )


def write_run_report(
    result: Any, out_dir: str | Path, *, label: str | None = None, html_page: bool = True
) -> RunReport:
    """Write the run folder of a cleaning or wiping result (see the module docstring)."""
    if run_kind(result) == "clean":
        return write_clean_report(result, out_dir, label=label, html_page=html_page)
    return write_wipe_report(result, out_dir, label=label, html_page=html_page)
