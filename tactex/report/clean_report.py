"""The run folder of a cleaning run (TEC §V-A): the dirt, force, phase and time-breakdown plots, the
cloud's fields with the agent's and the TCP's paths, the ergodicity series and the page."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from tactex.errors import InputError
from tactex.report.cloud import plot_cloud
from tactex.report.html import cloud_html
from tactex.report.run_common import RunReport, figure, finite_rows, save_png, start_report, try_plot
from tactex.report.run_pages import add_sections, plain_page
from tactex.report.series import plot_series
from tactex.tasks.clean.config import RASTER_BASELINES
from tactex.tasks.clean_phases import CLEAN_PHASES

__all__ = [
    "DIRT_CMAP",
    "DIRT_COLORSCALE",
    "TIME_BUCKETS",
    "contact_stretches",
    "trips_with_a_view",
    "vision_round_trips",
    "write_clean_report",
]

#: Target in red on grey (a zero-mass point must stay visible), as the explore reports.
DIRT_CMAP = "Reds"
DIRT_COLORSCALE = [[0.0, "lightgrey"], [1.0, "red"]]


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
    fig, (ax,) = figure()
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
    return save_png(fig, path)


#: Labels and colours of the time-breakdown buckets (tactex.tasks.clean.time_breakdown.BUCKETS).
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
    fig, (ax,) = figure(height=2.2 + 0.5 * (len(rows) - 1))
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
    return save_png(fig, path)


def _plot_clean_force(s: Mapping[str, np.ndarray], force_n: float, path: Path) -> Path:
    fig, (ax,) = figure(height=2.8)
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
    return save_png(fig, path)


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
    fig, (ax,) = figure(height=1.5)
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
    return save_png(fig, path)


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


def write_clean_report(
    result: Any, out_dir: str | Path, *, label: str | None = None, html_page: bool = True
) -> RunReport:
    """Run folder of a cleaning result (TEC §V-A); see the module docstring for the files."""
    s, out, rep = start_report(result, "clean", out_dir, label,
                                ("t", "phase", "tcp", "force_z_n", "set_point_n", "dirt_remaining"))
    metrics, cfg, label = rep.metrics, result.config, rep.label

    cloud = result.cloud
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
        try_plot(rep, "time_breakdown_png", _plot_time_breakdown, metrics["time_breakdown_s"],
                  metrics.get("time_to_95pct_s"), out / "time_breakdown.png",
                  to_95pct=metrics.get("time_breakdown_to_95pct_s"))
    erg = _ergodicity(metrics)
    if len(erg):
        rep.files["ergodicity_png"] = plot_series(
            {"normalised ergodicity [-]": erg[:, 1]}, out / "ergodicity.png", x=erg[:, 0], xlabel="time [s]",
            title="Ergodicity (TEC eq. 48); the line breaks at each vision update (a new target)",
        )
    else:
        why = (f"the {metrics['baseline'].replace('_', ' ')} baseline has no target distribution to compare"
               if metrics.get("baseline") in RASTER_BASELINES else "the run ended before any exploration in contact")
        rep.notes.append(f"no ergodicity series ({why})")
    title = f"tactex clean — {label} ({metrics.get('object', getattr(cfg, 'object_name', ''))})"
    if cloud is None:  # a run on a robot stopped before its first capture was made
        rep.notes.append("no cloud: the run stopped before its first capture was made (no cloud figures)")
        page = plain_page(out / "report.html", title) if html_page else None
    else:
        page = _cloud_files(result, s, out, rep, label, title, html_page)
    if page is not None:
        rep.files["html"] = add_sections(page, rep, title)
    return rep


def _cloud_files(result: Any, s: Mapping[str, np.ndarray], out: Path, rep: RunReport, label: str, title: str,
                 html_page: bool) -> Path | None:
    """The captured cloud's files: cloud.npz, its fields and paths as PNGs, and the 3-D page (None: no page)."""
    cloud = result.cloud
    fields = {k: np.asarray(v, dtype=np.float64) for k, v in (result.fields or {}).items()}
    agent = finite_rows(result.agent_path)
    explore = np.rint(s["phase"]) == CLEAN_PHASES["explore"]
    tcp_contact, lifted = contact_stretches(s["tcp"], explore)
    np.savez_compressed(
        out / "cloud.npz", points=cloud.points, agent_path=agent, tcp_path_contact=tcp_contact,
        tcp_path_contact_lifted=np.asarray(lifted, dtype=np.intp),  # rows that start a stretch after a lift-off
        **{f"field_{k}": v for k, v in fields.items()},
    )
    rep.files["cloud_data"] = out / "cloud.npz"
    named = {"dirt (first capture)": fields.get("target_initial", cloud.target)}
    for key, name in (("target", "dirt (last capture)"), ("coverage", "coverage"), ("potential", "potential")):
        if key in fields:
            named[name] = fields[key]
    cmaps = {"dirt (first capture)": DIRT_CMAP, "dirt (last capture)": DIRT_CMAP}
    try_plot(rep, "cloud_png", plot_cloud, cloud.points, named, out / "cloud.png",
              trajectory=agent if len(agent) else None, title=f"{label}: fields with the agent path", cmaps=cmaps)
    try_plot(rep, "tcp_png", plot_cloud, cloud.points, {"dirt (first capture)": named["dirt (first capture)"]},
              out / "cloud_tcp.png", trajectory=tcp_contact if len(tcp_contact) else None, flights=lifted,
              title=f"{label}: TCP path in contact (dashed: lifted between)", cmaps=cmaps)
    if not html_page:
        return None
    scales = {"dirt (first capture)": DIRT_COLORSCALE, "dirt (last capture)": DIRT_COLORSCALE}
    path = tcp_contact if len(tcp_contact) else (agent if len(agent) else None)
    dirty = named["dirt (first capture)"] > 0
    if "dirt (last capture)" in named:
        dirty |= named["dirt (last capture)"] > 0
    return cloud_html(cloud.points, named, out / "report.html", trajectory=path, colorscales=scales, title=title,
                      keep=dirty, normals=cloud.normals)
