"""The methods of a compare on shared axes (``compare.png``), read from their run folders.

A clean's figure: the dirt remaining [% of the initial dirt, simulated] against the simulated time [s] for
every method, each method's time to 95 % removed marked on its curve, and the normal contact force [N]
against time with the set point and its ±20 % band. A wipe's: the normal force [N] against time with the
set point, and the motion error ‖x − x_d‖ [mm] in contact against time (log scale: the methods differ by
orders of magnitude). Each run folder gives its ``series.npz`` (:mod:`tactex.report.run_common`) and
``metrics.json``; a run whose series is missing or lacks a curve is left out and named in a note.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tactex.errors import InputError
from tactex.report.metrics import read_metrics
from tactex.report.run_common import figure, save_png
from tactex.tasks.clean.time_breakdown import time_to_fraction_removed

__all__ = ["REMOVED_MARK", "CompareFigure", "plot_compare"]

#: The removed share whose time each method's dirt curve marks (the summary's "95 % removed at [s]").
REMOVED_MARK = 0.95
#: Series each kind's figure reads, and the share of the set point the force band spans (grey, as no method is).
_KEYS = {"clean": ("t", "dirt_remaining", "force_z_n", "set_point_n"), "wipe": ("t", "force_z_n", "force_set_n",
                                                                                  "in_contact", "tcp", "desired")}
_BAND = 0.2


@dataclass
class CompareFigure:
    """What :func:`plot_compare` drew: the PNG (None when no run could be drawn), the methods on it, and a
    note per run left out."""

    path: Path | None
    drawn: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class _Run:
    """A method's series and metrics as read from its folder, and its colour: the one of its place in the
    compare, so that a method keeps its colour when another is left out."""

    label: str
    s: Mapping[str, np.ndarray]
    metrics: Mapping[str, Any]
    colour: str


def _load(label: str, folder: Path, keys: Sequence[str]) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """A run folder's series (the ``keys``, each as long as ``t``) and metrics (empty when it has none)."""
    path = folder / "series.npz"
    if not path.is_file():
        raise InputError(f"{label}: no series.npz in {folder}")
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in keys if k not in z.files]
            if missing:
                raise InputError(f"{label}: series.npz lacks {', '.join(missing)}")
            s = {k: np.asarray(z[k], dtype=np.float64) for k in keys}
    except (OSError, ValueError) as exc:
        raise InputError(f"{label}: series.npz cannot be read ({exc})") from exc
    n = s["t"].shape[0]
    if s["t"].ndim != 1 or n < 2 or any(v.shape[:1] != (n,) for v in s.values()):
        raise InputError(f"{label}: series.npz holds fewer than 2 samples or series of unequal length")
    metrics = read_metrics(folder / "metrics.json") if (folder / "metrics.json").is_file() else {}
    return s, dict(metrics)


def _when(t95: float | None, remaining: np.ndarray) -> str:
    """A method's legend text on the dirt axis: when it reached the mark, or how far it got."""
    mark = f"{100 * REMOVED_MARK:.0f} %"
    if t95 is not None:
        return f"{mark} removed at {t95:.1f} s"
    finite = remaining[np.isfinite(remaining)]
    return f"{mark} not reached ({100 * (1 - finite.min()):.0f} % removed)" if finite.size else "dirt not known"


def _clean(runs: Sequence[_Run], path: Path) -> Path:
    fig, (dirt, force) = figure(2, height=2.9, width=8.5)
    dirt.axhline(100 * (1 - REMOVED_MARK), color="0.4", ls=":", lw=1.0, label=f"{100 * REMOVED_MARK:.0f} % removed")
    set_points = []
    for run in runs:
        label, s, m, colour = run.label, run.s, run.metrics, run.colour
        t95 = time_to_fraction_removed(s["t"], s["dirt_remaining"], REMOVED_MARK)
        dirt.plot(s["t"], 100 * s["dirt_remaining"], color=colour, lw=1.6,
                  label=f"{label}: {_when(t95, s['dirt_remaining'])}")
        if t95 is not None:
            dirt.axvline(t95, color=colour, ls="--", lw=0.9, alpha=0.8)
            dirt.plot([t95], [100 * (1 - REMOVED_MARK)], marker="o", ms=6, color=colour, mec="black", mew=0.6)
        force.plot(s["t"], s["force_z_n"], color=colour, lw=0.8, alpha=0.85, label=label)
        active = s["set_point_n"][s["set_point_n"] > 0]
        set_points.append(float(m.get("force_set_point_n") or (np.median(active) if active.size else np.nan)))
    sp = next((f for f in set_points if np.isfinite(f) and f > 0), None)
    if sp is not None:  # one set point for all: a compare runs every method with the same parameters
        force.axhspan((1 - _BAND) * sp, (1 + _BAND) * sp, color="0.5", alpha=0.2, lw=0,
                      label=f"set point ±{100 * _BAND:.0f} %")
        force.axhline(sp, color="black", ls="--", lw=1.0, label=f"set point {sp:g} N")
        force.set_ylim(min(-1.0, force.get_ylim()[0]), max(2.2 * sp, min(force.get_ylim()[1], 3.0 * sp)))
    dirt.set_ylim(0, 105)
    dirt.set_ylabel("dirt remaining\n[% of initial, simulated]")
    dirt.set_title("Dirt remaining (dashed: each method's time to 95 % removed)")
    dirt.legend(loc="upper right", fontsize=8)
    force.set_ylabel("normal force [N]")
    force.set_xlabel("simulated time [s]")
    force.set_title("Contact force (F/T, tool z)")
    force.legend(loc="upper left", fontsize=8, ncol=3)
    return save_png(fig, path)


