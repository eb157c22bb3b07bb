"""``tactex demo``: a short clean of the built-in plate and a short wipe of the sine panel, no files
needed, one run folder with an ``index.html`` linking the runs."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tactex.config import param, write_json
from tactex.errors import ConfigError
from tactex.experiments.run import Note, note_stderr, remark_lines, run_task
from tactex.experiments.run_folder import prepare_out_dir
from tactex.experiments.tasks import baseline_names, task_spec
from tactex.report.run_report import RunReport, summary_table, write_index_html

__all__ = ["DemoConfig", "DemoResult", "run_demo"]


@dataclass(frozen=True)
class DemoConfig:
    """``tactex demo``: short runs of both tasks on built-in objects (budgets tuned for < 3 min wall)."""

    clean_budget_s: float = param(40.0, "simulated time of the short cleaning run on the plate [s]")
    wipe_duration_s: float = param(10.0, "simulated duration of the short wiping run on the sine panel [s]")
    baselines: bool = param(
        False, "also run the baselines (raster, HEDAC without vision; Cartesian impedance): about 2.5× longer"
    )
    quick: bool = param(False, "a smoke run: a quarter of the budgets, no baselines")
    video: bool = param(True, "write replay videos when GL rendering works")
    seed: int = param(0, "seed of the simulations and the explorer")

    def __post_init__(self) -> None:
        for name in ("clean_budget_s", "wipe_duration_s"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be a positive number of seconds, got {getattr(self, name)!r}")

    def task_configs(self) -> dict[str, Any]:
        """The CleanConfig and WipeConfig of the demo."""
        scale = 0.25 if self.quick else 1.0
        clean = task_spec("clean").config_cls(object_name="plate", marking="X", budget_s=scale * self.clean_budget_s,
                                              seed=self.seed)
        wipe = task_spec("wipe").config_cls(duration_s=scale * self.wipe_duration_s, seed=self.seed)
        return {"clean": clean, "wipe": wipe}


@dataclass
class DemoResult:
    """The demo's run folder, its index page, the reports per task and the terminal summary."""

    out_dir: Path
    index: Path
    reports: dict[str, list[RunReport]] = field(default_factory=dict)
    wall_time_s: float = 0.0

    def summary(self) -> str:
        """The tables of the runs per task, then the runs' remarks (the safety layer, the alignment transient)."""
        tables = {k: summary_table([(r.label, r.metrics) for r in reps]) for k, reps in self.reports.items() if reps}
        text = "\n\n".join(f"{kind}:\n{table}" for kind, table in tables.items())
        remarks = remark_lines([(f"{kind} {r.label}", r.metrics) for kind, reps in self.reports.items() for r in reps])
        return "\n\n".join([text, "\n".join(remarks)]) if remarks else text


def run_demo(out_dir: str | Path = "runs/demo", config: DemoConfig | None = None, *, progress: bool = True,
             note: Note | None = note_stderr) -> DemoResult:
    """Short clean + short wipe (+ baselines) into ``out_dir/<task>/<run>``, with ``out_dir/index.html``."""
    cfg = config or DemoConfig()
    out = prepare_out_dir(out_dir)
    wall0 = time.perf_counter()
    configs = cfg.task_configs()
    plan = [(kind, b) for kind in ("clean", "wipe")
            for b in ("", *(baseline_names(kind) if cfg.baselines and not cfg.quick else ()))]
    reports: dict[str, list[RunReport]] = {"clean": [], "wipe": []}
    for i, (kind, b) in enumerate(plan, 1):
        label = b or "tactex"
        if note is not None:
            note(f"demo [{i}/{len(plan)}] {kind} {label}")
        task_cfg = dataclasses.replace(configs[kind], baseline=b)
        reports[kind].append(run_task(kind, task_cfg, out / kind / label, label=label, progress=progress,
                                      video=cfg.video, note=note))
    all_reports = [r for reps in reports.values() for r in reps]
    index = write_index_html(out / "index.html", all_reports, title="tactex demo")
    result = DemoResult(out_dir=out, index=index, reports=reports, wall_time_s=time.perf_counter() - wall0)
    write_json({"demo": cfg, "tasks": configs}, out / "config.json")
    (out / "summary.txt").write_text(result.summary() + "\n")
    return result
