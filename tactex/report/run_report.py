"""Run folders of the closed-loop tasks: parameters, metrics, time series, plots and one HTML page.

``write_run_report(result, out_dir)`` takes a cleaning result (TEC §V-A) or a wiping result
(VA-UFIC §III) and writes

- ``config.json`` — the exact parameters of the run,
- ``metrics.json`` — the metrics contract (:data:`CLEAN_METRIC_KEYS` / :data:`WIPE_METRIC_KEYS`) and more,
- ``series.npz`` — the 100 Hz time series (plain arrays, no pickle) and ``cloud.npz`` — points and fields,
- ``explored.ply`` (wipe) — the explored contact points with normals and curvature, which
  ``tactex explore`` loads,
- ``events.json`` — safety events,
- PNG plots (clean: dirt, force band, phases, time breakdown, cloud fields, ergodicity; wipe: VA-UFIC Fig. 2 and 3a–d,
  explored curvature),
- ``report.html`` — an interactive 3-D view of the cloud (inline plotly, works offline) with the
  metrics and the PNGs embedded.

:func:`summary_table` prints tactex beside its baselines in the terminal; :func:`write_index_html`
links several run folders from one page.
"""

from __future__ import annotations

import base64
import dataclasses
import html
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tactex.config import to_jsonable, write_json
from tactex.control.safety import SafetyLimits
from tactex.control.va_ufic import VaUficParams
from tactex.errors import InputError
from tactex.report.cloud import plot_cloud
from tactex.report.html import cloud_html
from tactex.report.metrics import write_metrics
from tactex.report.series import plot_series
from tactex.tasks.clean_phases import CLEAN_PHASES

__all__ = [
    "CLEAN_METRIC_KEYS",
    "SUMMARY_COLUMNS",
    "WIPE_METRIC_KEYS",
    "RunReport",
    "missing_metric_keys",
    "run_kind",
    "safety_summary",
    "summary_table",
    "vision_round_trips",
    "write_clean_report",
    "write_index_html",
    "write_run_report",
    "write_wipe_report",
]

#: Curvature in both the PNG (matplotlib's coolwarm) and the page: blue low, red high.
CURVATURE_COLORSCALE = [[0.0, "rgb(59,76,192)"], [0.5, "rgb(221,221,221)"], [1.0, "rgb(180,4,38)"]]

#: Keys every ``tactex clean`` metrics.json holds (issue 6 metrics contract).
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
#: VA-UFIC Table I tank limits [J], used when the run's config does not carry VaUficParams.
DEFAULT_TANK_LIMITS = {
    "impedance": (VaUficParams().tank_i_lower, VaUficParams().tank_i_upper),
    "force": (VaUficParams().tank_f_lower, VaUficParams().tank_f_upper),
}
#: Target in red on grey (a zero-mass point must stay visible), as the explore reports.
DIRT_CMAP = "Reds"
DIRT_COLORSCALE = [[0.0, "lightgrey"], [1.0, "red"]]


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


def run_kind(result: Any) -> str:
    """'clean' or 'wipe', from the fields the result carries."""
    if hasattr(result, "profile") and hasattr(result, "explored"):
        return "wipe"
    if hasattr(result, "fields") and hasattr(result, "agent_path"):
        return "clean"
    raise InputError(
        f"cannot report a {type(result).__name__}: expected a CleanResult (fields, agent_path) "
        "or a WipeResult (profile, explored)"
    )


def missing_metric_keys(kind: str, metrics: Mapping[str, Any]) -> list[str]:
    """Contract keys absent from ``metrics`` (kind 'clean' or 'wipe')."""
    keys = {"clean": CLEAN_METRIC_KEYS, "wipe": WIPE_METRIC_KEYS}.get(kind)
    if keys is None:
        raise InputError(f"unknown run kind '{kind}'; valid: clean, wipe")
    return [k for k in keys if k not in metrics]


def write_run_report(
    result: Any, out_dir: str | Path, *, label: str | None = None, html_page: bool = True
) -> RunReport:
    """Write the run folder of a cleaning or wiping result (see the module docstring)."""
    if run_kind(result) == "clean":
        return write_clean_report(result, out_dir, label=label, html_page=html_page)
    return write_wipe_report(result, out_dir, label=label, html_page=html_page)


# --------------------------------------------------------------------------------------------- common


def _figure(n_rows: int = 1, height: float = 2.4, width: float = 7.5, sharex: bool = True):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height * n_rows + 0.6), dpi=110)
    FigureCanvasAgg(fig)
    axes = fig.subplots(n_rows, 1, sharex=sharex, squeeze=False)[:, 0]
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.ticklabel_format(axis="y", useOffset=False)  # an offset ("+9.999e-1") hides a flat curve
    return fig, axes


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")
    return path


def _series(result: Any, kind: str, required: Sequence[str]) -> dict[str, np.ndarray]:
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


def _write_common(result: Any, kind: str, out: Path, series: Mapping[str, np.ndarray], rep: RunReport) -> None:
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


