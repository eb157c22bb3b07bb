"""Interactive 3-D view of a cloud (plotly HTML): colourings switchable from a menu, agent path.

The plotly library is embedded in the page by default so that it opens without a network
connection (robot PCs often have none); ``include_plotlyjs="cdn"`` writes a small file instead.

A big cloud is drawn through an even subset of its points (:mod:`tactex.report.display_subset`), so
that the page stays small and quick to open whatever the cloud; the page says how many it shows.
The positions and colours are written as float32 (a display needs no more: 0.1 µm on a 1 m cloud),
the positions once: the colourings share one trace and the menu swaps its colours.
"""

from __future__ import annotations

import base64
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tactex.errors import ConfigError, InputError
from tactex.report._validate import as_fields, as_mask, as_path, as_points
from tactex.report.cloud import color_limits
from tactex.report.display_subset import check_budget, display_subset, touched_points
from tactex.report.path_lift import lift_path
from tactex.report.path_segments import flight_indices, split_flights

__all__ = ["KEEP_SHARE", "PAGE_POINTS", "cloud_html", "tick_format"]

#: The most cloud points a page draws. Measured per 1000 points drawn: 0.021 MB with one colouring,
#: 0.037 MB with three (explore), 0.043 MB with four (clean: two dirt captures, coverage, potential;
#: the most a report offers), over the 4.9 MB of a page with inline plotly.js and a small cloud: a
#: page stays ≤ 9.2 MB (a 240 000-point room scan drawn whole, in float64 and a trace per colouring,
#: makes 43 MB).
PAGE_POINTS = 100_000
#: The share of :data:`PAGE_POINTS` the target and the points the path touched may take before they
#: are thinned too: they are what the page is read for, the rest of the budget draws the surface.
KEEP_SHARE = 0.5
#: A typed array's base64 text in plotly's JSON.
_BDATA = re.compile(r'"bdata":"[^"]*"')


def tick_format(lo: float, hi: float) -> str:
    """A d3 tick format for a colour bar over [lo, hi]: plotly's default writes SI prefixes ("20μ"), which read
    as a unit on a quantity without one; small or large magnitudes get an exponent ("2e-5"), others 3 digits."""
    big = max(abs(lo), abs(hi))
    return ".2~e" if 0 < big < 1e-2 or big >= 1e4 else ".3~g"


def _f4(values: np.ndarray) -> dict[str, str]:
    """plotly.js's typed-array form of ``values`` as float32 (half of float64's bytes)."""
    raw = np.ascontiguousarray(values, dtype="<f4").tobytes()
    return {"dtype": "f4", "bdata": base64.b64encode(raw).decode("ascii")}


def _thin_path(traj: np.ndarray, flown: np.ndarray, max_path_points: int) -> tuple[np.ndarray, np.ndarray]:
    """The path through ``max_path_points`` evenly spaced samples (start, end and every flight's two ends
    kept, so that a flight is drawn as the chord it was), and the flights' indices into it."""
    if traj.shape[0] <= max_path_points or max_path_points <= 1:
        return traj, flown
    keep = np.linspace(0, traj.shape[0] - 1, max_path_points).round().astype(np.intp)
    if flown.size:
        keep = np.concatenate([keep, flown - 1, flown])
    keep = np.unique(keep)
    return traj[keep], np.searchsorted(keep, flown)


def _colouring(name: str, values: np.ndarray, scale: Any) -> dict[str, Any]:
    """A restyle of the points trace to the colouring ``name``: its colours, scale, limits and hover."""
    lo, hi = color_limits(values)  # a constant (whole-surface) target in the scale's top colour
    return {"marker.color": [_f4(values)], "marker.colorscale": [scale], "marker.cmin": [lo], "marker.cmax": [hi],
            "marker.colorbar.title.text": [name], "marker.colorbar.tickformat": [tick_format(lo, hi)],
            "name": [name], "hovertemplate": [f"{name}: %{{marker.color:.4g}}<extra></extra>"]}


def _points_trace(go, pts: np.ndarray, first: dict[str, Any], point_size: float):
    """The cloud's markers in the first colouring (a restyle of :func:`_colouring`)."""
    look = {key: value[0] for key, value in first.items()}  # one trace's values
    return go.Scatter3d(
        x=_f4(pts[:, 0]), y=_f4(pts[:, 1]), z=_f4(pts[:, 2]), mode="markers", name=look["name"],
        marker={"size": point_size, "color": look["marker.color"], "colorscale": look["marker.colorscale"],
                "cmin": look["marker.cmin"], "cmax": look["marker.cmax"],
                "colorbar": {"title": {"text": look["name"]}, "tickformat": look["marker.colorbar.tickformat"]}},
        hovertemplate=look["hovertemplate"],
    )


def _path_traces(go, traj: np.ndarray, flown: np.ndarray, pts: np.ndarray, normals: np.ndarray | None) -> list:
    """The walked path (solid, lifted off the surface so that the markers do not hide it), its flights
    (dashed chords through the air) and its start and end markers (on the lifted path)."""
    walked, air = split_flights(traj, flown)
    lifted = lift_path(walked, pts, normals)
    traces = [go.Scatter3d(x=_f4(lifted[:, 0]), y=_f4(lifted[:, 1]), z=_f4(lifted[:, 2]), mode="lines", name="path",
                           line={"color": "black", "width": 4}, connectgaps=False)]
    if air is not None:
        traces.append(go.Scatter3d(x=_f4(air[:, 0]), y=_f4(air[:, 1]), z=_f4(air[:, 2]), mode="lines", name="flight",
                                   line={"color": "dimgrey", "width": 3, "dash": "dash"}, connectgaps=False))
    for name, i, colour in (("start", 0, "limegreen"), ("end", walked.shape[0] - 1, "purple")):
        traces.append(go.Scatter3d(x=lifted[[i], 0], y=lifted[[i], 1], z=lifted[[i], 2], mode="markers", name=name,
                                   marker={"size": 6, "color": colour, "line": {"color": "black", "width": 1}}))
    return traces


