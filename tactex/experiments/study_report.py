"""The outputs of a study: the table (CSV, Parquet), statistics per setting, plots per factor, study.json."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from tactex.config import write_json
from tactex.experiments.study_spec import StudyRun, StudySpec, level_label

__all__ = ["summarize", "t_interval", "wilson_interval", "write_csv", "write_study_outputs"]

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


def summarize(spec: StudySpec, records: list[dict[str, Any]], metrics: tuple[str, ...]) -> list[dict[str, Any]]:
    """One row per setting (every factor but the seed), in plan order."""
    from tactex.experiments.study import is_success

    keys = [f for f in spec.factors if f != "seed"]
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for rec in records:
        groups.setdefault(tuple(rec["factors"][k] for k in keys), []).append(rec)
    rows = []
    for values, recs in groups.items():
        ok = [r for r in recs if r["status"] == "ok"]
        wins = sum(is_success(r, spec) for r in recs)
        lo, hi = wilson_interval(wins, len(recs))
        row: dict[str, Any] = {**dict(zip(keys, values, strict=True)), "runs": len(recs),
                               "failed": len(recs) - len(ok), "success_rate": wins / len(recs),
                               "success_ci_low": lo, "success_ci_high": hi}
        for m in metrics:
            vals = np.array([r["metrics"].get(m) for r in ok if isinstance(r["metrics"].get(m), (int, float))],
                            dtype=np.float64)
            mean, std, half = t_interval(vals)
            row.update({f"{m}_mean": mean, f"{m}_std": std, f"{m}_ci95": half})
        rows.append(row)
    return rows


def _summary_text(spec: StudySpec, rows: list[dict[str, Any]], metrics: tuple[str, ...]) -> str:
    keys = [f for f in spec.factors if f != "seed"]
    head = [*keys, "runs", "failed", "success [95% CI]", *(f"{m} (mean ± ci95)" for m in metrics)]
    body = []
    for r in rows:
        cells = [level_label(k, r[k]) for k in keys]
        cells += [str(r["runs"]), str(r["failed"]),
                  f"{r['success_rate']:.2f} [{r['success_ci_low']:.2f}, {r['success_ci_high']:.2f}]"]
        for m in metrics:
            mean, half = r[f"{m}_mean"], r[f"{m}_ci95"]
            cells.append("-" if math.isnan(mean) else f"{mean:.3g}" + ("" if math.isnan(half) else f" ± {half:.2g}"))
        body.append(cells)
    widths = [max(len(h), *(len(b[i]) for b in body)) if body else len(h) for i, h in enumerate(head)]
    line = lambda cells: "  ".join(c.ljust(w) for c, w in zip(cells, widths, strict=True))  # noqa: E731
    return "\n".join([line(head), line(["-" * w for w in widths]), *(line(b) for b in body)])


def _csv_value(v: Any) -> str:
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
            w.writerow([_csv_value(v) for v in row])
    tmp.replace(path)
    return path


def _write_parquet(path: Path, cols: list[str], rows: list[list[Any]]) -> tuple[Path | None, str]:
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


def write_study_outputs(out: Path, spec: StudySpec, runs: list[StudyRun], records: list[dict[str, Any]], *,
                        executor: str, elapsed_s: float) -> tuple[dict[str, Path], list[dict[str, Any]]]:
    """Table (CSV + Parquet), summary (CSV + text), plots and study.json of the finished records."""
    from tactex.experiments.study import MAIN_METRICS, table_rows

    known = {r["run_id"]: r for r in records}
    cols, rows = table_rows(spec, runs, known)
    files = {"table": write_csv(out / "table.csv", cols, rows)}
    notes = []
    parquet, note = _write_parquet(out / "table.parquet", cols, rows)
    if parquet is not None:
        files["parquet"] = parquet
    if note:
        notes.append(note)
    metrics = MAIN_METRICS[spec.task]
    summary = summarize(spec, records, metrics)
    if summary:
        scols = list(summary[0])
        files["summary"] = write_csv(out / "summary.csv", scols, [[r[c] for c in scols] for r in summary])
        text = _summary_text(spec, summary, metrics)
        (out / "summary.txt").write_text(text + "\n")
        files["summary_text"] = out / "summary.txt"
        from tactex.experiments.study_plots import plot_factors

        files.update(plot_factors(out, spec, records, metrics))
    n_ok = sum(r["status"] == "ok" for r in records)
    study = {"spec": spec.to_json(), "executor": executor, "elapsed_s": elapsed_s, "runs_planned": len(runs),
             "runs_finished": len(records), "runs_ok": n_ok, "runs_failed": len(records) - n_ok, "notes": notes,
             "summary": summary, "runs": records}
    files["study"] = write_json(study, out / "study.json")
    return files, summary
