"""The policy study's table: each bound is checked per run (and fails when it should), refused runs
are rows with their reason, and the counts add up."""

from __future__ import annotations

import json
import math

from tactex.experiments.policy_study import load_records, policy_rows, policy_table_markdown


def _record(index: int, policy: str, surface: str, **metrics) -> dict:
    m = {"force_mae_n": 0.3, "motion_mae_m": [0.001, 0.002, 0.0045], "motion_mae_tool_m": [0.001, 0.002, 0.004],
         "motion_mae_tangent_m": [0.001, 0.002, 0.0025],
         "motion_mae_all_contact_m": [0.004, 0.004, 0.004],
         "tank_impedance_energy_j": {"min": 20.0, "max": 24.9}, "tank_force_energy_j": {"min": 1.5, "max": 2.0},
         "tank_impedance_limits_j": [5.0, 25.0], "tank_force_limits_j": [0.1, 2.0], "torque_rate_clip_ticks": 0,
         "max_force_over_set_point": 1.5, "contact_fraction_after_first_contact": 1.0, **metrics}
    return {"run_id": f"r{index}", "index": index, "factors": {"policy": f"examples/policies/{policy}.toml",
                                                               "object_name": surface, "seed": 0},
            "config": {}, "status": "ok", "error": "", "metrics": m}


def test_each_bound_is_checked() -> None:
    recs = [
        _record(0, "spiral", "bowl"),
        _record(1, "sinusoid", "sine_panel", force_mae_n=0.6),  # over the sinusoid's own 0.5 N
        _record(2, "sinusoid", "bowl", force_mae_n=0.6),  # within 1 N elsewhere
        _record(3, "zigzag", "bowl", motion_mae_tangent_m=[0.001, 0.0031, 0.001]),
        _record(4, "zigzag", "sine_panel", motion_mae_tangent_m=[None, None, None]),  # never aligned: not met
        _record(5, "figure8", "bowl", tank_force_energy_j={"min": 0.05, "max": 2.0}),
        _record(6, "figure8", "sine_panel", torque_rate_clip_ticks=3),
        _record(7, "drawn", "bowl", max_force_over_set_point=2.05),
        {**_record(8, "drawn", "cup"), "status": "failed", "error": "PolicyFileError: not a height field",
         "metrics": None},
    ]
    rows = policy_rows(recs)
    assert all(rows[0]["ok"].values())
    assert rows[1]["force_bound_n"] == 0.5 and not rows[1]["ok"]["force"]
    assert rows[2]["force_bound_n"] == 1.0 and rows[2]["ok"]["force"]
    assert not rows[3]["ok"]["motion"] and rows[3]["ok"]["force"]
    assert not rows[4]["ok"]["motion"] and math.isnan(rows[4]["motion_mae_tangent_m"][0])
    # the base-frame error with its tool-axis part (4.5 mm along z here) is shown and counted, not judged
    assert not rows[0]["motion_with_tool_axis_ok"]
    assert not rows[5]["ok"]["tanks"]
    assert not rows[6]["ok"]["clips"]
    assert not rows[7]["ok"]["peak"]
    assert "ok" not in rows[8]
    text = policy_table_markdown(rows)
    assert "| drawn | cup | not run: PolicyFileError: not a height field |" in text
    assert "9 runs planned, 8 ran; bounds met — force MAE 7, motion MAE 6 (with the tool-axis part 0), tanks 7, " \
           "no clip 7, peak ≤ 2× 7; all five 2 of 9." in text
    assert "| spiral | bowl | 0.30 (1) ✓ | 1.0/2.0/2.5 ✓ | 1.0/2.0/4.5 | 4.0/4.0/4.0 |" in text


def test_the_last_record_of_a_run_counts(tmp_path) -> None:
    a, b = _record(0, "spiral", "bowl"), _record(1, "zigzag", "bowl")
    retried = {**_record(0, "spiral", "bowl"), "metrics": {**a["metrics"], "force_mae_n": 0.9}}
    (tmp_path / "runs.jsonl").write_text("\n".join(json.dumps(r) for r in (b, a, retried)) + "\n")
    recs = load_records(tmp_path)
    assert [r["index"] for r in recs] == [0, 1] and recs[0]["metrics"]["force_mae_n"] == 0.9


def test_a_study_varies_policies_and_refuses_a_bad_one_up_front(tmp_path) -> None:
    from pathlib import Path

    import pytest

    from tactex.errors import ConfigError
    from tactex.experiments.study_spec import StudySpec, level_label

    examples = Path(__file__).resolve().parents[1] / "examples" / "policies"
    files = [str(examples / "spiral.toml"), str(examples / "zigzag.toml")]
    spec = StudySpec(task="wipe", grid={"policy": files, "object_name": ["sine_panel", "bowl"]},
                     fixed={"start_y_m": 0.0})
    runs = spec.runs()
    assert [(r.config["policy"], r.config["object_name"]) for r in runs] == [
        (files[0], "sine_panel"), (files[0], "bowl"), (files[1], "sine_panel"), (files[1], "bowl")]
    assert len({r.run_id for r in runs}) == 4
    assert level_label("policy", files[0]) == "spiral" and level_label("policy", "") == "sinusoid (built in)"
    bad = tmp_path / "bad.toml"
    bad.write_text('[[segment]]\nkind = "wobble"\n')
    with pytest.raises(ConfigError, match="unknown kind 'wobble'"):  # the first run's config is checked at once
        StudySpec(task="wipe", grid={"policy": [str(bad)]})


def test_runs_of_two_passes_get_a_table_of_first_against_re_planned() -> None:
    recs = [
        _record(0, "spiral", "bowl", replan={"first_pass": {"force_mae_n": 0.5,
                                                            "motion_mae_tangent_m": [0.004, 0.002, 0.01]}}),
        _record(1, "zigzag", "bowl", replan={"first_pass": {"force_mae_n": 0.2, "motion_mae_tangent_m": [0.001] * 3}}),
        _record(2, "drawn", "bowl"),  # one pass: not in the comparison
    ]
    text = policy_table_markdown(policy_rows(recs))
    assert "| spiral | bowl | 0.50 → 0.30 | 4.0/2.0/10.0 → 1.0/2.0/2.5 | ✓ |" in text
    assert "| zigzag | bowl | 0.20 → 0.30 | 1.0/1.0/1.0 → 1.0/2.0/2.5 | ✗ |" in text
    assert "The re-plan lowered the force MAE in 1 of 2 runs." in text
    assert sum("→" in line for line in text.splitlines()) == 3  # the header and the two runs of two passes
