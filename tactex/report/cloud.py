"""3-D scatter plots of a cloud coloured by per-point fields, with an agent path (PNG)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tactex.report._validate import as_fields, as_mask, as_path, as_points
from tactex.report.path_segments import split_flights

__all__ = ["color_limits", "plot_cloud"]


def color_limits(values: np.ndarray) -> tuple[float, float]:
    """Colour-scale limits of a field: its range; a constant field (a whole-surface target) spans
    0..its value, so that it shows in the map's top colour with a colour bar, not as mid-scale grey."""
    finite = np.asarray(values, dtype=np.float64)
    finite = finite[np.isfinite(finite)]
    if finite.size == 0:
        return 0.0, 1.0
    lo, hi = float(finite.min()), float(finite.max())
    if hi > lo:
        return lo, hi
    if hi == 0.0:
        return 0.0, 1.0
    return (0.0, hi) if hi > 0 else (hi, 0.0)


def _equal_aspect(ax, points: np.ndarray) -> None:
    """One metre is as long on every axis; each axis spans the data (at least a quarter of the
    widest), so a flat plate is not drawn in a tall empty cube."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = (lo + hi) / 2
    widest = max(float((hi - lo).max()) / 2, 1e-6)
    half = np.maximum((hi - lo) / 2, 0.25 * widest)
    ax.set_xlim(centre[0] - half[0], centre[0] + half[0])
    ax.set_ylim(centre[1] - half[1], centre[1] + half[1])
    ax.set_zlim(centre[2] - half[2], centre[2] + half[2])
    ax.set_box_aspect(tuple(half.tolist()), zoom=1.15)


def plot_cloud(
    points: np.ndarray,
    fields: Mapping[str, np.ndarray] | np.ndarray | None,
    path: str | Path,
    *,
    trajectory: np.ndarray | None = None,
    flights: Sequence[int] = (),
    keep_out: np.ndarray | None = None,
    title: str | None = None,
    cmaps: Mapping[str, Any] | None = None,
    labels: Mapping[str, str] | None = None,
    point_size: float = 2.0,
    view: tuple[float, float] = (35.0, -60.0),
    dpi: int = 110,
) -> Path:
    """One 3-D scatter panel per field (N,) of the cloud, each with the path drawn on top.

    Args:
        points: (N, 3) positions [m].
        fields: {name: (N,) values} (a bare array is one field; None → grey cloud).
        path: output PNG file.
        trajectory: (T, 3) agent path [m]: black line, start green, end purple (as TEC Fig. 8).
        flights: indices k of the trajectory reached from k − 1 through the air (relocations): drawn as
            dashed grey chords, not as a walk across the surface.
        keep_out: (N,) bool, kept-out points, drawn as blue crosses over every panel.
        title: figure title.
        cmaps: colour map (name or matplotlib Colormap) per field name (default "viridis").
        labels: colour bar label per field name, with its unit (default the name).
        point_size: marker size [pt²].
        view: (elevation, azimuth) of the camera [deg].
        dpi: resolution.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator

    pts = as_points(points)
    data = as_fields(fields, pts.shape[0]) or {"cloud": np.zeros(pts.shape[0])}
    traj = as_path(trajectory)
    walked, flown = (None, None) if traj is None else split_flights(traj, flights)
    zone = None if keep_out is None else pts[as_mask(keep_out, pts.shape[0], "keep_out")]
    cmaps = dict(cmaps or {})
    n = len(data)
    fig = Figure(figsize=(5.2 * n, 4.6), dpi=dpi)
    FigureCanvasAgg(fig)
    for i, (name, values) in enumerate(data.items()):
        ax = fig.add_subplot(1, n, i + 1, projection="3d")
        # Draw in call order: the depth-sorted default hides a path lying on the surface.
        ax.computed_zorder = False
        lo, hi = color_limits(values)
        sc = ax.scatter(
            pts[:, 0],
            pts[:, 1],
            pts[:, 2],
            c=values,
            s=point_size,
            cmap=cmaps.get(name, "viridis"),
            vmin=lo,
            vmax=hi,
            depthshade=False,
            zorder=1,
        )
        if name != "cloud":  # above the panel, labelled (it is the panel's title): under it the bar would cover the
            # x and y axis titles, beside it the z axis title
            bar = fig.colorbar(sc, ax=ax, shrink=0.6, pad=0.02, location="top", aspect=30)
            bar.set_label((labels or {}).get(name, name), fontsize=8)
            bar.ax.tick_params(labelsize=7)
        if zone is not None and zone.shape[0]:
            ax.scatter(zone[:, 0], zone[:, 1], zone[:, 2], color="dodgerblue", marker="x", s=6, lw=0.6,
                       depthshade=False, zorder=2, label="keep-out")
        if traj is not None and traj.shape[0] > 0:
            ax.plot(walked[:, 0], walked[:, 1], walked[:, 2], color="black", lw=1.2, zorder=3, label="path")
            if flown is not None:
                ax.plot(flown[:, 0], flown[:, 1], flown[:, 2], color="dimgrey", lw=1.0, ls="--", zorder=3,
                        label="flight")
            ax.scatter(*traj[0], color="limegreen", s=40, edgecolors="black", depthshade=False, zorder=4,
                       label="start")
            ax.scatter(*traj[-1], color="purple", s=40, edgecolors="black", depthshade=False, zorder=4, label="end")
        if i == 0 and ((traj is not None and traj.shape[0] > 0) or (zone is not None and zone.shape[0] > 0)):
            ax.legend(loc="upper left", fontsize=7, framealpha=0.8)
        _equal_aspect(ax, pts if traj is None else np.vstack([pts, traj]))
        ax.view_init(*view)
        if name == "cloud":
            ax.set_title(name)
        for axis, label, pad in ((ax.xaxis, "x [m]", 8), (ax.yaxis, "y [m]", 8), (ax.zaxis, "z [m]", 2)):
            axis.set_major_locator(MaxNLocator(4))  # few ticks: 3-D axes crowd their labels together
            axis.set_label_text(label, fontsize=8)
            axis.labelpad = pad  # z's label sits beyond its tick labels, at the next panel's edge when padded
        ax.tick_params(labelsize=6, pad=1)
    if title:
        fig.suptitle(title)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, format="png", bbox_inches="tight")  # 3-D axes leave wide empty margins
    return out
