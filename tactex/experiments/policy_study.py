"""The table of a policy study (``tactex study`` over ``policy`` × ``object_name`` of the wipe): one
row per run with the figures the acceptance asks of any force-motion policy, each checked.

Bounds: force MAE against the policy's own set point ≤ 1.0 N (≤ 0.5 N for the sinusoid on the sine
panel, the paper's own case); aligned motion MAE ≤ 3 mm on each base axis, of the error without its
part along the tool axis; both energy tanks inside their limits for the whole run; no torque-rate clip;
no contact force above 2× the set point. A run that failed or was refused is a row too, with its reason.

The motion bound leaves out the tool axis because a force-motion policy gives no position there: along
it the force controller sets the position, and VA-UFIC puts the desired position inside the surface on
purpose (eq. 30), so that part of x − x_d is the force loop's depth, not a motion error. The base-frame
error with that part in is in the table beside it, and its count is given too."""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

__all__ = ["BOUNDS", "load_records", "policy_rows", "policy_table_markdown"]

#: Bounds of a run [N, m, -]: force MAE (the sinusoid on the sine panel has its own), motion MAE per
#: axis, peak force over the set point.
BOUNDS = {"force_mae_n": 1.0, "force_mae_sinusoid_panel_n": 0.5, "motion_mae_m": 0.003, "peak_over_set": 2.0}


def load_records(study_dir: str | Path) -> list[dict[str, Any]]:
    """The study's finished runs (``runs.jsonl``), the last record of each run id, in plan order."""
    recs: dict[str, dict[str, Any]] = {}
    for line in (Path(study_dir) / "runs.jsonl").read_text().splitlines():
        if line.strip():
            r = json.loads(line)
            recs[r["run_id"]] = r
    return sorted(recs.values(), key=lambda r: r["index"])


def _num(x: Any) -> float:
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) else math.nan


def _policy_name(path: str) -> str:
    return Path(path).stem if path else "sinusoid (built in)"


