"""The pages and tables around the run folders: a run's page (its summary, notes and PNGs above its
interactive 3-D view), the terminal summary of tactex beside its baselines, the safety layer's summary
line, and one index page linking several runs."""

from __future__ import annotations

import base64
import html
import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tactex.config import to_jsonable
from tactex.control.safety import SafetyLimits
from tactex.errors import InputError
from tactex.report.run_common import RunReport

__all__ = ["SUMMARY_COLUMNS", "add_sections", "plain_page", "run_remarks", "safety_summary", "summary_table",
           "write_index_html"]


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


def plain_page(path: Path, title: str) -> Path:
    """An empty page titled ``title`` for :func:`add_sections`: a run's report with no cloud to show in 3-D."""
    path.write_text(f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title></head>"
                    "<body></body></html>\n")
    return path


_BODY = re.compile(r"<body[^>]*>", re.IGNORECASE)
_HEAD = re.compile(r"<head[^>]*>", re.IGNORECASE)


def _png_sections(rep: RunReport) -> list[str]:
    """The run's PNGs, each under its file name, inline (base64) so that the page is one self-contained file."""
    parts = []
    for role, path in rep.files.items():
        if role.endswith("_png"):
            data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
            parts.append(f"<h3>{html.escape(Path(path).name)}</h3><img alt='{html.escape(role)}' "
                         f"src='data:image/png;base64,{data}'>")
    return parts