def _finite_rows(path: np.ndarray | None) -> np.ndarray:
    if path is None:
        return np.zeros((0, 3))
    arr = np.asarray(path, dtype=np.float64).reshape(-1, 3)
    return arr[np.isfinite(arr).all(axis=1)]


def _try_plot(rep: RunReport, role: str, fn, *args, **kwargs) -> None:
    """A plot that cannot be drawn from this run's data becomes a note, not a lost report."""
    try:
        rep.files[role] = fn(*args, **kwargs)
    except InputError as exc:
        rep.notes.append(f"{role} plot skipped: {exc}")


# --------------------------------------------------------------------------------------------- clean


def _segments(mask: np.ndarray) -> list[tuple[int, int]]:
    """Index ranges [start, stop) where ``mask`` is true."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.flatnonzero(np.diff(m.astype(np.int8)))
    return list(zip(d[::2].tolist(), d[1::2].tolist(), strict=True))


def vision_round_trips(t: np.ndarray, phase: np.ndarray) -> np.ndarray:
    """(k, 2) [s] spans from each retract that is followed by another approach to the start of that approach: the
    visual re-measurements (TEC §VI-B: retract, move to the capture pose, capture, return) and the moves through
    the air without a view (a relocation, the move to the next island; :func:`trips_with_a_view` tells them
    apart)."""
    ph = np.rint(phase)
    approaches = [a for a, _ in _segments(ph == CLEAN_PHASES["approach"])]
    spans = []
    for a, _ in _segments(ph == CLEAN_PHASES["retract"]):
        nxt = [b for b in approaches if b > a]
        if nxt:
            spans.append((t[a], t[nxt[0]]))
    return np.asarray(spans, dtype=np.float64).reshape(-1, 2)


def trips_with_a_view(trips: np.ndarray, view_times_s: np.ndarray) -> np.ndarray:
    """Per lift-off-to-touch-down span (k, 2) [s], whether a camera view was taken in it (a trip to vision)
    or not (a move through the air: a relocation, or the task's move to the next island)."""
    times = np.asarray(view_times_s, dtype=np.float64).reshape(-1)
    return np.array([bool(np.any((times >= a) & (times <= b))) for a, b in np.reshape(trips, (-1, 2))], dtype=bool)


def contact_stretches(tcp_m: np.ndarray, in_contact: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """The TCP's points (M, 3) [m] while in contact (finite rows of ``tcp_m`` where ``in_contact``), and the
    indices of those points that start a new stretch after the tool was lifted (for a plot's flights)."""
    tcp = np.asarray(tcp_m, dtype=np.float64).reshape(-1, 3)
    contact = np.asarray(in_contact, dtype=bool)
    stretch = np.cumsum(contact & ~np.r_[False, contact[:-1]])  # which stretch in contact each row is in
    rows = np.flatnonzero(contact & np.isfinite(tcp).all(axis=1))  # a dropped sample does not end a stretch
    return tcp[rows], (np.flatnonzero(np.diff(stretch[rows]) > 0) + 1).tolist()


def _plot_dirt(s: Mapping[str, np.ndarray], trips: np.ndarray, times: np.ndarray | None, path: Path) -> Path:
    fig, (ax,) = _figure()
    ax.plot(s["t"], 100.0 * s["dirt_remaining"], color="C3", lw=1.5, label="dirt remaining (simulated surface)")
    # a lift-off followed by a touch-down is a trip to the camera when a view was taken in it, else a move
    # through the air (a relocation, or the task's move to the next island)
    vision = np.ones(len(trips), dtype=bool) if times is None else trips_with_a_view(trips, times)
    labelled = set()
    for (a, b), seen in zip(trips, vision, strict=True):
        name = "return to vision" if seen else "lift and move"
        ax.axvspan(a, b, color="C0" if seen else "C7", alpha=0.15, lw=0, label=None if name in labelled else name)
        labelled.add(name)
    for i, tv in enumerate([] if times is None else times):
        ax.axvline(tv, color="C0", ls="--", lw=1.0, label="vision update" if i == 0 else None)
    ax.set_ylim(0, 105)
    ax.set_ylabel("dirt remaining [%]")
    ax.set_xlabel("time [s]")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title("Dirt remaining")
    return _save(fig, path)


#: Labels and colours of the time-breakdown buckets (tactex.tasks.time_breakdown.BUCKETS).
TIME_BUCKETS = {
    "contact_dirt": ("contact on dirt", "C3"),
    "contact_clean": ("contact on clean surface", "C1"),
    "contact": ("contact (dirt not known)", "C1"),
    "explore_no_contact": ("exploring, contact lost", "C7"),
    "touch_down": ("touch-downs", "C4"),
    "transit": ("transit (camera → hover)", "C2"),
    "vision": ("vision (capture, trips)", "C0"),
    "lift_off": ("final lift-off", "C8"),
}


def _plot_time_breakdown(breakdown: Mapping[str, Any], t95: Any, path: Path,
                         to_95pct: Mapping[str, Any] | None = None) -> Path:
    """Horizontal stacked bars of where the time went [s]: the whole run, and (``to_95pct``) the time up to
    95 % removed, with that time marked."""
    def positive(b: Mapping[str, Any]) -> list[tuple[str, float]]:
        return [(k, float(v)) for k, v in b.items() if v is not None and float(v) > 0]

    parts = positive(breakdown)
    if not parts:
        raise InputError("the time breakdown is empty (no tick was accounted)")
    rows = [("whole run", parts)]
    if to_95pct:
        rows.append(("to 95 %", positive(to_95pct)))
    fig, (ax,) = _figure(height=2.2 + 0.5 * (len(rows) - 1))
    labelled: set[str] = set()
    for y, (_, row) in enumerate(rows):
        left = 0.0
        for key, v in row:
            label, color = TIME_BUCKETS.get(key, (key, "C9"))
            # the legend names each bucket once, with the whole run's duration
            name = f"{label}: {v:.1f} s" if key not in labelled else None
            labelled.add(key)
            ax.barh([-y], [v], height=0.6, left=left, color=color, label=name)
            left += v
    if t95 is not None:
        ax.axvline(float(t95), color="k", ls="--", lw=1.2, label=f"95 % removed at {float(t95):.1f} s")
    ax.set_ylim(-0.5 - (len(rows) - 1), 2.4)  # the legend sits above the bars
    ax.set_yticks([-y for y in range(len(rows))], [name for name, _ in rows] if len(rows) > 1 else [""])
    ax.set_xlabel("time [s] (bucket durations stacked, not in time order)")
    ax.legend(loc="upper center", fontsize=7, ncol=3, frameon=False)
    ax.set_title("Where the time went")
    return _save(fig, path)


def _plot_clean_force(s: Mapping[str, np.ndarray], force_n: float, path: Path) -> Path:
    fig, (ax,) = _figure(height=2.8)
    t, sp = s["t"], s["set_point_n"]
    active = sp > 0
    band_lo = np.where(active, 0.8 * sp, np.nan)
    band_hi = np.where(active, 1.2 * sp, np.nan)
    ax.fill_between(t, band_lo, band_hi, color="C2", alpha=0.25, lw=0, label="set point ±20 %")
    ax.plot(t, np.where(active, sp, np.nan), color="C2", lw=1.0, label="set point")
    ax.axhline(2.0 * force_n, color="C3", ls="--", lw=1.0, label="2× set point")
    ax.plot(t, s["force_z_n"], color="C0", lw=0.9, label="normal force (F/T, tool z)")
    top = max(2.6 * force_n, float(np.nanpercentile(s["force_z_n"], 99.5)) * 1.1 if t.size else 0.0)
    ax.set_ylim(min(-1.0, float(np.nanmin(s["force_z_n"], initial=0.0))), top)
    ax.set_ylabel("force [N]")
    ax.set_xlabel("time [s]")
    ax.legend(loc="upper right", fontsize=7, ncol=2)
    ax.set_title("Contact force (peaks above the axis are in metrics: max_contact_force_n)")
    return _save(fig, path)


def _phase_changes(metrics: Mapping[str, Any]) -> np.ndarray | None:
    """The run's recorded phase changes as (k, 2) rows (t [s], phase id), or None without them."""
    changes = metrics.get("phase_changes")
    return np.asarray(changes, dtype=np.float64).reshape(-1, 2) if changes else None


def _phase_spans(s: Mapping[str, np.ndarray], ch: np.ndarray | None) -> dict[int, list[tuple[float, float]]]:
    """(start, duration) [s] of each phase: from the recorded phase changes ``ch`` when the run has them
    (a capture takes no tick and an approach a few ms, which 100 Hz samples miss), else from the series."""
    t = s["t"]
    spans: dict[int, list[tuple[float, float]]] = {}
    if ch is not None:
        t_end = float(t[-1]) if t.size else float(ch[-1, 0])
        for (ta, pa), tb in zip(ch, [*ch[1:, 0], t_end], strict=True):
            spans.setdefault(int(pa), []).append((float(ta), float(tb - ta)))
        return spans
    phase = np.rint(s["phase"])
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.01
    for pid in np.unique(phase).astype(int):
        spans[pid] = [(t[a], t[b - 1] - t[a] + dt) for a, b in _segments(phase == pid)]
    return spans


def _plot_phases(s: Mapping[str, np.ndarray], path: Path, ch: np.ndarray | None = None) -> Path:
    fig, (ax,) = _figure(height=1.5)
    names = list(CLEAN_PHASES)
    spans = _phase_spans(s, ch)
    t = s["t"]
    visible = 0.002 * (float(t[-1] - t[0]) if t.size > 1 else 1.0)  # a zero-length phase still shows
    for i, name in enumerate(names):
        bars = [(a, max(d, visible)) for a, d in spans.get(CLEAN_PHASES[name], [])]
        ax.broken_barh(bars, (i - 0.4, 0.8), color=f"C{i}")
    ax.set_yticks(range(len(names)), names)
    ax.set_xlabel("time [s]")
    ax.set_title("Phases of the cleaning program")
    return _save(fig, path)


def _ergodicity(metrics: Mapping[str, Any]) -> np.ndarray:
    """(t, ε) pairs, with a NaN row at each vision update: the samples after it are measured against
    a new target, so the curve breaks there instead of joining two different quantities."""
    pairs = metrics.get("ergodicity") or []
    arr = np.asarray(pairs, dtype=np.float64)
    if arr.size == 0:
        return np.zeros((0, 2))
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise InputError(f"metrics 'ergodicity' must be (t, value) pairs, got shape {arr.shape}")
    updates = np.asarray(metrics.get("vision_update_times_s") or [], dtype=np.float64)
    breaks = [t for t in updates if arr[0, 0] < t <= arr[-1, 0]]
    if breaks:
        arr = np.vstack([arr, [[t, np.nan] for t in breaks]])
        arr = arr[np.argsort(arr[:, 0], kind="stable")]
    return arr


def _start_report(
    result: Any, kind: str, out_dir: str | Path, label: str | None, keys: tuple[str, ...]
) -> tuple[dict[str, np.ndarray], Path, RunReport]:
    """Series, folder and report of a run, with the files every run folder has already written."""
    series = _series(result, kind, keys)
    metrics = dict(result.metrics)
    label = label or str(metrics.get("baseline") or getattr(result.config, "baseline", "") or "tactex")
    out = Path(out_dir)
    rep = RunReport(out_dir=out, kind=kind, label=label, metrics=metrics)
    _write_common(result, kind, out, series, rep)
    return series, out, rep


def write_clean_report(
    result: Any, out_dir: str | Path, *, label: str | None = None, html_page: bool = True
) -> RunReport:
    """Run folder of a cleaning result (TEC §V-A); see the module docstring for the files."""
    s, out, rep = _start_report(result, "clean", out_dir, label,
                                ("t", "phase", "tcp", "force_z_n", "set_point_n", "dirt_remaining"))
    metrics, cfg, label = rep.metrics, result.config, rep.label

    cloud = result.cloud
    fields = {k: np.asarray(v, dtype=np.float64) for k, v in (result.fields or {}).items()}
    agent = _finite_rows(result.agent_path)
    explore = np.rint(s["phase"]) == CLEAN_PHASES["explore"]
    tcp_contact, lifted = contact_stretches(s["tcp"], explore)
    np.savez_compressed(
        out / "cloud.npz", points=cloud.points, agent_path=agent, tcp_path_contact=tcp_contact,
        tcp_path_contact_lifted=np.asarray(lifted, dtype=np.intp),  # rows that start a stretch after a lift-off
        **{f"field_{k}": v for k, v in fields.items()},
    )
    rep.files["cloud_data"] = out / "cloud.npz"

    force_n = float(metrics.get("force_set_point_n", getattr(cfg, "force_n", np.nan)))
    ch = _phase_changes(metrics)  # exact phase boundaries; the 100 Hz series can miss a short approach
    trips = vision_round_trips(s["t"], s["phase"]) if ch is None else vision_round_trips(ch[:, 0], ch[:, 1])
    times = metrics.get("vision_update_times_s")
    times = None if times is None else np.asarray(times, dtype=np.float64).reshape(-1)
    shown = len(trips) if times is None else len(times)
    if int(metrics.get("vision_updates", shown)) != shown:
        rep.notes.append(f"dirt plot marks {shown} vision updates, metrics count {metrics.get('vision_updates')}")
    rep.files["dirt_png"] = _plot_dirt(s, trips, times, out / "dirt.png")
    rep.files["force_png"] = _plot_clean_force(s, force_n, out / "force.png")
    rep.files["phases_png"] = _plot_phases(s, out / "phases.png", ch)
    if metrics.get("time_breakdown_s"):
        _try_plot(rep, "time_breakdown_png", _plot_time_breakdown, metrics["time_breakdown_s"],
                  metrics.get("time_to_95pct_s"), out / "time_breakdown.png",
                  to_95pct=metrics.get("time_breakdown_to_95pct_s"))
    named = {"dirt (first capture)": fields.get("target_initial", cloud.target)}
    for key, name in (("target", "dirt (last capture)"), ("coverage", "coverage"), ("potential", "potential")):
        if key in fields:
            named[name] = fields[key]
    cmaps = {"dirt (first capture)": DIRT_CMAP, "dirt (last capture)": DIRT_CMAP}
    _try_plot(rep, "cloud_png", plot_cloud, cloud.points, named, out / "cloud.png",
              trajectory=agent if len(agent) else None, title=f"{label}: fields with the agent path", cmaps=cmaps)
    _try_plot(rep, "tcp_png", plot_cloud, cloud.points, {"dirt (first capture)": named["dirt (first capture)"]},
              out / "cloud_tcp.png", trajectory=tcp_contact if len(tcp_contact) else None, flights=lifted,
              title=f"{label}: TCP path in contact (dashed: lifted between)", cmaps=cmaps)
    erg = _ergodicity(metrics)
    if len(erg):
        rep.files["ergodicity_png"] = plot_series(
            {"normalised ergodicity [-]": erg[:, 1]}, out / "ergodicity.png", x=erg[:, 0], xlabel="time [s]",
            title="Ergodicity (TEC eq. 48); the line breaks at each vision update (a new target)",
        )
    else:
        why = ("the raster baseline has no target distribution to compare" if metrics.get("baseline") == "raster"
               else "the run ended before any exploration in contact")
        rep.notes.append(f"no ergodicity series ({why})")
    if html_page:
        scales = {"dirt (first capture)": DIRT_COLORSCALE, "dirt (last capture)": DIRT_COLORSCALE}
        path = tcp_contact if len(tcp_contact) else (agent if len(agent) else None)
        page = cloud_html(cloud.points, named, out / "report.html", trajectory=path, colorscales=scales,
                          title=f"tactex clean — {label} ({metrics.get('object', getattr(cfg, 'object_name', ''))})")
        rep.files["html"] = _append_sections(page, rep)
    return rep


# --------------------------------------------------------------------------------------------- wipe


def _tank_limits(cfg: Any, metrics: Mapping[str, Any]) -> dict[str, tuple[float, float]]:
    """(lower, upper) tank energies [J]: from the metrics (``tank_impedance_limits_j``, ``tank_force_limits_j``),
    else from VaUficParams inside the config, else VA-UFIC Table I."""
    limits = dict(DEFAULT_TANK_LIMITS)
    if "tank_impedance_limits_j" in metrics and "tank_force_limits_j" in metrics:
        lim_i, lim_f = metrics["tank_impedance_limits_j"], metrics["tank_force_limits_j"]
        return {"impedance": (float(lim_i[0]), float(lim_i[1])), "force": (float(lim_f[0]), float(lim_f[1]))}
    if dataclasses.is_dataclass(cfg):
        for f in dataclasses.fields(cfg):
            v = getattr(cfg, f.name)
            if hasattr(v, "tank_i_upper") and hasattr(v, "tank_f_upper"):
                limits = {"impedance": (float(v.tank_i_lower), float(v.tank_i_upper)),
                          "force": (float(v.tank_f_lower), float(v.tank_f_upper))}
    return limits


def _plot_profile(s: Mapping[str, np.ndarray], profile: Mapping[str, Any], path: Path) -> Path:
    fig, (ax,) = _figure(height=3.0)
    y, z = np.asarray(profile["y_m"], float), np.asarray(profile["z_m"], float)
    if y.shape != z.shape or y.ndim != 1:
        raise InputError(f"profile y_m and z_m must be 1-D of equal length, got {y.shape} and {z.shape}")
    ax.plot(y, z, color="0.3", lw=2.0, label="surface")
    tcp = s["tcp_object"]
    contact = s["in_contact"] > 0.5
    ax.plot(tcp[:, 1], tcp[:, 2], color="C0", lw=0.8, alpha=0.6, label="TCP")
    ax.plot(tcp[:, 1], np.where(contact, tcp[:, 2], np.nan), color="C3", lw=1.4, label="TCP in contact")
    ax.set_xlabel("y (object frame) [m]")
    ax.set_ylabel("z (object frame) [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=8)
    ax.set_title("VA-UFIC Fig. 2: TCP trajectory over the surface")
    return _save(fig, path)


def _plot_rho(s: Mapping[str, np.ndarray], path: Path) -> Path:
    fig, axes = _figure(2, height=1.8)
    axes[0].plot(s["t"], s["rho_align"], color="C0")
    axes[0].set_ylabel("ρ_align [-]")
    axes[1].plot(s["t"], s["rho_frc"], color="C1")
    axes[1].set_ylabel("ρ_frc [-]")
    axes[1].set_xlabel("time [s]")
    axes[0].set_title("VA-UFIC Fig. 3a: contact alignment and force shaping")
    return _save(fig, path)


def _plot_motion(s: Mapping[str, np.ndarray], path: Path) -> Path:
    fig, axes = _figure(3, height=1.6)
    for i, ax in enumerate(axes):
        ax.plot(s["t"], s["desired"][:, i], color="C2", lw=1.4, label="desired")
        ax.plot(s["t"], s["tcp"][:, i], color="C0", lw=0.9, label="actual")
        ax.set_ylabel(f"{'xyz'[i]} [m]")
    axes[0].legend(fontsize=8, loc="upper right")
    axes[-1].set_xlabel("time [s]")
    axes[0].set_title("VA-UFIC Fig. 3b: desired vs actual motion (world frame)")
    return _save(fig, path)


def _plot_wipe_force(s: Mapping[str, np.ndarray], path: Path) -> Path:
    fig, (ax,) = _figure(height=2.6)
    ax.plot(s["t"], s["force_set_n"], color="C2", lw=1.4, label="desired")
    ax.plot(s["t"], s["force_z_n"], color="C0", lw=0.9, label="measured (tool z)")
    ax.set_ylabel("force [N]")
    ax.set_xlabel("time [s]")
    ax.legend(fontsize=8)
    ax.set_title("VA-UFIC Fig. 3c: desired vs measured force")
    return _save(fig, path)


def _plot_tanks(s: Mapping[str, np.ndarray], limits: Mapping[str, tuple[float, float]], path: Path) -> Path:
    fig, axes = _figure(2, height=1.8)
    for ax, key, name in ((axes[0], "tank_i_energy_j", "impedance"), (axes[1], "tank_f_energy_j", "force")):
        lo, hi = limits[name]
        ax.plot(s["t"], s[key], color="C0", label="energy")
        ax.axhline(lo, color="C3", ls="--", lw=1.0, label="limits")
        ax.axhline(hi, color="C3", ls="--", lw=1.0)
        ax.set_ylabel(f"{name} tank [J]")
    axes[0].legend(fontsize=8, loc="upper right")
    axes[-1].set_xlabel("time [s]")
    axes[0].set_title("VA-UFIC Fig. 3d: energy tanks")
    return _save(fig, path)


def write_wipe_report(
    result: Any, out_dir: str | Path, *, label: str | None = None, html_page: bool = True
) -> RunReport:
    """Run folder of a wiping result (VA-UFIC §III); see the module docstring for the files."""
    keys = ("t", "tcp", "desired", "force_z_n", "force_set_n", "in_contact", "rho_align", "rho_frc",
            "tank_i_energy_j", "tank_f_energy_j", "tcp_object")
    s, out, rep = _start_report(result, "wipe", out_dir, label, keys)
    metrics, cfg, label = rep.metrics, result.config, rep.label

    explored = result.explored
    pts = np.asarray(explored.points if explored is not None else np.zeros((0, 3)), dtype=np.float64).reshape(-1, 3)
    curv = np.asarray(result.explored_curvature, dtype=np.float64).reshape(-1)
    if curv.shape[0] != pts.shape[0]:
        raise InputError(f"explored_curvature has {curv.shape[0]} values for {pts.shape[0]} explored points")
    contact = s["in_contact"] > 0.5
    tcp_contact = _finite_rows(s["tcp"][contact])
    profile = {k: np.asarray(v, dtype=np.float64) for k, v in dict(result.profile).items()}
    np.savez_compressed(out / "cloud.npz", explored_points=pts, explored_curvature=curv, tcp_path_contact=tcp_contact,
                        **{f"profile_{k}": v for k, v in profile.items()})
    rep.files["cloud_data"] = out / "cloud.npz"
    if explored is not None and len(explored) > 0:  # what `tactex explore` loads (normals, curvature)
        from tactex.pointcloud.io import save_ply

        whole = explored if explored.n_target else explored.with_target(np.ones(len(explored)))  # all of it
        rep.files["explored_ply"] = save_ply(whole, out / "explored.ply", extra={"curvature": curv})

    _try_plot(rep, "fig2_png", _plot_profile, s, profile, out / "fig2_profile.png")
    rep.files["fig3a_png"] = _plot_rho(s, out / "fig3a_alignment.png")
    rep.files["fig3b_png"] = _plot_motion(s, out / "fig3b_motion.png")
    rep.files["fig3c_png"] = _plot_wipe_force(s, out / "fig3c_force.png")
    rep.files["fig3d_png"] = _plot_tanks(s, _tank_limits(cfg, metrics), out / "fig3d_tanks.png")
    if len(pts):
        _try_plot(rep, "explored_png", plot_cloud, pts, {"curvature l_s [-]": curv}, out / "explored.png",
                  trajectory=tcp_contact if len(tcp_contact) else None,
                  title=f"{label}: explored contact points, curvature l_s (VA-UFIC eq. 16)",
                  cmaps={"curvature l_s [-]": "coolwarm"})
    else:
        rep.notes.append("no explored points (the tool never touched the surface): no curvature plot")
    if html_page:
        if len(pts):
            page = cloud_html(pts, {"curvature l_s [-]": curv}, out / "report.html",
                              trajectory=tcp_contact if len(tcp_contact) else None,
                              colorscales={"curvature l_s [-]": CURVATURE_COLORSCALE}, title=f"tactex wipe — {label}")
        else:
            page = out / "report.html"
            page.write_text(f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>tactex wipe — "
                            f"{html.escape(label)}</title></head><body><h1>tactex wipe — {html.escape(label)}</h1>"
                            "</body></html>\n")
        rep.files["html"] = _append_sections(page, rep)
    return rep


# --------------------------------------------------------------------------------------------- html + tables


def _fmt(value: Any) -> str:
    if isinstance(value, bool) or value is None:
        return str(value)
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return "nan" if not math.isfinite(value) else f"{value:.4g}"
    if isinstance(value, Mapping):
        return ", ".join(f"{k} {_fmt(v)}" for k, v in value.items())
    if isinstance(value, (list, tuple)) and all(isinstance(v, (int, float, np.number)) for v in value):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    return str(value)


def _metrics_table_html(metrics: Mapping[str, Any]) -> str:
    rows = []
    for k, v in metrics.items():
        if isinstance(v, (list, tuple)) and len(v) > 6:
            continue  # long series are in the plots and metrics.json
        rows.append(f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(_fmt(v))}</td></tr>")
    return "<table class='tx'>" + "".join(rows) + "</table>"


_CSS = ("<style>.tx{border-collapse:collapse;font:13px sans-serif}.tx td,.tx th{border:1px solid #ccc;"
        "padding:3px 8px;text-align:left}.txs{font:14px sans-serif;margin:12px}.txs img{max-width:100%}</style>")


def _append_sections(page: Path, rep: RunReport) -> Path:
    """Add the metrics, the notes and the PNGs (base64, so the page is one self-contained file)."""
    parts = [_CSS, "<div class='txs'>", f"<h2>{html.escape(rep.kind)} — {html.escape(rep.label)}</h2>",
             _metrics_table_html(rep.metrics)]
    if rep.notes:
        parts.append("<ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in rep.notes) + "</ul>")
    for role, path in rep.files.items():
        if role.endswith("_png"):
            data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
            parts.append(f"<h3>{html.escape(Path(path).name)}</h3><img alt='{html.escape(role)}' "
                         f"src='data:image/png;base64,{data}'>")
    parts.append("<p>Files: " + ", ".join(html.escape(Path(p).name) for r, p in rep.files.items()
                                          if r != "html") + "</p></div>")
    text = page.read_text()
    cut = text.rfind("</body>")
    section = "\n".join(parts)
    page.write_text(text[:cut] + section + text[cut:] if cut >= 0 else text + section)
    return page


#: Columns of the summary table: (header, metric key, formatter).
def _pct(v: Any) -> str:
    return f"{100 * float(v):.1f} %"


def _num(fmt: str):
    return lambda v: format(float(v), fmt)


def _xyz_mm(v: Any) -> str:
    arr = np.asarray(v, dtype=np.float64)
    return "–" if not np.isfinite(arr).any() else "/".join(f"{1e3 * x:.1f}" for x in arr)


def _minmax(v: Any) -> str:
    lo, hi = (float("nan") if v.get(k) is None else float(v[k]) for k in ("min", "max"))
    return "–" if not (math.isfinite(lo) and math.isfinite(hi)) else f"{lo:.2f}–{hi:.2f}"


SUMMARY_COLUMNS: tuple[tuple[str, str, Any], ...] = (
    ("dirt removed", "dirt_removed_fraction", _pct),
    ("force in ±20 %", "force_within_20pct_fraction", _pct),
    ("max force [N]", "max_contact_force_n", _num(".1f")),
    ("vision updates", "vision_updates", _num(".0f")),
    ("95 % removed at [s]", "time_to_95pct_s", _num(".1f")),
    ("force MAE [N]", "force_mae_n", _num(".2f")),
    ("force RMSE [N]", "force_rmse_n", _num(".2f")),
    # the same samples for every controller (all contact ticks): motion_mae_m is VA-UFIC's aligned
    # subset (ρ_align = 1), which a baseline without ρ_align cannot have
    ("motion MAE in contact x/y/z [mm]", "motion_mae_all_contact_m", _xyz_mm),
    ("tank imp. [J]", "tank_impedance_energy_j", _minmax),
    ("tank force [J]", "tank_force_energy_j", _minmax),
    ("explore [s]", "explore_time_s", _num(".1f")),
    ("contact", "contact_fraction", _pct),
    ("sim time [s]", "sim_time_s", _num(".1f")),
    ("wall [s]", "wall_time_s", _num(".1f")),
)


def _summary_cells(rows: Sequence[tuple[str, Mapping[str, Any]]]) -> tuple[list[str], list[list[str]]]:
    cols = [c for c in SUMMARY_COLUMNS if any(c[1] in m and m[c[1]] is not None for _, m in rows)]
    header = ["run"] + [c[0] for c in cols]
    body = []
    for name, m in rows:
        cells = [str(name)]
        for _, key, fmt in cols:
            v = m.get(key)
            try:
                cells.append("–" if v is None else fmt(v))
            except (TypeError, ValueError, KeyError):
                cells.append(_fmt(v))
        body.append(cells)
    return header, body


def _as_rows(rows: Mapping[str, Mapping[str, Any]] | Sequence[tuple[str, Mapping[str, Any]]]):
    items = list(rows.items()) if isinstance(rows, Mapping) else list(rows)
    for item in items:
        if not (isinstance(item, tuple) and len(item) == 2 and isinstance(item[1], Mapping)):
            raise InputError(f"summary rows must be (name, metrics mapping) pairs, got {item!r:.80}")
    return items


def safety_summary(metrics: Mapping[str, Any]) -> str | None:
    """What the safety layer did in a run, and why, as one line from ``metrics["safety_counts"]``
    (None when it never stepped in): a run that retreated or was clipped must say so where its
    results are read, not only in metrics.json."""
    counts = {k: int(v) for k, v in (metrics.get("safety_counts") or {}).items() if v}
    limits = metrics.get("safety_limits") or {}
    cap = float(limits.get("max_contact_force_n", SafetyLimits.max_contact_force))
    rate = float(limits.get("tau_rate_max_n_m_s", SafetyLimits.tau_rate_max))
    peak = metrics.get("max_contact_force_n", metrics.get("max_force_n"))  # clean: the magnitude; wipe: the normal
    peak_text = f", peak {float(peak):.1f} N" if isinstance(peak, (int, float)) and math.isfinite(peak) else ""
    said = {
        "force_limit": lambda n: f"retreated {n}× from a contact force above {cap:g} N{peak_text}",
        "wrench_lost": lambda n: f"lost the F/T sensor {n}× (backed off, then held until it was back)",
        "nan_wrench": lambda n: f"bridged {n} non-finite F/T reading(s) with the last finite one",
        "nan_state": lambda n: f"held {n}× on a non-finite robot state",
        "controller_fault": lambda n: f"held {n}× on a controller fault",
        "nan_torque": lambda n: f"held {n}× on a non-finite controller torque",
        "joint_limit": lambda n: f"pushed back from a joint limit {n}×",
        "torque_limit": lambda n: f"saturated the torque at the joint limits on {n} tick(s)",
        "torque_rate_limit": lambda n: f"clipped the torque rate ({rate:g} N·m/s) on {n} tick(s)",
    }
    parts = [say(counts[kind]) for kind, say in said.items() if counts.get(kind)]
    parts += [f"{kind} {n}×" for kind, n in counts.items() if kind not in said and kind != "retreat_end"]
    return "; ".join(parts) if parts else None


def summary_table(rows: Mapping[str, Mapping[str, Any]] | Sequence[tuple[str, Mapping[str, Any]]]) -> str:
    """A fixed-width text table of runs side by side (tactex and its baselines).

    ``rows``: {run name: metrics} or [(run name, metrics)]; the columns are the known metrics that at
    least one run has (clean: dirt removed, force within ±20 %, max force, …; wipe: force MAE/RMSE,
    motion MAE per axis, tank energy ranges, …); a run without a metric shows "–".
    """
    items = _as_rows(rows)
    if not items:
        raise InputError("summary_table needs at least one run")
    header, body = _summary_cells(items)
    widths = [max(len(r[i]) for r in [header, *body]) for i in range(len(header))]

    def line(cells: list[str]) -> str:
        pairs = enumerate(zip(cells, widths, strict=True))
        return "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in pairs)

    rule = "  ".join("-" * w for w in widths)
    return "\n".join([line(header), rule, *(line(r) for r in body)])


def write_index_html(path: str | Path, reports: Sequence[RunReport], *, title: str = "tactex runs") -> Path:
    """One page linking the run folders' reports, with a summary table per kind of run."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    parts = ["<!DOCTYPE html><html><head><meta charset='utf-8'>", f"<title>{html.escape(title)}</title>", _CSS,
             "</head><body><div class='txs'>", f"<h1>{html.escape(title)}</h1>"]
    for kind in dict.fromkeys(r.kind for r in reports):
        group = [r for r in reports if r.kind == kind]
        header, body = _summary_cells([(r.label, r.metrics) for r in group])
        parts.append(f"<h2>{html.escape(kind)}</h2><table class='tx'><tr>"
                     + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>")
        for r, cells in zip(group, body, strict=True):
            link = r.html.relative_to(out.parent).as_posix() if r.html and r.html.is_relative_to(out.parent) else None
            first = f"<a href='{html.escape(link)}'>{html.escape(cells[0])}</a>" if link else html.escape(cells[0])
            parts.append("<tr><td>" + first + "</td>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells[1:])
                         + "</tr>")
        parts.append("</table>")
        for r in group:
            if r.notes:
                notes = "; ".join(html.escape(n) for n in r.notes)
                parts.append(f"<p><b>{html.escape(r.label)}</b>: {notes}</p>")
    parts.append("<h2>Metrics (JSON)</h2><pre>" + html.escape(json.dumps(
        {f"{r.kind}/{r.label}": {k: v for k, v in to_jsonable(r.metrics).items() if k != "ergodicity"}
         for r in reports}, indent=1)) + "</pre>")
    parts.append("</div></body></html>\n")
    out.write_text("\n".join(parts))
    return out
