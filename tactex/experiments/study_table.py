"""The study table: one row per finished run (factors, status, success and the scalar metrics), its
CSV and Parquet files, and the statistics of its columns. The runner rewrites the table after
every run; the report and the plots read the same rows, so all three share this module.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from tactex.experiments.study_spec import StudyRun, StudySpec

__all__ = [
    "CONFIDENCE",
    "MAIN_METRICS",
    "PER_AXIS_METRICS",
    "WALL_CLOCK_METRICS",
    "flat_scalars",
    "is_success",
    "t_interval",
    "table_rows",
    "wilson_interval",
    "write_csv",
    "write_parquet",
]

#: Metrics measured on the wall clock: in ``runs.jsonl`` and ``study.json``, never in the table.
WALL_CLOCK_METRICS = ("wall_time_s", "basis_time_s", "start_plan_time_s")
#: Metrics the summary and the plots describe, per task.
MAIN_METRICS = {
    "clean": ("dirt_removed_fraction", "force_within_20pct_fraction", "max_contact_force_n", "sim_time_s",
              "agent_path_length_m"),
    "wipe": ("force_rmse_n", "force_mae_n", "contact_fraction_after_first_contact", "max_force_n"),
}
#: Metrics given per axis of the base frame as [x, y, z]: columns ``name.x``, ``name.y``, ``name.z``.
PER_AXIS_METRICS = ("motion_mae_m", "motion_rmse_m", "motion_mae_tool_m", "motion_rmse_tool_m",
                    "motion_mae_tangent_m", "motion_rmse_tangent_m", "motion_mae_all_contact_m",
                    "motion_rmse_all_contact_m")
#: Confidence level of the intervals in the summary.
CONFIDENCE = 0.95


def wilson_interval(successes: int, n: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Wilson score interval of a success rate (sound at 0 and n successes, unlike mean ± z·se)."""
    if n == 0:
        return (math.nan, math.nan)
    from scipy.stats import norm

    z = float(norm.ppf(0.5 + confidence / 2))
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (max(0.0, centre - half), min(1.0, centre + half))


def t_interval(values: np.ndarray, confidence: float = CONFIDENCE) -> tuple[float, float, float]:
    """Mean, sample standard deviation and the half-width of the Student-t interval of the mean."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return (math.nan, math.nan, math.nan)
    if v.size == 1:
        return (float(v[0]), math.nan, math.nan)
    from scipy.stats import t

    std = float(v.std(ddof=1))
    return (float(v.mean()), std, float(t.ppf(0.5 + confidence / 2, v.size - 1)) * std / math.sqrt(v.size))


def flat_scalars(metrics: dict[str, Any]) -> dict[str, Any]:
    """The table's metric columns: scalars, dicts as ``name.key`` (nested ones too, e.g. a re-planned wipe's
    ``replan.first_pass.force_mae_n``), per-axis metrics as ``name.x/y/z``; other lists (time series) stay in
    ``runs.jsonl``."""
    out: dict[str, Any] = {}
    for k, v in metrics.items():
        if k in WALL_CLOCK_METRICS:
            continue
        if k in PER_AXIS_METRICS and isinstance(v, list) and len(v) == 3:
            out.update({f"{k}.{axis}": x for axis, x in zip("xyz", v, strict=True)})
        elif isinstance(v, dict):
            out.update({f"{k}.{kk}": vv for kk, vv in flat_scalars(v).items()})
        elif v is None or isinstance(v, (bool, int, float, str)):
            out[k] = v
    return out


def is_success(rec: dict[str, Any], spec: StudySpec) -> bool:
    """A run succeeds when it finished, did not abort, and its success metric reaches the threshold."""
    if rec["status"] != "ok":
        return False
    m = rec.get("metrics") or {}
    value = m.get(spec.success_metric)
    return not m.get("aborted") and isinstance(value, (int, float)) and value >= spec.success_at_least


def table_rows(spec: StudySpec, runs: list[StudyRun], known: dict[str, dict[str, Any]]) -> tuple[list[str], list]:
    """Columns and rows (plan order, finished runs only) of the study table."""
    recs = [known[r.run_id] for r in runs if r.run_id in known]
    metric_cols: list[str] = []
    for rec in recs:
        for k in flat_scalars(rec.get("metrics") or {}):
            if k not in metric_cols:
                metric_cols.append(k)
    metric_cols = [c for c in metric_cols if c not in spec.factors]
    cols = ["run", "run_id", *spec.factors, "status", "success", "error", *metric_cols]
    rows = []
    for rec in recs:
        flat = flat_scalars(rec.get("metrics") or {})
        rows.append([rec["index"], rec["run_id"], *(rec["factors"][f] for f in spec.factors), rec["status"],
                     is_success(rec, spec), rec["error"].splitlines()[0][:300] if rec["error"] else "",
                     *(flat.get(c) for c in metric_cols)])
    return cols, rows


def csv_value(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ""  # repr: the shortest text that reads back to the same float
    return str(v)


def write_csv(path: Path, cols: list[str], rows: list[list[Any]]) -> Path:
    """Written to a temporary file and renamed: a reader never sees half a table."""
    import csv

    tmp = path.with_name(f".{path.name}.tmp")
    with tmp.open("w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(cols)
        for row in rows:
            w.writerow([csv_value(v) for v in row])
    tmp.replace(path)
    return path


def write_parquet(path: Path, cols: list[str], rows: list[list[Any]]) -> tuple[Path | None, str]:
    """``table.parquet`` with pyarrow when it is installed (it comes with the distributed extra)."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return None, "table.parquet skipped: pyarrow is not installed (pip install 'tactex[distributed]')"
    data = {}
    for j, c in enumerate(cols):
        column = [row[j] for row in rows]
        kinds = {type(v) for v in column if v is not None}
        if kinds == {int, float} or kinds == {float}:
            column = [None if v is None or (isinstance(v, float) and not math.isfinite(v)) else float(v)
                      for v in column]
        elif len(kinds) > 1:
            column = [None if v is None else str(v) for v in column]
        data[c] = column
    try:
        pq.write_table(pa.table(data), path)
    except (pa.ArrowInvalid, pa.ArrowTypeError) as exc:
        return None, f"table.parquet skipped: {exc}"
    return path, ""
