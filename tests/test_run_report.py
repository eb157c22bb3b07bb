"""Run reports of the closed-loop tasks on synthetic results: files, contract keys, data in the page."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import pytest

from tactex.control.va_ufic import VaUficParams
from tactex.errors import InputError
from tactex.pointcloud import SurfaceCloud
from tactex.report import CLEAN_METRIC_KEYS, WIPE_METRIC_KEYS, summary_table, write_index_html, write_run_report
from tactex.report.run_report import CLEAN_PHASES, missing_metric_keys, run_kind, vision_round_trips

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
DT = 0.01  # 100 Hz recorder


@dataclass(frozen=True)
class FakeCleanConfig:
    object_name: str = "plate"
    force_n: float = 10.0
    baseline: str = ""


@dataclass(frozen=True)
class FakeWipeConfig:
    force_n: float = 15.0
    controller: VaUficParams = field(default_factory=VaUficParams)


@dataclass
class FakeEvent:
    t: float
    kind: str
    detail: str


def _plate(n_side: int = 20) -> SurfaceCloud:
    g = np.linspace(-0.1, 0.1, n_side)
    x, y = np.meshgrid(g, g)
    pts = np.column_stack([x.ravel() + 0.5, y.ravel(), np.full(x.size, 0.02)])
    target = (np.abs(x.ravel() - y.ravel()) < 0.02).astype(float)
    return SurfaceCloud(points=pts, normals=np.tile([0.0, 0.0, 1.0], (len(pts), 1)), target=target, spacing=0.01)


def _clean_phases() -> np.ndarray:
    """move, capture, approach, explore, retract, move, capture (re-measure), approach, explore, retract."""
    spans = [("move", 50), ("capture", 10), ("approach", 20), ("explore", 200), ("retract", 20), ("move", 40),
             ("capture", 10), ("approach", 20), ("explore", 200), ("retract", 30)]
    return np.concatenate([np.full(n, CLEAN_PHASES[p], float) for p, n in spans])


def fake_clean(baseline: str = "") -> SimpleNamespace:
    phase = _clean_phases()
    n = len(phase)
    t = np.arange(n) * DT
    explore = phase == CLEAN_PHASES["explore"]
    cloud = _plate()
    tcp = np.tile([0.5, 0.0, 0.3], (n, 1))
    tcp[explore] = cloud.points[np.arange(explore.sum()) % len(cloud)]
    agent = np.full((n, 3), np.nan)
    agent[explore] = tcp[explore]
    force = np.where(explore, 10.0 + np.sin(t * 7.0), 0.0)
    metrics = {
        "dirt_removed_fraction": 0.62, "force_within_20pct_fraction": 0.91, "max_contact_force_n": 14.5,
        "sim_time_s": float(t[-1]), "vision_updates": 1, "force_set_point_n": 10.0, "baseline": baseline or "tactex",
        "object": "plate",
        "ergodicity": [] if baseline in ("raster", "region_raster") else [(1.0, 0.9), (2.0, 0.7), (3.0, 0.55)],
    }
    fields = {"target_initial": cloud.target.copy()}
    if baseline not in ("raster", "region_raster"):
        fields.update(target=cloud.target * 0.5, coverage=np.linspace(0, 1, len(cloud)),
                      potential=np.cos(cloud.points[:, 0]))
    return SimpleNamespace(
        config=FakeCleanConfig(baseline=baseline), metrics=metrics,
        series={"t": t, "phase": phase, "tcp": tcp, "agent": agent, "force_z_n": force, "force_norm_n": np.abs(force),
                "set_point_n": np.where(explore, 10.0, 0.0), "pad_force_n": force,
                "dirt_remaining": np.linspace(1.0, 0.38, n)},
        cloud=cloud, fields=fields, agent_path=cloud.points[:40], tcp_path=tcp,
        events=[FakeEvent(1.5, "torque_rate_limit", "torque rate saturated")],
    )


def fake_wipe(label: str = "") -> SimpleNamespace:
    n = 500
    t = np.arange(n) * DT
    y = np.linspace(-0.1, 0.1, n)
    z = 0.02 * np.sin(2 * np.pi * y / 0.1)
    tcp_obj = np.column_stack([np.zeros(n), y, z + 0.001])
    tcp = tcp_obj + np.array([0.5, 0.0, 0.05])
    contact = (t > 0.5).astype(float)
    curv = np.abs(np.sin(np.linspace(0, 3, 80))) * 40.0
    explored = SurfaceCloud(points=tcp[::6][:80], normals=np.tile([0.0, 0.0, 1.0], (80, 1)))
    metrics = {
        "force_mae_n": 0.4, "force_rmse_n": 0.8, "motion_mae_m": [0.001, 0.002, 0.0005],
        "motion_mae_all_contact_m": [0.003, 0.004, 0.001],
        "motion_rmse_m": [0.002, 0.003, 0.001], "tank_impedance_energy_j": {"min": 5.2, "max": 30.1},
        "tank_force_energy_j": {"min": 1.1, "max": 2.0}, "explore_time_s": 4.5, "contact_fraction": 0.9,
        "sim_time_s": float(t[-1]), "baseline": label or "tactex",
    }
    series = {
        "t": t, "tcp": tcp, "desired": tcp + 0.001, "motion_error_tool": np.full((n, 3), 0.001),
        "force_z_n": 15.0 * contact + 0.3 * np.sin(t), "force_set_n": 15.0 * contact, "in_contact": contact,
        "rho_align": np.clip(t / 3, 0, 1), "rho_frc": np.clip(t / 2, 0, 1), "tank_i_energy_j": 30 - 0.01 * t,
        "tank_f_energy_j": np.full(n, 2.0), "tcp_object": tcp_obj,
    }
    return SimpleNamespace(config=FakeWipeConfig(), metrics=metrics, series=series, profile={"y_m": y, "z_m": z},
                           explored=explored, explored_curvature=curv, events=[])


def _pngs_ok(rep) -> list[str]:
    names = []
    for role, path in rep.files.items():
        if role.endswith("_png"):
            assert path.read_bytes()[:8] == PNG_MAGIC, path
            names.append(path.name)
    return names


def test_clean_report_files_and_contract(tmp_path) -> None:
    res = fake_clean()
    rep = write_run_report(res, tmp_path / "clean")
    assert rep.kind == "clean" and rep.label == "tactex" and rep.notes == []
    metrics = json.loads((tmp_path / "clean" / "metrics.json").read_text())
    assert set(CLEAN_METRIC_KEYS) <= set(metrics) and metrics["dirt_removed_fraction"] == 0.62
    assert json.loads((tmp_path / "clean" / "config.json").read_text()) == {"object_name": "plate", "force_n": 10.0,
                                                                             "baseline": ""}
    assert sorted(_pngs_ok(rep)) == sorted(["dirt.png", "force.png", "phases.png", "cloud.png", "cloud_tcp.png",
                                            "ergodicity.png"])
    with np.load(tmp_path / "clean" / "series.npz", allow_pickle=False) as z:
        assert set(z.files) == set(res.series)
        np.testing.assert_array_equal(z["dirt_remaining"], res.series["dirt_remaining"])
        assert np.isnan(z["agent"]).any()  # NaN where no agent is kept, not filled
    with np.load(tmp_path / "clean" / "cloud.npz", allow_pickle=False) as z:
        np.testing.assert_array_equal(z["field_coverage"], res.fields["coverage"])
        # Only TCP samples of the exploration phases are the tool path in contact.
        assert z["tcp_path_contact"].shape == (400, 3)
    events = json.loads((tmp_path / "clean" / "events.json").read_text())
    assert events == [{"t": 1.5, "kind": "torque_rate_limit", "detail": "torque rate saturated"}]
    page = rep.html.read_text()
    assert "<script src=" not in page and '"coverage"' in page and '"potential"' in page and '"path"' in page
    assert page.count("src='data:image/png;base64,") == 6 and "dirt_removed_fraction" in page
    assert page.rstrip().endswith("</html>")


def test_clean_report_shows_the_time_breakdown(tmp_path) -> None:
    res = fake_clean()
    res.metrics.update(time_breakdown_s={"contact_dirt": 2.0, "contact_clean": 1.0, "explore_no_contact": 0.0,
                                         "touch_down": 0.5, "transit": 0.8, "vision": 0.6, "lift_off": 0.0},
                       time_to_95pct_s=3.2,
                       time_breakdown_to_95pct_s={"contact_dirt": 1.5, "contact_clean": 0.2, "explore_no_contact": 0.0,
                                                  "touch_down": 0.5, "transit": 0.4, "vision": 0.6, "lift_off": 0.0})
    rep = write_run_report(res, tmp_path / "clean")
    assert "time_breakdown.png" in _pngs_ok(rep)
    assert "time_breakdown_s" in json.loads((tmp_path / "clean" / "metrics.json").read_text())
    res.metrics.update(ideal_time_s=2.0, time_to_95pct_over_ideal=1.6)
    table = summary_table([("tactex", res.metrics), ("raster", {**res.metrics, "time_to_95pct_s": None,
                                                                "time_to_95pct_over_ideal": None})])
    header, _, tactex_row, raster_row = table.splitlines()
    assert "95 % removed at [s]" in header and "3.2" in tactex_row.split() and "–" in raster_row.split()
    assert "95 % / bound" in header and "1.60" in tactex_row.split() and "2.0" in raster_row.split()
    res.metrics["time_breakdown_s"] = {"vision": 0.0}  # nothing accounted: a note, not a crash
    rep = write_run_report(res, tmp_path / "empty")
    assert "time_breakdown.png" not in _pngs_ok(rep) and any("time breakdown" in n for n in rep.notes)


@pytest.mark.parametrize(("baseline", "name"), [("raster", "raster"), ("region_raster", "region raster")])
def test_clean_report_raster_baseline_notes_missing_ergodicity(tmp_path, baseline, name) -> None:
    rep = write_run_report(fake_clean(baseline), tmp_path / baseline)
    assert rep.label == baseline and "ergodicity_png" not in rep.files
    assert f"no ergodicity series (the {name} baseline has no target distribution to compare)" in rep.notes
    assert '"dirt (first capture)"' in rep.html.read_text()


def test_clean_report_of_a_run_stopped_before_its_first_capture(tmp_path) -> None:
    res = fake_clean()
    res.cloud, res.fields, res.agent_path = None, {}, np.zeros((0, 3))
    rep = write_run_report(res, tmp_path / "clean")
    assert sorted(_pngs_ok(rep)) == sorted(["dirt.png", "force.png", "phases.png", "ergodicity.png"])
    assert not (tmp_path / "clean" / "cloud.npz").exists() and (tmp_path / "clean" / "series.npz").is_file()
    assert any("before its first capture" in n for n in rep.notes)
    page = rep.html.read_text()
    assert "plotly" not in page and page.count("src='data:image/png;base64,") == 4 and "before its first" in page


def test_vision_round_trips_span_retract_to_next_approach() -> None:
    phase = _clean_phases()
    t = np.arange(len(phase)) * DT
    # The first retract starts after 50+10+20+200 samples; the next approach after 20+40+10 more. The final
    # retract is followed by no approach: the end of the run, not a vision update.
    np.testing.assert_allclose(vision_round_trips(t, phase), [[280 * DT, 350 * DT]])
    assert vision_round_trips(t, np.full(len(t), CLEAN_PHASES["explore"], float)).shape == (0, 2)


def test_missing_contract_keys_are_noted(tmp_path) -> None:
    res = fake_clean()
    del res.metrics["vision_updates"]
    rep = write_run_report(res, tmp_path / "c", html_page=False)
    assert rep.notes == ["metrics lack contract keys: vision_updates"]
    assert missing_metric_keys("wipe", {}) == list(WIPE_METRIC_KEYS)
    with pytest.raises(InputError, match="unknown run kind 'sweep'"):
        missing_metric_keys("sweep", {})


def test_wipe_report_files_and_contract(tmp_path) -> None:
    res = fake_wipe()
    rep = write_run_report(res, tmp_path / "wipe")
    assert rep.kind == "wipe" and rep.notes == []
    metrics = json.loads((tmp_path / "wipe" / "metrics.json").read_text())
    assert set(WIPE_METRIC_KEYS) <= set(metrics)
    assert metrics["motion_mae_m"] == [0.001, 0.002, 0.0005] and metrics["tank_force_energy_j"]["max"] == 2.0
    cfg = json.loads((tmp_path / "wipe" / "config.json").read_text())
    assert cfg["controller"]["tank_i_upper"] == 32.0
    assert sorted(_pngs_ok(rep)) == sorted(["fig2_profile.png", "fig3a_alignment.png", "fig3b_motion.png",
                                            "fig3c_force.png", "fig3d_tanks.png", "explored.png"])
    with np.load(tmp_path / "wipe" / "cloud.npz", allow_pickle=False) as z:
        np.testing.assert_array_equal(z["explored_curvature"], res.explored_curvature)
        np.testing.assert_array_equal(z["profile_z_m"], res.profile["z_m"])
        assert z["tcp_path_contact"].shape == (int(res.series["in_contact"].sum()), 3)
    page = rep.html.read_text()
    assert '"curvature l_s [-]"' in page and '"path"' in page and page.count("src='data:image/png;base64,") == 6
    # the explored surface as a PLY that `tactex explore` loads: points, normals, curvature, all of it target
    from tactex.pointcloud.io import load_ply

    ply = load_ply(rep.files["explored_ply"])
    np.testing.assert_allclose(ply.points, res.explored.points)
    np.testing.assert_allclose(ply.normals, res.explored.normals)
    assert ply.n_target == len(res.explored)
    from plyfile import PlyData

    np.testing.assert_allclose(PlyData.read(str(rep.files["explored_ply"]))["vertex"]["curvature"],
                               res.explored_curvature)


def test_wipe_report_without_contact(tmp_path) -> None:
    res = fake_wipe()
    res.series["in_contact"][:] = 0.0
    res.explored = None  # a run that never touched the surface
    res.explored_curvature = np.zeros(0)
    rep = write_run_report(res, tmp_path / "w")
    assert "explored_png" not in rep.files and any("no explored points" in n for n in rep.notes)
    assert "explored_ply" not in rep.files and not (tmp_path / "w" / "explored.ply").exists()
    assert "fig3d_png" in rep.files and rep.html.read_text().rstrip().endswith("</html>")


@pytest.mark.parametrize(
    ("mutate", "match"),
    [
        (lambda r: r.series.pop("rho_align"), "lacks rho_align"),
        (lambda r: r.series.__setitem__("force_z_n", np.zeros(3)), "'force_z_n' has shape"),
        (lambda r: setattr(r, "explored_curvature", np.zeros(5)), "5 values for 80 explored points"),
        (lambda r: setattr(r, "series", None), "no 'series' mapping"),
    ],
)
def test_wipe_report_bad_result(tmp_path, mutate, match) -> None:
    res = fake_wipe()
    mutate(res)
    with pytest.raises(InputError, match=match):
        write_run_report(res, tmp_path / "bad")


def test_run_kind_refuses_other_objects() -> None:
    assert run_kind(fake_clean()) == "clean" and run_kind(fake_wipe()) == "wipe"
    with pytest.raises(InputError, match="cannot report a dict"):
        run_kind({})


def test_summary_table_side_by_side() -> None:
    rows = [("tactex", fake_clean().metrics), ("raster", {**fake_clean("raster").metrics, "dirt_removed_fraction": 0.4,
                                                          "vision_updates": 0})]
    text = summary_table(rows)
    lines = text.splitlines()
    assert len(lines) == 4 and lines[0].split()[0] == "run" and "dirt removed" in lines[0]
    assert "62.0 %" in lines[2] and "40.0 %" in lines[3] and "91.0 %" in lines[2]
    assert "force MAE" not in text  # no wipe metric in these rows
    wipe = summary_table({"tactex": fake_wipe().metrics, "cartesian": {"force_mae_n": 2.5}})
    # VA-UFIC's aligned motion error (the paper's figure) and the one over all contact ticks (the same samples for
    # every controller), each under its own header
    head = wipe.splitlines()[0]
    assert head.index("motion MAE aligned") < head.index("motion MAE in contact")
    row = wipe.splitlines()[2]
    assert row.index("1.0/2.0/0.5") < row.index("3.0/4.0/1.0") and "5.20–30.10" in wipe and "2.50" in wipe
    assert wipe.splitlines()[3].count("–") >= 4  # the baseline lacks motion and tank metrics
    # A baseline without tanks (NaN energies, null in JSON) shows "–", not "nan–nan".
    no_tank = summary_table([("cartesian", {"tank_force_energy_j": {"min": None, "max": float("nan")},
                                            "motion_mae_all_contact_m": [float("nan")] * 3, "force_mae_n": 2.5})])
    assert "nan" not in no_tank and no_tank.splitlines()[2].split()[1:] == ["2.50", "–", "–"]
    with pytest.raises(InputError, match="at least one run"):
        summary_table([])
    with pytest.raises(InputError, match="pairs"):
        summary_table([("a", 3)])  # type: ignore[list-item]


def test_a_wipe_whose_motion_error_is_the_alignment_transient_says_so() -> None:
    from tactex.report.run_report import alignment_summary

    m = {"motion_mae_m": [0.002, 0.0018, 0.0024], "motion_mae_all_contact_m": [0.0121, 0.0094, 0.003],
         "first_contact_s": 0.8, "aligned_at_s": 3.4}
    said = alignment_summary(m)
    assert said is not None and "12.1/9.4/3.0 mm includes the alignment transient" in said
    assert "aligned at 3.4 s" in said and "first contact at 0.8 s" in said and "after alignment 2.0/1.8/2.4 mm" in said
    # nothing to say when the two differ by less than a millimetre, or for a controller without a contact monitor
    assert alignment_summary({**m, "motion_mae_all_contact_m": [0.0025, 0.002, 0.0028]}) is None
    assert alignment_summary({"motion_mae_all_contact_m": [0.01, 0.01, 0.01], "force_mae_n": 2.0}) is None
    never = alignment_summary({**m, "motion_mae_m": [float("nan")] * 3, "aligned_at_s": None})
    assert never is not None and "never aligned" in never


def test_a_commands_summary_carries_the_alignment_line() -> None:
    from tactex.experiments.run import task_summary
    from tactex.report.run_report import RunReport

    metrics = {**fake_wipe().metrics, "motion_mae_all_contact_m": [0.0121, 0.0094, 0.003],
               "motion_mae_m": [0.002, 0.0018, 0.0024], "first_contact_s": 0.8, "aligned_at_s": 3.4}
    text = task_summary([RunReport(label="tactex", kind="wipe", out_dir=None, metrics=metrics)])
    assert text.splitlines()[-1].startswith("motion (tactex): motion MAE in contact 12.1/9.4/3.0 mm includes")


def test_index_links_runs(tmp_path) -> None:
    reps = [write_run_report(fake_clean(), tmp_path / "clean", html_page=False),
            write_run_report(fake_clean("raster"), tmp_path / "clean_raster"),
            write_run_report(fake_wipe(), tmp_path / "wipe")]
    page = write_index_html(tmp_path / "index.html", reps, title="demo").read_text()
    assert "href='clean_raster/report.html'" in page and "href='wipe/report.html'" in page
    assert "<h2>clean</h2>" in page and "<h2>wipe</h2>" in page and "62.0 %" in page and "0.40" in page


def test_vision_marks_prefer_recorded_times(tmp_path) -> None:
    res = fake_clean()
    res.metrics.update(vision_updates=2, vision_update_times_s=[0.5, 1.0])
    assert write_run_report(res, tmp_path / "a", html_page=False).notes == []  # recorded times agree with the count
    res = fake_clean()
    res.metrics["vision_updates"] = 3  # the series shows one re-capture only
    notes = write_run_report(res, tmp_path / "b", html_page=False).notes
    assert notes == ["dirt plot marks 1 vision updates, metrics count 3"]


def test_tank_limits_sources() -> None:
    from tactex.report.wipe_report import DEFAULT_TANK_LIMITS, _tank_limits

    from_metrics = _tank_limits(FakeWipeConfig(), {"tank_impedance_limits_j": [2, 30], "tank_force_limits_j": [1.5, 3]})
    assert from_metrics == {"impedance": (2.0, 30.0), "force": (1.5, 3.0)}
    from_cfg = _tank_limits(FakeWipeConfig(controller=VaUficParams(tank_i_upper=20.0)), {})
    assert from_cfg == {"impedance": (1.0, 20.0), "force": (1.0, 2.0)}
    assert _tank_limits(FakeCleanConfig(), {}) == DEFAULT_TANK_LIMITS == {"impedance": (1.0, 32.0), "force": (1.0, 2.0)}


def test_phases_come_from_the_recorded_changes() -> None:
    """A capture takes no tick and an approach a few ms: the 100 Hz series misses both, the recorded
    phase changes do not (the plate run's phases.png showed empty approach and capture rows)."""
    from tactex.report.clean_report import _phase_spans

    P = CLEAN_PHASES
    series = {"t": np.arange(0.0, 3.0, 0.01), "phase": np.zeros(300)}  # the samples saw "move" only
    changes = [(0.0, P["move"]), (1.0, P["capture"]), (1.0, P["move"]), (1.5, P["approach"]),
               (1.503, P["explore"]), (2.5, P["retract"])]
    spans = _phase_spans(series, np.asarray(changes, dtype=np.float64))
    assert spans[P["capture"]] == [(1.0, 0.0)]
    assert spans[P["approach"]][0] == (1.5, pytest.approx(0.003))
    assert spans[P["retract"]] == [(2.5, pytest.approx(0.49))]  # to the end of the series
    assert spans[P["move"]] == [(0.0, 1.0), (1.0, 0.5)]
    ch = np.asarray(changes)
    assert vision_round_trips(ch[:, 0], ch[:, 1]).shape == (0, 2)  # no approach after the retract
    ch = np.vstack([ch, [[2.7, P["move"]], [2.8, P["capture"]], [2.8, P["move"]], [2.9, P["approach"]]]])
    np.testing.assert_allclose(vision_round_trips(ch[:, 0], ch[:, 1]), [[2.5, 2.9]])


def test_lift_offs_without_a_view_are_moves_and_contact_stretches_break_at_lift_offs() -> None:
    from tactex.report.clean_report import contact_stretches, trips_with_a_view

    trips = np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]])
    np.testing.assert_array_equal(trips_with_a_view(trips, [1.5, 5.9]), [True, False, True])
    assert trips_with_a_view(np.zeros((0, 2)), [1.0]).shape == (0,)
    tcp = np.arange(30, dtype=float).reshape(10, 3)
    tcp[5] = np.nan  # a dropped sample inside a stretch is no lift-off
    contact = np.array([1, 1, 0, 0, 1, 1, 1, 0, 1, 1], dtype=bool)
    pts, lifted = contact_stretches(tcp, contact)
    np.testing.assert_array_equal(pts, tcp[[0, 1, 4, 6, 8, 9]])
    assert lifted == [2, 4]
