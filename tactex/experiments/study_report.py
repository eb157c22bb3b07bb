"""The outputs of a study: the table (CSV, Parquet), statistics per setting, plots per factor, study.json."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from tactex.config import write_json
from tactex.experiments.study_plots import plot_factors
from tactex.experiments.study_spec import StudyRun, StudySpec, level_label
from tactex.experiments.study_table import (
    MAIN_METRICS,
    is_success,
    t_interval,
    table_rows,
    wilson_interval,
    write_csv,
    write_parquet,
)

__all__ = ["summarize", "write_study_outputs"]

def summarize(spec: StudySpec, records: list[dict[str, Any]], metrics: tuple[str, ...]) -> list[dict[str, Any]]:
    """One row per setting (every factor but the seed), in plan order."""
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


def write_study_outputs(out: Path, spec: StudySpec, runs: list[StudyRun], records: list[dict[str, Any]], *,
                        executor: str, elapsed_s: float) -> tuple[dict[str, Path], list[dict[str, Any]]]:
    """Table (CSV + Parquet), summary (CSV + text), plots and study.json of the finished records."""
    known = {r["run_id"]: r for r in records}
    cols, rows = table_rows(spec, runs, known)
    files = {"table": write_csv(out / "table.csv", cols, rows)}
    notes = []
    parquet, note = write_parquet(out / "table.parquet", cols, rows)
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
        files.update(plot_factors(out, spec, records, metrics))
    n_ok = sum(r["status"] == "ok" for r in records)
    study = {"spec": spec.to_json(), "executor": executor, "elapsed_s": elapsed_s, "runs_planned": len(runs),
             "runs_finished": len(records), "runs_ok": n_ok, "runs_failed": len(records) - n_ok, "notes": notes,
             "summary": summary, "runs": records}
    files["study"] = write_json(study, out / "study.json")
    return files, summary