def _motion_error_mm(s: Mapping[str, np.ndarray]) -> np.ndarray:
    """‖x − x_d‖ [mm] while in contact, NaN out of contact (the ticks the wipe's motion metrics count)."""
    err = 1e3 * np.linalg.norm(s["tcp"] - s["desired"], axis=1)
    return np.where(s["in_contact"] > 0.5, err, np.nan)


def _wipe(runs: Sequence[_Run], path: Path) -> Path:
    fig, (force, motion) = figure(2, height=2.9, width=8.5)
    ref, first = runs[0].s, runs[0].label
    sp = np.where(ref["force_set_n"] > 0, ref["force_set_n"], np.nan)
    force.fill_between(ref["t"], (1 - _BAND) * sp, (1 + _BAND) * sp, color="0.5", alpha=0.2, lw=0,
                       label=f"set point ±{100 * _BAND:.0f} % ({first})")
    force.plot(ref["t"], sp, color="black", ls="--", lw=1.0, label=f"set point ({first})")
    for i, run in enumerate(runs):
        label, s, colour = run.label, run.s, run.colour
        force.plot(s["t"], s["force_z_n"], color=colour, lw=0.9, alpha=0.85, label=label)
        if i and not np.allclose(s["force_set_n"], np.interp(s["t"], ref["t"], ref["force_set_n"]), atol=1e-6):
            force.plot(s["t"], np.where(s["force_set_n"] > 0, s["force_set_n"], np.nan), color=colour, ls="--",
                       lw=1.0, label=f"set point ({label})")
        err = _motion_error_mm(s)
        mean = np.nanmean(err) if np.isfinite(err).any() else np.nan
        motion.plot(s["t"], err, color=colour, lw=1.0, label=f"{label} (mean {mean:.3g} mm)"
                    if np.isfinite(mean) else f"{label} (never in contact)")
    top = float(np.nanmax(sp)) if np.isfinite(sp).any() else 0.0
    if top > 0:
        force.set_ylim(min(-1.0, force.get_ylim()[0]), max(2.2 * top, min(force.get_ylim()[1], 3.0 * top)))
    force.set_ylabel("normal force [N]")
    force.set_title("Normal force (F/T, tool z)")
    force.legend(loc="lower right", fontsize=8, ncol=2)  # under the set point: the touch-down peaks are above it
    motion.set_yscale("log")
    motion.set_ylabel("motion error ‖x − x_d‖\nin contact [mm]")
    motion.set_xlabel("simulated time [s]")
    motion.set_title("Motion error in contact (log scale)")
    motion.legend(loc="lower right", fontsize=8)  # below the larger errors, which a short run's end reaches
    return save_png(fig, path)


def plot_compare(kind: str, runs: Sequence[tuple[str, str | Path]], path: str | Path) -> CompareFigure:
    """Draw the methods of a compare on shared axes into ``path`` (see the module docstring).

    Args:
        kind: "clean" or "wipe".
        runs: (method name, run folder) pairs, in the order of the legend (the first sets the wipe's set point).
        path: the PNG to write.

    Returns:
        The figure's path (None when no run had the series to draw), the methods drawn and a note per run left out.
    """
    if kind not in _KEYS:
        raise InputError(f"no compare figure for a '{kind}' run; valid: {', '.join(_KEYS)}")
    if not runs:
        raise InputError("a compare figure needs at least one run")
    out = CompareFigure(path=None)
    loaded = []
    for i, (label, folder) in enumerate(runs):
        try:
            s, metrics = _load(str(label), Path(folder), _KEYS[kind])
        except InputError as exc:
            out.notes.append(f"{exc}: not drawn in the compare figure")
            continue
        loaded.append(_Run(str(label), s, metrics, f"C{i % 10}"))
    if loaded:
        out.path = (_clean if kind == "clean" else _wipe)(loaded, Path(path))
        out.drawn = [run.label for run in loaded]
    return out