def policy_rows(records: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per run: policy, surface, the figures and a pass flag per bound (None when not measured)."""
    rows = []
    for r in records:
        f = r["factors"]
        row: dict[str, Any] = {"policy": _policy_name(f.get("policy", r["config"].get("policy", ""))),
                               "surface": f.get("object_name", r["config"].get("object_name", "sine_panel")),
                               "status": r["status"], "error": r.get("error", "")}
        m = r.get("metrics") or {}
        if r["status"] != "ok" or not m:
            rows.append(row)
            continue
        force_bound = BOUNDS["force_mae_sinusoid_panel_n"] if (row["policy"].startswith("sinusoid")
                                                               and row["surface"] == "sine_panel") \
            else BOUNDS["force_mae_n"]
        motion = [_num(x) for x in (m.get("motion_mae_m") or [math.nan] * 3)]
        tangent = [_num(x) for x in (m.get("motion_mae_tangent_m") or [math.nan] * 3)]
        ti, tf = m.get("tank_impedance_energy_j") or {}, m.get("tank_force_energy_j") or {}
        (li, ui), (lf, uf) = m.get("tank_impedance_limits_j", [math.nan] * 2), m.get("tank_force_limits_j",
                                                                                      [math.nan] * 2)
        tanks_ok = (_num(ti.get("min")) >= li and _num(ti.get("max")) <= ui
                    and _num(tf.get("min")) >= lf and _num(tf.get("max")) <= uf)
        row.update({
            "force_mae_n": _num(m.get("force_mae_n")), "force_bound_n": force_bound,
            "motion_mae_m": motion, "motion_mae_tangent_m": tangent,
            "motion_mae_tool_m": [_num(x) for x in m.get("motion_mae_tool_m") or [math.nan] * 3],
            "motion_mae_all_contact_m": [_num(x) for x in m.get("motion_mae_all_contact_m")
                                                                 or [math.nan] * 3],
            "tank_i_j": (_num(ti.get("min")), _num(ti.get("max"))), "tank_f_j": (_num(tf.get("min")),
                                                                                  _num(tf.get("max"))),
            "clip_ticks": int(m.get("torque_rate_clip_ticks", 0)),
            "peak_over_set": _num(m.get("max_force_over_set_point")),
            "contact_fraction": _num(m.get("contact_fraction_after_first_contact")),
            # a run of two passes (passes = 2): the first pass's figures, the second's above
            "first_pass": ((m.get("replan") or {}).get("first_pass") or {}),
        })
        row["ok"] = {
            "force": row["force_mae_n"] <= force_bound,
            "motion": all(x <= BOUNDS["motion_mae_m"] for x in tangent),  # NaN (never aligned) fails
            "tanks": tanks_ok, "clips": row["clip_ticks"] == 0,
            "peak": row["peak_over_set"] <= BOUNDS["peak_over_set"],
        }
        row["motion_with_tool_axis_ok"] = all(x <= BOUNDS["motion_mae_m"] for x in motion)
        rows.append(row)
    return rows


def _mark(ok: bool) -> str:
    return "✓" if ok else "✗"


def _mm(v: list[float]) -> str:
    return "/".join("–" if math.isnan(x) else f"{1e3 * x:.1f}" for x in v)


def policy_table_markdown(rows: list[dict[str, Any]]) -> str:
    """The rows as a Markdown table, then how many runs meet each bound and all of them."""
    head = ("| policy | surface | force MAE [N] (bound) | motion MAE aligned, without the tool-axis part x/y/z [mm] "
            "| with it x/y/z [mm] | motion MAE all contact x/y/z [mm] | impedance tank [J] | force tank [J] "
            "| torque-rate clips | peak / set point | all met |")
    lines = [head, "|" + "---|" * 11]
    ran = [r for r in rows if "ok" in r]
    for r in rows:
        if "ok" not in r:
            reason = (r["error"] or r["status"]).replace("|", "/").splitlines()[0]
            lines.append(f"| {r['policy']} | {r['surface']} | not run: {reason[:160]} | | | | | | | | ✗ |")
            continue
        ok = r["ok"]
        lines.append(
            f"| {r['policy']} | {r['surface']} | {r['force_mae_n']:.2f} ({r['force_bound_n']:g}) {_mark(ok['force'])} "
            f"| {_mm(r['motion_mae_tangent_m'])} {_mark(ok['motion'])} | {_mm(r['motion_mae_m'])} "
            f"| {_mm(r['motion_mae_all_contact_m'])} "
            f"| {r['tank_i_j'][0]:.2f}–{r['tank_i_j'][1]:.2f} {_mark(ok['tanks'])} "
            f"| {r['tank_f_j'][0]:.2f}–{r['tank_f_j'][1]:.2f} | {r['clip_ticks']} {_mark(ok['clips'])} "
            f"| {r['peak_over_set']:.2f} {_mark(ok['peak'])} | {_mark(all(ok.values()))} |")
    lines.append("")
    counts = {k: sum(r["ok"][k] for r in ran) for k in ("force", "motion", "tanks", "clips", "peak")}
    with_axis = sum(r["motion_with_tool_axis_ok"] for r in ran)
    lines.append(f"{len(rows)} runs planned, {len(ran)} ran; bounds met — force MAE {counts['force']}, motion MAE "
                 f"{counts['motion']} (with the tool-axis part {with_axis}), tanks {counts['tanks']}, no clip "
                 f"{counts['clips']}, peak ≤ 2× {counts['peak']}; all five {sum(all(r['ok'].values()) for r in ran)} "
                 f"of {len(rows)}.")
    replanned = [r for r in ran if r["first_pass"]]
    if replanned:
        lines += ["", replan_table_markdown(replanned)]
    return "\n".join(lines) + "\n"


def replan_table_markdown(rows: list[dict[str, Any]]) -> str:
    """Runs of two passes: the first pass's force MAE and aligned motion MAE (without the tool-axis part) beside
    the re-planned second's, and in how many the re-plan lowered the force MAE."""
    lines = ["| policy | surface | force MAE first → re-planned [N] | motion MAE aligned without the tool-axis part, "
             "first → re-planned x/y/z [mm] | lower |", "|---|---|---|---|---|"]
    lower = 0
    for r in rows:
        first = r["first_pass"]
        f1 = _num(first.get("force_mae_n"))
        down = r["force_mae_n"] < f1
        lower += down
        m1 = [_num(x) for x in (first.get("motion_mae_tangent_m") or [math.nan] * 3)]
        lines.append(f"| {r['policy']} | {r['surface']} | {f1:.2f} → {r['force_mae_n']:.2f} | {_mm(m1)} → "
                     f"{_mm(r['motion_mae_tangent_m'])} | {_mark(down)} |")
    lines += ["", f"The re-plan lowered the force MAE in {lower} of {len(rows)} runs."]
    return "\n".join(lines)
