"""`tactex study`: many closed-loop runs (clean, wipe) over a grid and/or random draws, with statistics.

Each run is :func:`run_study_task`: the task's config from the plan (:mod:`.study_spec`), run in
simulation without progress bars, its metrics returned. Runs go through an
:class:`~tactex.experiments.executor.Executor` (local processes or Ray) and the study folder holds

- ``runs.jsonl`` — one line per finished run, appended the moment it finishes (config, metrics,
  error and traceback of a run that raised, where and how long it ran, and ``attempt``: how many
  earlier starts were lost with their worker process or node); a re-run of the same
  study into the same folder skips the runs found here (``retry_failed`` re-runs those that failed);
- ``table.csv`` (and ``table.parquet`` when pyarrow is installed) — one row per run in plan order:
  factors, status, error, and the scalar metrics, rewritten after every finished run. Wall-clock
  times are not in the table (they are in ``runs.jsonl``/``study.json``), so the table is the same
  bit for bit whichever executor ran the study, and in whatever order;
- ``summary.csv`` / ``summary.txt`` — per setting (the factors but the seed): runs, failures,
  success rate with a 95 % Wilson interval, and mean, standard deviation and 95 % t-interval of
  the main metrics;
- ``study.json`` — the spec, the executor, the counts, the summary and every run's record;
- ``factor_<name>.png`` — per factor, the success rate and the main metrics' distributions.
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tactex.config import to_jsonable, write_json
from tactex.errors import ConfigError, RunInterrupted
from tactex.experiments.executor import Executor, LocalExecutor
from tactex.experiments.run_folder import prepare_out_dir
from tactex.experiments.study_files import pack_files
from tactex.experiments.study_report import write_study_outputs
from tactex.experiments.study_spec import StudyRun, StudySpec, level_label
from tactex.experiments.study_table import table_rows, write_csv

__all__ = ["StudyResult", "check_same_study", "run_study", "run_study_task"]

Say = Callable[[str], None]


def run_study_task(task: dict[str, Any], shared: Any = None) -> dict[str, Any]:
    """One study run (executed by a worker): ``task = {"task": "clean", "config": {...}}`` → the
    run's metrics as JSON values. A pure function of the config and of the input files it names,
    which come in ``shared`` (:mod:`.study_files`: the worker's machine need not have them); no
    progress bar."""
    from tactex.experiments.study_files import local_config
    from tactex.experiments.tasks import task_spec
    from tactex.tasks.robot import stopped_by_user

    spec = task_spec(task["task"])
    cfg = spec.config_cls(**local_config(task["config"], shared))
    result = spec.run(cfg, progress=False)
    if stopped_by_user(result.metrics):
        # the task's loop keeps a run Ctrl-C cut short as its own; here it must stop the study instead
        # of being recorded as a finished run (which a resumed study would then skip)
        raise KeyboardInterrupt
    return to_jsonable(result.metrics)


@dataclass
class StudyResult:
    """A finished (or interrupted) study: its folder, its records in plan order, the summary rows."""

    out_dir: Path
    records: list[dict[str, Any]]
    summary: list[dict[str, Any]]
    files: dict[str, Path] = field(default_factory=dict)
    skipped: int = 0

    @property
    def failed(self) -> list[dict[str, Any]]:
        return [r for r in self.records if r["status"] != "ok"]


# -- records ---------------------------------------------------------------------------------------------
def _read_records(path: Path) -> dict[str, dict[str, Any]]:
    """The finished runs of ``runs.jsonl`` by run id (a line cut short by a crash is ignored)."""
    records: dict[str, dict[str, Any]] = {}
    if not path.is_file():
        return records
    for line in path.read_text().splitlines():
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(rec, dict) and "run_id" in rec:
            records[rec["run_id"]] = rec
    return records


def check_same_study(spec: StudySpec, out_dir: str | Path) -> None:
    """Refuse (:class:`ConfigError`) to run ``spec`` into ``out_dir`` when the study recorded there is another:
    another task, or runs of which none is in ``spec``'s plan (its table would mix the two). A study resumed,
    or given more seeds or levels, shares runs with it and passes."""
    out = Path(out_dir)
    known = _read_records(out / "runs.jsonl")
    if not known:
        return
    tasks = sorted({str(rec.get("task", "")) for rec in known.values()})
    planned = {run.run_id for run in spec.runs()}
    other = tasks != [spec.task] or not planned & set(known)
    if other:
        raise ConfigError(f"--out {out} holds another study ({len(known)} {'/'.join(tasks)} runs, none of this "
                          f"{spec.task} study's plan): give another --out, or --force to record these runs beside "
                          "them")


def _append_record(path: Path, rec: dict[str, Any]) -> None:
    with path.open("a") as f:
        f.write(json.dumps(to_jsonable(rec)) + "\n")  # key order kept: it is the column order of the table
        f.flush()
        os.fsync(f.fileno())


# -- the driver ------------------------------------------------------------------------------------------
class _Progress:
    """``study: 12/270 done, 1 failed, 2 running, 3.1 runs/min, ETA 14 min`` after every finished run."""

    def __init__(self, total: int, skipped: int, say: Say | None) -> None:
        self.total, self.skipped, self.say = total, skipped, say
        self.done = self.failed = 0
        self.t0 = time.perf_counter()

    def line(self, running: int, last: str) -> None:
        self.done += 1
        if self.say is None:
            return
        elapsed = time.perf_counter() - self.t0
        rate = self.done / elapsed * 60.0 if elapsed > 0 else 0.0
        left = self.total - self.skipped - self.done
        eta = f"ETA {_minutes(left / rate * 60.0)}" if rate > 0 and left else "ETA -"
        self.say(f"[{self.skipped + self.done}/{self.total}] done, {self.failed} failed, {running} running, "
                 f"{rate:.1f} runs/min, {eta} | {last}")


def _minutes(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.0f} min" if seconds < 5400 else \
        f"{seconds / 3600:.1f} h"


def run_study(spec: StudySpec, out_dir: str | Path, executor: Executor | None = None, *,
              retry_failed: bool = False, progress: Say | None = None) -> StudyResult:
    """Run every run of ``spec`` not yet in ``out_dir/runs.jsonl``, then write the table, the
    summary, the plots and ``study.json``. Ctrl-C stops the runs and raises
    :class:`~tactex.errors.RunInterrupted` once those files are written (what finished stays recorded: run the
    same study again to go on)."""
    out = prepare_out_dir(out_dir)
    runs = spec.runs()
    if not runs:
        raise ConfigError("the study has no runs")
    jsonl = out / "runs.jsonl"
    known = _read_records(jsonl)
    todo = [r for r in runs if r.run_id not in known or (retry_failed and known[r.run_id]["status"] != "ok")]
    skipped = len(runs) - len(todo)
    say = progress or (lambda msg: None)
    write_json({"spec": spec.to_json(), "runs_planned": len(runs)}, out / "study_spec.json")
    ex = executor if executor is not None else LocalExecutor(0)
    if skipped:
        say(f"{skipped} of {len(runs)} runs already in {jsonl.name}; running the other {len(todo)}")
    say(f"{len(todo)} {spec.task} runs on {ex.describe()}")
    bar = _Progress(len(runs), skipped, progress)
    tasks = [{"task": spec.task, "config": r.config} for r in todo]
    inputs = pack_files(t["config"] for t in tasks)  # the input files the runs name, sent with them
    t0 = time.perf_counter()
    interrupted = False
    try:
        for outcome in ex.run(run_study_task, tasks, inputs):
            run = todo[outcome.index]
            rec = _record(spec, run, outcome)
            known[run.run_id] = rec
            _append_record(jsonl, rec)
            if not outcome.ok:
                bar.failed += 1
            label = ", ".join(f"{k}={level_label(k, v)}" for k, v in run.factors.items())
            value = rec["metrics"].get(spec.success_metric) if outcome.ok else None
            what = (f"FAILED {outcome.error[:120]}" if not outcome.ok else
                    f"{spec.success_metric} {value:.3g}" if isinstance(value, (int, float)) else
                    f"{spec.success_metric} -")
            bar.line(ex.running, f"{label}: {what}")
            _write_table(out, spec, runs, known)  # the table so far: a crash loses nothing finished
    except KeyboardInterrupt:
        interrupted = True
    finally:
        if executor is None:
            ex.close()
    records = [known[r.run_id] for r in runs if r.run_id in known]
    files, summary = write_study_outputs(out, spec, runs, records, executor=ex.describe(),
                                         elapsed_s=time.perf_counter() - t0)
    result = StudyResult(out_dir=out, records=records, summary=summary, files=files, skipped=skipped)
    if interrupted:
        raise RunInterrupted(f"{bar.done} runs finished in this session, {len(records)} in all, are recorded in "
                             f"{jsonl}; run the same study again to go on")
    return result


def _record(spec: StudySpec, run: StudyRun, outcome) -> dict[str, Any]:
    metrics = outcome.value if outcome.ok else {}
    return {"run_id": run.run_id, "index": run.index, "task": spec.task, "factors": run.factors,
            "config": run.config, "status": "ok" if outcome.ok else "failed", "error": outcome.error,
            "traceback": outcome.traceback, "metrics": metrics, "worker": outcome.worker,
            "seconds": outcome.seconds, "attempt": outcome.attempt}


def _write_table(out: Path, spec: StudySpec, runs: list[StudyRun], known: dict[str, dict[str, Any]]) -> Path:
    return write_csv(out / "table.csv", *table_rows(spec, runs, known))


def print_to_stderr(prefix: str) -> Say:
    def say(msg: str) -> None:
        print(f"{prefix}: {msg}", file=sys.stderr, flush=True)

    return say
