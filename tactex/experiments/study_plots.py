"""Plots of a study, one figure per factor: success rate (Wilson 95 % interval) and the main
metrics' distributions at each level (box plots; a scatter for a randomly drawn factor)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from tactex.experiments.study_spec import StudySpec, level_label
from tactex.experiments.study_table import is_success, wilson_interval

__all__ = ["plot_factors"]


def _figure(width: float, height: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def plot_factors(out: Path, spec: StudySpec, records: list[dict[str, Any]],
                 metrics: tuple[str, ...]) -> dict[str, Path]:
    """``factor_<name>.png`` for every grid or random factor with more than one value."""
    files: dict[str, Path] = {}
    factors = [f for f in spec.grid if len(spec.grid[f]) > 1] + list(spec.random)
    panels = 1 + len(metrics)
    cols = min(3, panels)
    for name in factors:
        fig = _figure(4.2 * cols, 3.3 * math.ceil(panels / cols))
        ok = [r for r in records if r["status"] == "ok"]
        if name in spec.grid:
            levels = list(spec.grid[name])
            labels = [level_label(name, v) for v in levels]
            ax = fig.add_subplot(math.ceil(panels / cols), cols, 1)
            rates, lows, highs = [], [], []
            for v in levels:
                group = [r for r in records if r["factors"][name] == v]
                wins = sum(is_success(r, spec) for r in group)
                lo, hi = wilson_interval(wins, len(group))
                rate = wins / len(group) if group else math.nan
                rates.append(rate)
                lows.append(max(rate - lo, 0.0) if group else 0.0)  # ≥ 0 against rounding at 0 % and 100 %
                highs.append(max(hi - rate, 0.0) if group else 0.0)
            x = np.arange(len(levels))
            ax.bar(x, rates, yerr=[lows, highs], capsize=4, color="tab:green", alpha=0.7)
            ax.set_xticks(x, labels)
            ax.set_ylim(0, 1.05)
            ax.set_ylabel("success rate")
            ax.set_title(f"success: {spec.success_metric} ≥ {spec.success_at_least:g}", fontsize=9)
            for k, m in enumerate(metrics, start=2):
                ax = fig.add_subplot(math.ceil(panels / cols), cols, k)
                data = [np.array([r["metrics"].get(m) for r in ok if r["factors"][name] == v
                                  and isinstance(r["metrics"].get(m), (int, float))], dtype=float) for v in levels]
                data = [d[np.isfinite(d)] for d in data]
                if any(d.size for d in data):
                    ax.boxplot([d if d.size else np.array([np.nan]) for d in data], showmeans=True)
                    ax.set_xticks(x + 1, labels)
                ax.set_title(m, fontsize=9)
                ax.grid(alpha=0.3)
        else:
            ax = fig.add_subplot(math.ceil(panels / cols), cols, 1)
            xs = np.array([r["factors"][name] for r in records], dtype=float)
            ys = np.array([is_success(r, spec) for r in records], dtype=float)
            ax.scatter(xs, ys + np.random.default_rng(0).uniform(-0.03, 0.03, len(ys)), s=8)
            ax.set_yticks([0, 1], ["fail", "success"])
            ax.set_title("success per run", fontsize=9)
            for k, m in enumerate(metrics, start=2):
                ax = fig.add_subplot(math.ceil(panels / cols), cols, k)
                pts = [(r["factors"][name], r["metrics"].get(m)) for r in ok
                       if isinstance(r["metrics"].get(m), (int, float))]
                if pts:
                    ax.scatter(*np.array(pts, dtype=float).T, s=8)
                ax.set_title(m, fontsize=9)
                ax.grid(alpha=0.3)
        for ax in fig.axes:
            ax.set_xlabel(name, fontsize=8)
            ax.tick_params(labelsize=7)
        fig.suptitle(f"{spec.task} study: by {name} ({len(records)} runs)")
        fig.tight_layout()
        path = out / f"factor_{name}.png"
        fig.savefig(path)
        files[f"factor_{name}"] = path
    return files
