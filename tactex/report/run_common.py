"""What every run folder of a closed-loop task shares: the :class:`RunReport` it returns, the metrics
contract, the files every run writes (config, metrics, series, events) and the plotting helpers."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tactex.config import to_jsonable, write_json
from tactex.errors import InputError
from tactex.report.metrics import write_metrics

__all__ = [
    "CLEAN_METRIC_KEYS",
    "WIPE_METRIC_KEYS",
    "RunReport",
    "figure",
    "finite_rows",
    "missing_metric_keys",
    "save_png",
    "series_arrays",
    "start_report",
    "try_plot",
    "write_common_files",
]

#: Keys every ``tactex clean`` metrics.json holds (the metrics contract a study, a sweep and the summary read).
CLEAN_METRIC_KEYS = (
    "dirt_removed_fraction",
    "force_within_20pct_fraction",
    "max_contact_force_n",
    "sim_time_s",
    "vision_updates",
)
#: Keys every ``tactex wipe`` metrics.json holds; motion errors are [x, y, z], tank energies {min, max}.
WIPE_METRIC_KEYS = (
    "force_mae_n",
    "force_rmse_n",
    "motion_mae_m",
    "motion_rmse_m",
    "tank_impedance_energy_j",
    "tank_force_energy_j",
    "explore_time_s",
    "contact_fraction",
)


@dataclass
class RunReport:
    """What :func:`write_run_report` wrote: the folder, the metrics, the files by role, and notes."""

    out_dir: Path
    kind: str
    label: str
    metrics: dict[str, Any]
    files: dict[str, Path] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def html(self) -> Path | None:
        return self.files.get("html")


def missing_metric_keys(kind: str, metrics: Mapping[str, Any]) -> list[str]:
    """Contract keys absent from ``metrics`` (kind 'clean' or 'wipe')."""
    keys = {"clean": CLEAN_METRIC_KEYS, "wipe": WIPE_METRIC_KEYS}.get(kind)
    if keys is None:
        raise InputError(f"unknown run kind '{kind}'; valid: clean, wipe")
    return [k for k in keys if k not in metrics]


def figure(n_rows: int = 1, height: float = 2.4, width: float = 7.5, sharex: bool = True):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height * n_rows + 0.6), dpi=110)
    FigureCanvasAgg(fig)
    axes = fig.subplots(n_rows, 1, sharex=sharex, squeeze=False)[:, 0]
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.ticklabel_format(axis="y", useOffset=False)  # an offset ("+9.999e-1") hides a flat curve
    return fig, axes


def save_png(fig, path: Path) -> Path:
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")
    return path


def series_arrays(result: Any, kind: str, required: Sequence[str]) -> dict[str, np.ndarray]:
    raw = getattr(result, "series", None)
    if not isinstance(raw, Mapping):
        raise InputError(f"{kind} result has no 'series' mapping, got {type(raw).__name__}")
    s = {str(k): np.asarray(v, dtype=np.float64) for k, v in raw.items()}
    missing = [k for k in required if k not in s]
    if missing:
        raise InputError(f"{kind} result series lacks {', '.join(missing)} (has: {', '.join(sorted(s)) or 'nothing'})")
    n = s["t"].shape[0]
    for k in required:
        if s[k].shape[:1] != (n,):
            raise InputError(f"{kind} series '{k}' has shape {s[k].shape}; expected {n} rows like 't'")
    return s


def write_common_files(result: Any, kind: str, out: Path, series: Mapping[str, np.ndarray], rep: RunReport) -> None:
    out.mkdir(parents=True, exist_ok=True)
    rep.files["config"] = write_json(to_jsonable(result.config), out / "config.json")
    rep.files["metrics"] = write_metrics(rep.metrics, out / "metrics.json")
    missing = missing_metric_keys(kind, rep.metrics)
    if missing:
        rep.notes.append(f"metrics lack contract keys: {', '.join(missing)}")
    series_path = out / "series.npz"
    np.savez_compressed(series_path, **{k: np.asarray(v, dtype=np.float64) for k, v in series.items()})
    rep.files["series"] = series_path
    events = [
        dataclasses.asdict(e) if dataclasses.is_dataclass(e) and not isinstance(e, type) else {"event": str(e)}
        for e in (getattr(result, "events", None) or [])
    ]
    rep.files["events"] = write_json(events, out / "events.json")


def finite_rows(path: np.ndarray | None) -> np.ndarray:
    if path is None:
        return np.zeros((0, 3))
    arr = np.asarray(path, dtype=np.float64).reshape(-1, 3)
    return arr[np.isfinite(arr).all(axis=1)]


def try_plot(rep: RunReport, role: str, fn, *args, **kwargs) -> None:
    """A plot that cannot be drawn from this run's data becomes a note, not a lost report."""
    try:
        rep.files[role] = fn(*args, **kwargs)
    except InputError as exc:
        rep.notes.append(f"{role} plot skipped: {exc}")


def start_report(
    result: Any, kind: str, out_dir: str | Path, label: str | None, keys: tuple[str, ...]
) -> tuple[dict[str, np.ndarray], Path, RunReport]:
    """Series, folder and report of a run, with the files every run folder has already written."""
    series = series_arrays(result, kind, keys)
    metrics = dict(result.metrics)
    label = label or str(metrics.get("baseline") or getattr(result.config, "baseline", "") or "tactex")
    out = Path(out_dir)
    rep = RunReport(out_dir=out, kind=kind, label=label, metrics=metrics)
    write_common_files(result, kind, out, series, rep)
    return series, out, rep