def _scene(pts: np.ndarray) -> dict[str, Any]:
    """The 3-D scene: axes in metres, drawn to scale in a box as long across as plotly's unit cube (√3),
    which the first view (the camera ~2 units out) holds whole. plotly's own "data" aspect gives the box
    a unit volume instead, which crops a flat room-sized scan at the first view."""
    extent = np.ptp(pts, axis=0)
    longest = float(extent.max()) or 1.0
    ratio = np.maximum(extent / longest, 0.02)  # a flat cloud keeps a sliver of depth to draw its axis in
    ratio *= np.sqrt(3.0) / np.linalg.norm(ratio)
    return {"aspectmode": "manual", "aspectratio": dict(zip("xyz", ratio.tolist(), strict=True)),
            "xaxis_title": "x [m]", "yaxis_title": "y [m]", "zaxis_title": "z [m]"}


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
    max_points: int = PAGE_POINTS,
    keep: np.ndarray | None = None,
    normals: np.ndarray | None = None,
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
        max_points: a bigger cloud is drawn through an even subset of this many points (see
            :data:`PAGE_POINTS` for the page's size per point).
        keep: (N,) bool, the points to draw whatever the budget (the target), with the points nearest
            the path, up to :data:`KEEP_SHARE` of ``max_points``.
        normals: (N, 3) the cloud's oriented unit normals: the path is drawn a little off the surface
            on their side (without them, on both sides; :mod:`tactex.report.path_lift`).
    """
    import plotly.graph_objects as go

    if include_plotlyjs not in (True, False, "cdn"):
        raise ConfigError(f"include_plotlyjs must be True, False or 'cdn', got {include_plotlyjs!r}")
    check_budget(max_points)
    pts = as_points(points)
    n = pts.shape[0]
    data = as_fields(fields, n) or {"cloud": np.zeros(n)}
    traj = as_path(trajectory)
    zone = None if keep_out is None else as_mask(keep_out, n, "keep_out")
    if normals is not None:
        normals = as_points(normals, "normals")
        if normals.shape[0] != n:
            raise InputError(f"normals must have shape ({n}, 3) to match the points, got {normals.shape}")
    wanted = touched_points(pts, traj) if n > max_points else None
    if wanted is not None and keep is not None:
        wanted |= as_mask(keep, n, "keep")
    shown = display_subset(pts, max_points, wanted, KEEP_SHARE)
    flown = flight_indices(flights, 0 if traj is None else traj.shape[0])
    if traj is not None:
        traj, flown = _thin_path(traj, flown, max_path_points)
    scales = dict(colorscales or {})
    looks = [_colouring(name, values[shown], scales.get(name, "Viridis")) for name, values in data.items()]
    traces = [_points_trace(go, pts[shown], looks[0], point_size)]
    if zone is not None and zone[shown].any():
        ko = pts[shown][zone[shown]]
        traces.append(go.Scatter3d(x=_f4(ko[:, 0]), y=_f4(ko[:, 1]), z=_f4(ko[:, 2]), mode="markers", name="keep-out",
                                   marker={"size": 3, "color": "dodgerblue", "symbol": "x"}))
    if traj is not None and traj.shape[0] > 0:
        traces += _path_traces(go, traj, flown, pts, normals)
    # each button restyles trace 0, the points, to its colouring
    buttons = [{"label": name, "method": "restyle", "args": [look, [0]]}
               for name, look in zip(data, looks, strict=True)]
    fig = go.Figure(data=traces)
    # The title on top, the field menu on its own row below it (over the title it would hide the text).
    fig.update_layout(
        title={"text": title or "", "x": 0.01, "xanchor": "left", "y": 0.98, "yanchor": "top"},
        scene=_scene(pts[shown]),
        updatemenus=[{"buttons": buttons, "direction": "down", "x": 0.01, "xanchor": "left", "y": 1.0,
                      "yanchor": "top", "pad": {"t": 0}}]
        if len(buttons) > 1
        else [],
        margin={"l": 0, "r": 0, "t": 80, "b": 0},
        legend={"x": 0.8, "y": 0.95},
        autosize=True,
        annotations=[_count_note(shown.size, n)] if shown.size < n else [],
    )
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    # The figure fills the window (less the body's 8 px margins, so no scroll bar on a bare page) and
    # follows its size; a report's sections come below it.
    page = fig.to_html(include_plotlyjs=include_plotlyjs, full_html=True, config={"responsive": True},
                       default_width="100%", default_height="calc(100vh - 16px)")
    # plotly writes "/" as "\u002f" so that no "</script>" ends its script early; base64 holds no "<", and
    # six characters for a "/" make a page of float32 numbers ~15 % bigger
    out.write_text(_BDATA.sub(lambda m: m.group(0).replace("\\u002f", "/"), page), encoding="utf-8")
    return out


def _count_note(shown: int, total: int) -> dict[str, Any]:
    """The page's word that it draws a subset: "showing N of M points"."""
    return {"text": f"showing {shown:,} of {total:,} points (an even subset for display; the run's files hold "
                    f"every point)".replace(",", " "),
            # under the title, above the plot (the menu's row starts at the plot's top)
            "xref": "paper", "yref": "paper", "x": 0.01, "y": 1.0, "xanchor": "left", "yanchor": "bottom",
            "showarrow": False, "font": {"size": 12, "color": "dimgrey"}}
