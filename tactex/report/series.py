"""Metric-versus-step plots (PNG), one panel per metric sharing the x axis."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from tactex.errors import InputError

__all__ = ["plot_series"]


def plot_series(
    series: Mapping[str, Sequence[float] | np.ndarray],
    path: str | Path,
    *,
    x: Sequence[float] | np.ndarray | None = None,
    xlabel: str = "step",
    title: str | None = None,
    logy: Sequence[str] = (),
    dpi: int = 110,
) -> Path:
    """Plot each named series (1-D, or 2-D (runs, T) drawn as thin lines plus the mean) in its own panel.

    Args:
        series: {label: values}; the label becomes the panel's y label (put units in it, "[m]").
        path: output PNG file.
        x: abscissa (T,), default 0..T−1.
        xlabel: x-axis label.
        title: figure title.
        logy: labels whose panel uses a log scale.
        dpi: resolution.

    Returns:
        The written path. NaN values leave gaps (they are not dropped silently: the line breaks).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if not series:
        raise InputError("plot_series needs at least one series")
    data = {}
    for label, values in series.items():
        arr = np.asarray(values, dtype=np.float64)
        if arr.ndim not in (1, 2) or arr.shape[-1] == 0:
            raise InputError(f"series '{label}' must be 1-D (T,) or 2-D (runs, T) and non-empty, got {arr.shape}")
        data[str(label)] = arr
    lengths = {a.shape[-1] for a in data.values()}
    if x is None:
        xs = np.arange(max(lengths))
    else:
        xs = np.asarray(x, dtype=np.float64)
    for label, arr in data.items():
        if arr.shape[-1] > xs.shape[0]:
            raise InputError(f"series '{label}' has {arr.shape[-1]} values but x only {xs.shape[0]}")

    fig = Figure(figsize=(7.0, 2.2 * len(data) + 0.6), dpi=dpi)
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(data), 1, sharex=True, squeeze=False)[:, 0]
    for ax, (label, arr) in zip(axes, data.items(), strict=True):
        t = xs[: arr.shape[-1]]
        if arr.ndim == 1:
            ax.plot(t, arr, lw=1.4, color="C0")
        else:
            for row in arr:
                ax.plot(t, row, lw=0.6, alpha=0.35, color="C0")
            mean = np.nanmean(arr, axis=0)
            std = np.nanstd(arr, axis=0)
            ax.fill_between(t, mean - std, mean + std, color="C0", alpha=0.2, lw=0)
            ax.plot(t, mean, lw=1.6, color="C0")
        if label in logy:
            ax.set_yscale("log")
        ax.set_ylabel(label)
        if label not in logy:  # "+9.999e-1" above the axis hides that a curve is flat
            ax.ticklabel_format(axis="y", useOffset=False, style="plain")
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel(xlabel)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, format="png")
    return out
