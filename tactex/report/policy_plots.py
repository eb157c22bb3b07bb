"""A wipe's force-motion policy in its run folder: the commanded and the executed path drawn on the
surface (top view in the object frame, over the surface's height), and the measured force against
the policy's own set point over time, each segment shaded and labelled with its force MAE."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from tactex.errors import InputError
from tactex.report.run_common import figure, save_png

__all__ = ["plot_policy_force", "plot_policy_path"]


def _segment_spans(s: Mapping[str, np.ndarray]) -> list[tuple[int, float, float]]:
    """(segment index, first t, last t) [s] of each segment in the recorded series."""
    seg, t = np.asarray(s["segment"]).astype(int), np.asarray(s["t"])
    if seg.size == 0:
        raise InputError("the run recorded no policy ticks")
    cuts = np.flatnonzero(np.diff(seg)) + 1
    starts, ends = np.r_[0, cuts], np.r_[cuts, seg.size]
    return [(int(seg[a]), float(t[a]), float(t[b - 1])) for a, b in zip(starts, ends, strict=True)]


def _labels(metrics: Mapping[str, Any]) -> dict[int, str]:
    segs = (metrics.get("policy") or {}).get("segments") or []
    out = {}
    for k, g in enumerate(segs):
        mae = g.get("force_mae_n")
        shown = isinstance(mae, float) and np.isfinite(mae)
        out[k] = f"{k + 1} {g.get('kind', '')}" + (f"\nMAE {mae:.2f} N" if shown else "")
    return out


def plot_policy_force(s: Mapping[str, np.ndarray], metrics: Mapping[str, Any], path: Path) -> Path:
    """Force along the tool axis against the policy's set point, segments shaded [N over s]."""
    fig, (ax,) = figure(height=2.8)
    labels = _labels(metrics)
    for k, t0, t1 in _segment_spans(s):
        ax.axvspan(t0, t1, color=f"C{k % 10}", alpha=0.08, lw=0)
        ax.text(0.5 * (t0 + t1), 1.0, labels.get(k, str(k + 1)), transform=ax.get_xaxis_transform(), ha="center",
                va="top", fontsize=7)
    contact = np.asarray(s["in_contact"]) > 0.5
    f = np.where(contact, s["force_z_n"], np.nan)
    ax.plot(s["t"], s["force_set_n"], color="k", lw=1.3, label="policy set point")
    ax.plot(s["t"], f, color="C0", lw=0.8, label="measured (tool z, in contact)")
    ax.set_ylabel("force [N]")
    ax.set_xlabel("policy time [s]")
    ax.legend(fontsize=7, loc="lower right")
    ax.set_title("force against the policy's set point, per segment", fontsize=9)
    return save_png(fig, path)


def plot_policy_path(s: Mapping[str, np.ndarray], surface: Any, obj_pos: np.ndarray, obj_rot: np.ndarray,
                     path: Path) -> Path:
    """Top view in the object frame [mm]: the commanded path (the policy's reference as the controller
    tracked it, dashed) and the executed TCP path (solid), per segment, over the surface height."""
    desired = (np.asarray(s["desired"]) - obj_pos) @ obj_rot  # world → object frame
    tcp = np.asarray(s["tcp_object"])
    seg = np.asarray(s["segment"]).astype(int)
    ok = np.all(np.isfinite(desired), axis=1) & np.all(np.isfinite(tcp), axis=1)
    if not ok.any():
        raise InputError("no finite path to draw")
    fig, (ax,) = figure(height=5.0, width=6.0)
    lo = np.minimum(desired[ok].min(axis=0), tcp[ok].min(axis=0))[:2] - 0.01
    hi = np.maximum(desired[ok].max(axis=0), tcp[ok].max(axis=0))[:2] + 0.01
    xs, ys = np.linspace(lo[0], hi[0], 120), np.linspace(lo[1], hi[1], 120)
    gx, gy = np.meshgrid(xs, ys)
    if hasattr(surface, "height"):
        z = np.where(surface.inside(gx, gy), surface.height(gx, gy), np.nan)
        im = ax.pcolormesh(1e3 * gx, 1e3 * gy, 1e3 * z, cmap="Greys", shading="auto", alpha=0.6)
        fig.colorbar(im, ax=ax, label="surface height [mm]")
    for k in np.unique(seg):
        m = ok & (seg == k)
        ax.plot(1e3 * desired[m, 0], 1e3 * desired[m, 1], ls="--", lw=1.0, color=f"C{k % 10}")
        ax.plot(1e3 * tcp[m, 0], 1e3 * tcp[m, 1], lw=1.2, color=f"C{k % 10}", label=f"segment {k + 1}")
    ax.plot([], [], ls="--", color="k", label="commanded")
    ax.plot([], [], color="k", label="executed (TCP)")
    ax.set_aspect("equal")
    ax.set_xlabel("object x [mm]")
    ax.set_ylabel("object y [mm]")
    ax.legend(fontsize=7)
    ax.set_title("commanded vs executed path on the surface (top view)", fontsize=9)
    return save_png(fig, path)