def add_sections(page: Path, rep: RunReport, title: str) -> Path:
    """Lay a run's page out in the order it is read: the title, the summary of its metrics (all of them folded
    below), the notes, the PNGs, then the page's 3-D view (a window-filling figure: above the rest, it would
    hide them behind a scroll), then the list of the run's files."""
    notes = [*rep.notes, *(f"{topic}: {said}" for topic, said in run_remarks(rep.metrics))]
    top = [_CSS, "<div class='txs'>", f"<h1>{html.escape(title)}</h1>", _summary_html([(rep.label, rep.metrics)]),
           "<details style='margin-top:6px'><summary><b>All metrics</b></summary>"
           f"{_metrics_table_html(rep.metrics)}</details>"]
    if notes:
        top.append("<ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in notes) + "</ul>")
    top += _png_sections(rep)
    text = page.read_text(encoding="utf-8")
    if "plotly-graph-div" in text:
        top.append("<h2>3-D view</h2><p>Drag to turn, scroll to zoom; the menu at its top left changes the "
                   "colouring.</p>")
    top.append("</div>")
    files = ", ".join(html.escape(Path(p).name) for r, p in rep.files.items() if r != "html")
    bottom = f"<div class='txs'><p>Files: {files}</p></div>"
    body = _BODY.search(text)
    head = _HEAD.search(text[:body.start()] if body else "")
    if head and "<title>" not in text[:body.start()]:  # the browser tab's name (plotly writes none)
        text = f"{text[:head.end()]}<title>{html.escape(title)}</title>{text[head.end():]}"
        body = _BODY.search(text)
    start = body.end() if body else 0
    cut = text.rfind("</body>")
    cut = cut if cut >= start else len(text)
    page.write_text(text[:start] + "\n".join(top) + text[start:cut] + bottom + text[cut:], encoding="utf-8")
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
    # the least time any method could take (tactex.tasks.clean.bound), and the time to 95 % over it
    ("bound [s]", "ideal_time_s", _num(".1f")),
    ("95 % / bound", "time_to_95pct_over_ideal", _num(".2f")),
    ("force MAE [N]", "force_mae_n", _num(".2f")),
    ("force RMSE [N]", "force_rmse_n", _num(".2f")),
    # VA-UFIC's aligned contact (ρ_align = 1), the paper's §IV figure; a baseline without ρ_align has none
    ("motion MAE aligned x/y/z [mm]", "motion_mae_m", _xyz_mm),
    # the same samples for every controller: all contact ticks, the alignment transient included
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


def _summary_html(rows: Sequence[tuple[str, Mapping[str, Any]]], links: Sequence[str | None] = ()) -> str:
    """The summary table's columns (:data:`SUMMARY_COLUMNS`) as an HTML table, a run's name linked to ``links``."""
    header, body = _summary_cells(rows)
    parts = ["<table class='tx'><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>"]
    for i, cells in enumerate(body):
        link = links[i] if i < len(links) else None
        first = f"<a href='{html.escape(link)}'>{html.escape(cells[0])}</a>" if link else html.escape(cells[0])
        parts.append("<tr><td>" + first + "</td>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells[1:]) + "</tr>")
    return "".join(parts) + "</table>"


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
    # the force's magnitude, as the safety layer judges it (clean: max_contact_force_n; wipe: max_force_norm_n; a
    # wipe recorded before it had only the normal force's peak)
    peak = metrics.get("max_contact_force_n", metrics.get("max_force_norm_n", metrics.get("max_force_n")))
    peak_text = f", peak |F| {float(peak):.1f} N" if isinstance(peak, (int, float)) and math.isfinite(peak) else ""
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
    if parts and metrics.get("dry_run"):  # the arm held still on its brakes while the controller chased the task
        parts.insert(0, "dry run, on torques computed but not sent")
    return "; ".join(parts) if parts else None


#: Gap [m] between the motion MAE over all contact and the aligned one, on any axis, above which a
#: summary says where the difference comes from.
ALIGNMENT_GAP_M = 1e-3


def alignment_summary(metrics: Mapping[str, Any]) -> str | None:
    """One line on the wipe's alignment transient when it weighs on the motion error (None otherwise): the
    motion MAE over all contact counts the ticks from the first touch until the contact monitor aligned
    the tool (ρ_align = 1), during which the controller yields on purpose; the aligned MAE is the figure
    of the paper's §IV and of the bench. A short run is dominated by that transient."""
    every = np.asarray(metrics.get("motion_mae_all_contact_m", [np.nan] * 3), dtype=np.float64).reshape(-1)
    if every.shape != (3,) or not np.isfinite(every).all():
        return None
    aligned = np.asarray(metrics.get("motion_mae_m", [np.nan] * 3), dtype=np.float64).reshape(-1)
    touch, at = metrics.get("first_contact_s"), metrics.get("aligned_at_s")
    if aligned.shape != (3,) or not np.isfinite(aligned).all() or at is None:
        if "aligned_at_s" not in metrics:  # a controller without a contact monitor
            return None
        return (f"motion MAE in contact {_xyz_mm(every)} mm: the tool never aligned (ρ_align never reached 1), "
                "so no aligned error exists to compare with the paper's and the bench's")
    if float(np.max(every - aligned)) <= ALIGNMENT_GAP_M:
        return None
    when = f"first contact at {float(touch):.1f} s, " if isinstance(touch, (int, float)) else ""
    return (f"motion MAE in contact {_xyz_mm(every)} mm includes the alignment transient ({when}aligned at "
            f"{float(at):.1f} s); after alignment {_xyz_mm(aligned)} mm, the figure the paper (§IV) and the bench "
            "report")


def learning_summary(metrics: Mapping[str, Any]) -> str | None:
    """One line on what a re-planned wipe learned from its first pass (``replan.learned``), None for any other
    run: the size of the force and in-plane corrections it fed forward, or why it learned nothing."""
    learned = (metrics.get("replan") or {}).get("learned")
    if not isinstance(learned, Mapping):
        return None
    if learned.get("note"):
        return f"learned nothing from the first pass: {learned['note']}"
    try:
        rms = np.asarray(learned["offset_rms_m"], dtype=np.float64).reshape(2) * 1e3
        return (f"learned from the first pass (gain {float(learned['gain']):g}): force corrections "
                f"{float(learned['force_rms_n']):.2f} N RMS (largest {float(learned['force_max_abs_n']):.2f} N), "
                f"in-plane {rms[0]:.1f}/{rms[1]:.1f} mm RMS (tool x/y)")
    except (KeyError, TypeError, ValueError):
        return None


def policy_cut_summary(metrics: Mapping[str, Any]) -> str | None:
    """One line when a wipe's policy file is longer than the run (``--duration-s`` ended it first), None
    otherwise: the tail it did not run is easy to miss in the figures."""
    policy = metrics.get("policy") or {}
    own, ran = policy.get("own_duration_s"), policy.get("duration_s")
    if not (policy.get("file") and isinstance(own, (int, float)) and isinstance(ran, (int, float))):
        return None
    if not (math.isfinite(own) and own > ran + 1e-9):
        return None
    return (f"the run ended at --duration-s {ran:g} s, {own - ran:g} s before the policy's end ({own:g} s): "
            f"give --duration-s {own:g} to run all of it")


def run_remarks(metrics: Mapping[str, Any]) -> list[tuple[str, str]]:
    """What a run's last lines say beside its table, as (topic, line): the safety layer's interventions
    (:func:`safety_summary`), the wipe's alignment transient (:func:`alignment_summary`), what a re-planned
    wipe learned (:func:`learning_summary`), a policy file the run's duration cut short
    (:func:`policy_cut_summary`) and a clean's first leg in contact (a planned sweep over strokes, the explorer
    over a blob: ``first_leg``), each only when there is something to say."""
    said = (("safety layer", safety_summary(metrics)), ("motion", alignment_summary(metrics)),
            ("re-plan", learning_summary(metrics)), ("policy", policy_cut_summary(metrics)),
            ("first leg", metrics.get("first_leg") or ""))
    return [(topic, line) for topic, line in said if line]


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


def write_index_html(path: str | Path, reports: Sequence[RunReport], *, title: str = "tactex runs",
                     figure: str | Path | None = None, figure_notes: Sequence[str] = ()) -> Path:
    """One page linking the run folders' reports, with a summary table per kind of run.

    ``figure``: a PNG shown first, above the tables (a compare's overlay of its methods), linked by its path
    relative to the page; ``figure_notes``: one line each under it (the runs it could not draw)."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    parts = ["<!DOCTYPE html><html><head><meta charset='utf-8'>", f"<title>{html.escape(title)}</title>", _CSS,
             "</head><body><div class='txs'>", f"<h1>{html.escape(title)}</h1>"]
    if figure is not None:
        fig = Path(figure).resolve()
        root = out.parent.resolve()
        href = fig.relative_to(root).as_posix() if fig.is_relative_to(root) else fig.as_uri()
        parts.append(f"<p><img src='{html.escape(href)}' alt='{html.escape(fig.stem)}' style='max-width:100%'></p>")
    parts += [f"<p class='note'>{html.escape(n)}</p>" for n in figure_notes]
    for kind in dict.fromkeys(r.kind for r in reports):
        group = [r for r in reports if r.kind == kind]
        links = [r.html.relative_to(out.parent).as_posix() if r.html and r.html.is_relative_to(out.parent) else None
                 for r in group]
        parts.append(f"<h2>{html.escape(kind)}</h2>" + _summary_html([(r.label, r.metrics) for r in group], links))
        for r in group:
            if r.notes:
                notes = "; ".join(html.escape(n) for n in r.notes)
                parts.append(f"<p><b>{html.escape(r.label)}</b>: {notes}</p>")
    parts.append(_metrics_table(reports, out.parent))
    parts.append("</div></body></html>\n")
    out.write_text("\n".join(parts))
    return out


def _cell(value: Any) -> str:
    """A metric as a person reads it: 4 significant digits, yes/no, '–' for none."""
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.4g}"
    return str(value)


def _metrics_table(reports: Sequence[RunReport], root: Path) -> str:
    """Every run's scalar metrics side by side (one row per metric), folded under a heading; lists and nested
    records stay in each run's metrics.json, which the table links."""
    runs = [(r, to_jsonable(r.metrics)) for r in reports]
    keys = list(dict.fromkeys(k for _, m in runs for k, v in m.items()
                              if v is None or isinstance(v, (bool, int, float, str))))
    head = "".join(f"<th>{html.escape(f'{r.kind}/{r.label}')}</th>" for r, _ in runs)
    rows = "".join("<tr><td>" + html.escape(k) + "</td>"
                   + "".join(f"<td>{html.escape(_cell(m.get(k)))}</td>" for _, m in runs) + "</tr>" for k in keys)
    links = []
    for r, _ in runs:
        folder = Path(r.out_dir).resolve()
        if (folder / "metrics.json").is_file() and folder.is_relative_to(root.resolve()):
            href = (folder / "metrics.json").relative_to(root.resolve()).as_posix()
            links.append(f"<a href='{html.escape(href)}'>{html.escape(r.label)}</a>")
    where = f" Lists and nested records: each run's metrics.json ({', '.join(links)})." if links else ""
    return (f"<details style='margin-top:1em'><summary><b>All metrics</b> ({len(keys)} per run)</summary><p>{where}</p>"
            f"<table class='tx'><tr><th>metric</th>{head}</tr>{rows}</table></details>")
