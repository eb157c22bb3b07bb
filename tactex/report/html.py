"""Interactive 3-D view of a cloud (plotly HTML): colourings switchable from a menu, agent path.

The plotly library is embedded in the page by default so that it opens without a network
connection (robot PCs often have none); ``include_plotlyjs="cdn"`` writes a small file instead.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tactex.errors import ConfigError
from tactex.report._validate import as_fields, as_mask, as_path, as_points
from tactex.report.cloud import color_limits
from tactex.report.path_segments import flight_indices, split_flights

__all__ = ["cloud_html", "tick_format"]


def tick_format(lo: float, hi: float) -> str:
    """A d3 tick format for a colour bar over [lo, hi]: plotly's default writes SI prefixes ("20μ"), which read
    as a unit on a quantity without one; small or large magnitudes get an exponent ("2e-5"), others 3 digits."""
    big = max(abs(lo), abs(hi))
    return ".2~e" if 0 < big < 1e-2 or big >= 1e4 else ".3~g"


def cloud_html(
    points: np.ndarray,
    fields: Mapping[str, np.ndarray] | np.ndarray | None,
    path: str | Path,
    *,
    trajectory: np.ndarray | None = None,
    flights: Sequence[int] = (),
    keep_out: np.ndarray | None = None,
    title: str | None = None,
    colorscales: Mapping[str, Any] | None = None,
    point_size: float = 2.5,
    include_plotlyjs: bool | str = True,
    max_path_points: int = 4000,
) -> Path:
    """Write an HTML page with the cloud coloured by each field (switchable) and the path.

    Args:
        points: (N, 3) positions [m].
        fields: {name: (N,) values}; the first is shown first. None → a plain cloud.
        path: output HTML file.
        trajectory: (T, 3) agent path [m] (start green, end purple).
        flights: indices k of the trajectory reached from k − 1 through the air (relocations): a dashed
            grey chord each, not a walk across the surface.
        keep_out: (N,) bool, kept-out points, drawn as blue crosses.
        title: page title.
        colorscales: plotly colour scale (name or [[0, colour], …, [1, colour]]) per field (default "Viridis").
        point_size: marker size [px].
        include_plotlyjs: True (inline, works offline), "cdn", or False.
        max_path_points: a longer path is drawn through this many evenly spaced samples (its start
            and end kept), so that a 200 000-step run gives a page of the same size as a short one.
    """
    import plotly.graph_objects as go

    if include_plotlyjs not in (True, False, "cdn"):
        raise ConfigError(f"include_plotlyjs must be True, False or 'cdn', got {include_plotlyjs!r}")
    pts = as_points(points)
    data = as_fields(fields, pts.shape[0]) or {"cloud": np.zeros(pts.shape[0])}
    traj = as_path(trajectory)
    zone = None if keep_out is None else pts[as_mask(keep_out, pts.shape[0], "keep_out")]
    flown = flight_indices(flights, 0 if traj is None else traj.shape[0])
    if traj is not None and traj.shape[0] > max_path_points > 1:
        keep = np.linspace(0, traj.shape[0] - 1, max_path_points).round().astype(np.intp)
        if flown.size:  # every flight's two ends stay, so that it is drawn as the chord it was
            keep = np.concatenate([keep, flown - 1, flown])
        keep = np.unique(keep)
        flown = np.searchsorted(keep, flown)
        traj = traj[keep]
    scales = dict(colorscales or {})
    names = list(data)
    traces = []
    for i, name in enumerate(names):
        lo, hi = color_limits(data[name])  # a constant (whole-surface) target in the scale's top colour
        traces.append(
            go.Scatter3d(
                x=pts[:, 0],
                y=pts[:, 1],
                z=pts[:, 2],
                mode="markers",
                name=name,
                visible=i == 0,
                marker={
                    "size": point_size,
                    "color": data[name],
                    "colorscale": scales.get(name, "Viridis"),
                    "cmin": lo,
                    "cmax": hi,
                    "colorbar": {"title": {"text": name}, "tickformat": tick_format(lo, hi)},
                },
                hovertemplate=f"{name}: %{{marker.color:.4g}}<extra></extra>",
            )
        )
    extra = 0
    if zone is not None and zone.shape[0]:
        traces.append(go.Scatter3d(x=zone[:, 0], y=zone[:, 1], z=zone[:, 2], mode="markers", name="keep-out",
                                   marker={"size": 3, "color": "dodgerblue", "symbol": "x"}))
        extra += 1
    if traj is not None and traj.shape[0] > 0:
        walked, air = split_flights(traj, flown)
        traces.append(
            go.Scatter3d(
                x=walked[:, 0], y=walked[:, 1], z=walked[:, 2], mode="lines", name="path",
                line={"color": "black", "width": 4}, connectgaps=False,
            )
        )
        if air is not None:
            traces.append(go.Scatter3d(x=air[:, 0], y=air[:, 1], z=air[:, 2], mode="lines", name="flight",
                                       line={"color": "dimgrey", "width": 3, "dash": "dash"}, connectgaps=False))
            extra += 1
        for name, i, colour in (("start", 0, "limegreen"), ("end", -1, "purple")):
            traces.append(
                go.Scatter3d(
                    x=traj[[i], 0],
                    y=traj[[i], 1],
                    z=traj[[i], 2],
                    mode="markers",
                    name=name,
                    marker={"size": 6, "color": colour, "line": {"color": "black", "width": 1}},
                )
            )
        extra += 3
    buttons = [
        {
            "label": name,
            "method": "restyle",
            "args": [{"visible": [j == i for j in range(len(names))] + [True] * extra}],
        }
        for i, name in enumerate(names)
    ]
    fig = go.Figure(data=traces)
    # The title on top, the field menu on its own row below it (over the title it would hide the text).
    fig.update_layout(
        title={"text": title or "", "x": 0.01, "xanchor": "left", "y": 0.98, "yanchor": "top"},
        scene={"aspectmode": "data", "xaxis_title": "x [m]", "yaxis_title": "y [m]", "zaxis_title": "z [m]"},
        updatemenus=[{"buttons": buttons, "direction": "down", "x": 0.01, "xanchor": "left", "y": 1.0,
                      "yanchor": "top", "pad": {"t": 0}}]
        if len(names) > 1
        else [],
        margin={"l": 0, "r": 0, "t": 80, "b": 0},
        legend={"x": 0.8, "y": 0.95},
    )
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.write_html(str(out), include_plotlyjs=include_plotlyjs, full_html=True)
    return out
