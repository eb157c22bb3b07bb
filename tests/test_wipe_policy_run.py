"""A wipe that runs a policy object: the controller's force set point is the policy's at each tick,
the offsets it follows are the policy's, per-segment figures are reported; a bad policy object is
refused before anything starts."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.errors import ConfigError
from tactex.tasks.policies import CirclePolicy, ForceRamp, LinePolicy, PolicySequence
from tactex.tasks.wipe import WipeConfig, run_wipe

#: the policy: 1.5 s of a 2 cm stroke ramping 8 → 14 N, then a 1 cm circle at 14 N
POLICY = PolicySequence([LinePolicy(1.5, ForceRamp(8.0, 14.0), length_m=0.02, direction_deg=-90.0),
                         CirclePolicy(1.5, ForceRamp(14.0, 14.0), radius_m=0.01)])


@pytest.fixture(scope="module")
def result():
    return run_wipe(WipeConfig(start_height_m=0.003, record_hz=1000.0), policy=POLICY, progress=False)


def test_the_run_lasts_the_policy_and_records_its_set_point(result) -> None:
    s = result.series
    assert s["t"][-1] == pytest.approx(3.0, abs=2e-3)
    # the recorded set point is the policy's at each tick (one tick ahead: the reference answers the next state)
    expected = np.array([POLICY.at(t).force_n for t in s["t"]])
    assert np.max(np.abs(s["force_set_n"][1:] - expected[1:])) < 0.01
    assert s["force_set_n"][0] == 8.0 and s["force_set_n"][-1] == 14.0
    assert set(np.unique(s["segment"])) == {0.0, 1.0}
    uv = s["policy_uv_m"]
    assert np.allclose(uv[-1], POLICY.at(3.0)[:2], atol=1e-4)


def test_force_errors_are_against_the_policys_set_point(result) -> None:
    m, s = result.metrics, result.series
    contact = s["in_contact"] > 0.5
    mae = np.mean(np.abs(s["force_z_n"][contact] - s["force_set_n"][contact]))
    assert m["force_mae_n"] == pytest.approx(mae, rel=0.05)  # every tick against every recorded tick
    segs = m["policy"]["segments"]
    assert [g["kind"] for g in segs] == ["line", "circle"]
    assert [g["start_s"] for g in segs] == [0.0, 1.5]
    assert all(g["contact_ticks"] > 0 for g in segs)
    # the overall MAE is the contact-tick-weighted mean of the segments'
    w = np.array([g["contact_ticks"] for g in segs], dtype=float)
    assert m["force_mae_n"] == pytest.approx(float(np.dot(w, [g["force_mae_n"] for g in segs]) / w.sum()), rel=1e-9)
    assert m["max_force_over_set_point"] == pytest.approx(max(g["max_force_over_set_point"] for g in segs))


def test_a_bad_policy_object_is_refused_before_the_run() -> None:
    fast = LinePolicy(0.5, ForceRamp(10.0, 10.0), length_m=0.1)
    with pytest.raises(ConfigError, match=r"segment 1 \(line\): duration_s: speed"):
        run_wipe(WipeConfig(), policy=fast, progress=False)
    with pytest.raises(ConfigError, match="must be a ForceMotionPolicy"):
        run_wipe(WipeConfig(), policy="spiral", progress=False)  # type: ignore[arg-type]


def test_the_report_draws_the_policy(result, tmp_path) -> None:
    from tactex.report.policy_plots import _segment_spans
    from tactex.report.wipe_report import write_wipe_report

    rep = write_wipe_report(result, tmp_path / "run", html_page=False)
    for role, name in (("policy_force_png", "policy_force.png"), ("policy_path_png", "policy_path.png")):
        assert rep.files[role] == tmp_path / "run" / name and (tmp_path / "run" / name).stat().st_size > 10_000
    spans = _segment_spans(result.series)
    assert [k for k, _, _ in spans] == [0, 1]
    assert spans[1][1] == pytest.approx(1.5, abs=2e-3)  # the circle starts where the policy says


def test_start_pose_above_a_height_field_and_beside_the_cup_wall() -> None:
    from tactex.sim.objects import get_object
    from tactex.tasks.runner import TOOL_DOWN
    from tactex.tasks.wipe_policy import wipe_start_pose

    cfg = WipeConfig(start_tilt_deg=0.0)
    pos, rot = np.array([0.5, 0.0, 0.0]), np.eye(3)
    p, r = wipe_start_pose(cfg, get_object("sine_panel").surface, pos, rot)
    z = float(get_object("sine_panel").surface.project(np.array([[0.0, 0.08, 0.0]]))[0][0, 2])
    assert np.array_equal(p, pos + np.array([0.0, 0.08, z + cfg.start_height_m])) and np.array_equal(r, TOOL_DOWN)
    cup = get_object("cup").surface
    on_wall = WipeConfig(object_name="cup", start_tilt_deg=0.0, amplitude_m=0.02, drift_m_s=0.0)  # a sinusoid it holds
    p, r = wipe_start_pose(on_wall, cup, pos, rot)
    assert np.allclose(p, pos + np.array([0.0, -cup.radius_m - cfg.start_height_m, 0.5 * cup.height_m]))
    assert np.allclose(r[:, 2], [0.0, 1.0, 0.0])  # the tool axis into the wall
    assert np.allclose(r[:, 0], [1.0, 0.0, 0.0]) and np.allclose(r[:, 1], [0.0, 0.0, -1.0])  # u along it, v down
    assert np.isclose(np.linalg.det(r), 1.0)


def test_a_policy_that_waits_for_the_alignment_starts_there_and_runs_whole() -> None:
    r = run_wipe(WipeConfig(policy_waits_for_alignment=True, record_hz=100.0), policy=POLICY, progress=False)
    s, m = r.series, r.metrics
    waited = m["policy_waited_s"]
    assert 0.5 < waited < WipeConfig().align_wait_max_s  # it aligned, and then the policy started
    assert m["aligned_at_s"] is not None and waited == pytest.approx(m["aligned_at_s"], abs=0.05)
    before = s["t"] < waited - 0.02
    assert before.any() and np.allclose(s["policy_uv_m"][before], 0.0)  # held at its start
    assert np.all(s["force_set_n"][before] == 8.0)  # at its first set point
    assert s["t"][-1] == pytest.approx(waited + 3.0, abs=0.02)  # then the whole policy
    assert m["explore_time_s"] == pytest.approx(waited + 3.0 - m["first_contact_s"], abs=0.02)  # the wait counts
    assert np.allclose(s["policy_uv_m"][-1], POLICY.at(3.0)[:2], atol=1e-4)


@pytest.mark.parametrize(("kw", "match"), [
    ({"policy_waits_for_alignment": True, "baseline": "cartesian"}, "no alignment to wait for"),
    ({"align_wait_max_s": 0.0}, "align_wait_max_s must be a positive number"),
    ({"compliant_below": 1.0}, r"compliant_below must be a share of ρ_align in \[0, 1\)"),
    ({"compliant_below": float("nan")}, "compliant_below must be"),
])
def test_waiting_for_the_alignment_and_the_compliant_share_are_checked(kw, match) -> None:
    with pytest.raises(ConfigError, match=match):
        WipeConfig(**kw)


def test_the_compliant_share_reaches_the_controller(monkeypatch) -> None:
    import tactex.tasks.wipe as wipe
    from tactex.control.va_ufic import VaUficController

    seen = []

    class Spy(VaUficController):
        def __init__(self, params=None, port_feedforward=None):
            seen.append(params.compliant_below)
            super().__init__(params, port_feedforward)

    monkeypatch.setattr(wipe, "VaUficController", Spy)
    run_wipe(WipeConfig(compliant_below=0.1, duration_s=0.05), progress=False)
    assert seen == [0.1]
