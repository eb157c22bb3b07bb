"""`tactex clean`, `tactex wipe`, `tactex demo`: bad input is one line and exit 2; short runs write the folder."""

from __future__ import annotations

import json
import os
from types import SimpleNamespace

import numpy as np
import pytest

from tactex.cli import main
from tactex.errors import ConfigError, InputError
from tactex.experiments.demo import DemoConfig
from tactex.experiments.run import _try_video, run_compare, run_task
from tactex.experiments.run_folder import prepare_out_dir
from tactex.experiments.video import write_replay_video
from tactex.report import CLEAN_METRIC_KEYS, WIPE_METRIC_KEYS
from tactex.report.run_report import RunReport
from tactex.tasks.clean.motion import UNLOAD_S

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _one_line_error(capsys: pytest.CaptureFixture, code: int, *needles: str) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2, err
    assert "Traceback" not in err
    assert len(lines) == 1, err
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


@pytest.mark.parametrize(
    ("argv", "needles"),
    [
        (["clean", "--object-name", "teapot"], ("tactex clean: error:", "unknown object 'teapot'", "plate")),
        (["wipe", "--object-name", "teapot"], ("tactex wipe: error:", "unknown object 'teapot'")),
        (["clean", "--force-n", "-5"], ("--force-n must be a positive number", "-5")),
        (["wipe", "--force-n", "-5"], ("--force-n must be a positive number", "-5")),
        (["clean", "--baseline", "zigzag"], ("unknown baseline 'zigzag'", "raster")),
        (["wipe", "--baseline", "zigzag"], ("unknown baseline 'zigzag'", "cartesian")),
        (["clean", "--compare", "--baseline", "raster"], ("--compare", "drop --baseline raster")),
    ],
)
def test_task_bad_input_one_line(tmp_path, capsys, argv, needles) -> None:
    code = main([*argv, "--out", str(tmp_path / "run")])
    _one_line_error(capsys, code, *needles)
    assert not (tmp_path / "run").exists()  # nothing ran


def test_out_is_a_file(tmp_path, capsys) -> None:
    target = tmp_path / "file.txt"
    target.write_text("x")
    code = main(["wipe", "--out", str(target)])
    _one_line_error(capsys, code, "is an existing file")
    with pytest.raises(InputError, match="existing file"):
        prepare_out_dir(target)
    assert prepare_out_dir(tmp_path / "new") == tmp_path / "new"


@pytest.mark.parametrize("command", [["explore", "cup", "--steps", "5"], ["sweep", "cup", "--steps", "5"],
                                     ["clean"], ["wipe"], ["demo"]])
def test_an_unwritable_out_is_one_line_before_any_work(tmp_path, capsys, command) -> None:
    """--out below a file (or anywhere it cannot be made) was an OSError traceback, for explore and
    sweep only after all the computing."""
    blocker = tmp_path / "one.npz"
    blocker.write_text("x")
    code = main([*command, "--out", str(blocker / "sub")])
    _one_line_error(capsys, code, "cannot write the run folder", "choose a writable directory")


def test_missing_cloud_file(tmp_path, capsys) -> None:
    code = main(["explore", str(tmp_path / "missing.ply"), "--out", str(tmp_path / "x")])
    _one_line_error(capsys, code, "missing.ply")


def test_demo_bad_input(tmp_path, capsys) -> None:
    code = main(["demo", "--clean-budget-s", "-1", "--out", str(tmp_path / "d")])
    _one_line_error(capsys, code, "--clean-budget-s must be a positive number", "-1")


def test_demo_configs_scale_with_quick() -> None:
    full, quick = DemoConfig().task_configs(), DemoConfig(quick=True).task_configs()
    assert full["clean"].object_name == "plate" and full["clean"].budget_s == DemoConfig().clean_budget_s
    assert quick["clean"].budget_s == pytest.approx(0.25 * full["clean"].budget_s)
    assert quick["wipe"].duration_s == pytest.approx(0.25 * full["wipe"].duration_s)


def test_run_task_and_compare_refuse_wrong_input(tmp_path) -> None:
    from tactex.tasks.clean import CleanConfig

    with pytest.raises(ConfigError, match="wipe needs a WipeConfig, got CleanConfig"):
        run_task("wipe", CleanConfig(), tmp_path / "x")
    with pytest.raises(ConfigError,
                       match="unknown clean baseline 'cartesian'; valid: raster, region_raster, no_feedback"):
        run_compare("clean", CleanConfig(), tmp_path / "x", baselines=["cartesian"])
    with pytest.raises(ConfigError, match="unknown task 'sand'"):
        run_task("sand", CleanConfig(), tmp_path / "x")


def test_video_needs_joint_series_and_gl(tmp_path) -> None:
    from tactex.sim.franka import FRANKA_HOME_Q
    from tactex.tasks.clean import CleanConfig

    rep = RunReport(out_dir=tmp_path, kind="clean", label="tactex", metrics={})
    no_q = SimpleNamespace(config=CleanConfig(), series={"t": np.arange(3) * 0.01})
    with pytest.raises(InputError, match="no joint positions 'q'"):
        write_replay_video(no_q, tmp_path / "v.gif")
    _try_video(no_q, rep, enabled=True)
    assert rep.notes == ["video skipped: the run recorded no joint positions 'q' in its series, so there is nothing "
                         "to replay"]
    t = np.arange(50) * 0.1
    q = np.tile(FRANKA_HOME_Q, (50, 1)) + np.linspace(0, 0.3, 50)[:, None]
    with_q = SimpleNamespace(config=CleanConfig(), series={"t": t, "q": q})
    rep.notes.clear()
    _try_video(with_q, rep, enabled=True)
    if os.environ.get("MUJOCO_GL") == "disable":  # the test default (conftest): no GL context
        assert "video" not in rep.files and len(rep.notes) == 1 and "GL rendering unavailable" in rep.notes[0]
    else:
        assert rep.files["video"].read_bytes()[:6] in (b"GIF89a", b"GIF87a") and rep.notes == []
    off = RunReport(out_dir=tmp_path / "off", kind="clean", label="off", metrics={})
    _try_video(with_q, off, enabled=False)
    assert off.files == {} and off.notes == [] and not (tmp_path / "off").exists()


@pytest.mark.slow
def test_clean_n_eigen_larger_than_cloud(tmp_path, capsys) -> None:
    # The plate captured at 3 mm has ~5.5k points: the eigensolver refuses n_K ≈ N with one line.
    code = main(["clean", "--n-eigen", "100000", "--budget-s", "4", "--quiet", "--no-video",
                 "--out", str(tmp_path / "c")])
    _one_line_error(capsys, code, "tactex clean: error:", "--n-eigen 100000 eigenpairs", "ask for fewer")


@pytest.mark.slow
def test_clean_n_eigen_refused_with_the_value_given(tmp_path, capsys) -> None:
    # 12 mm voxels leave a few hundred points: small enough for the dense solver, so only a check refuses it.
    code = main(["clean", "--n-eigen", "100000", "--voxel-size-m", "0.012", "--budget-s", "3", "--quiet",
                 "--no-video", "--out", str(tmp_path / "c")])
    line = _one_line_error(capsys, code, "--n-eigen 100000")
    assert line.count("--n-eigen") == 1, line


@pytest.mark.slow
def test_clean_end_to_end(tmp_path, capsys) -> None:
    out = tmp_path / "clean"
    code = main(["clean", "--budget-s", "8", "--quiet", "--no-video", "--out", str(out)])
    stdout = capsys.readouterr().out
    assert code == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert set(CLEAN_METRIC_KEYS) <= set(metrics)
    assert 0.0 <= metrics["dirt_removed_fraction"] <= 1.0
    assert 8.0 <= metrics["sim_time_s"] <= 8.0 + UNLOAD_S + 0.45  # the budget, then the final unload and lift-off
    assert json.loads((out / "config.json").read_text())["budget_s"] == 8.0
    for name in ("dirt.png", "force.png", "phases.png", "cloud.png", "cloud_tcp.png"):
        assert (out / name).read_bytes()[:8] == PNG_MAGIC, name
    with np.load(out / "series.npz", allow_pickle=False) as z:
        assert z["tcp"].shape == (z["t"].shape[0], 3) and z["t"][-1] == pytest.approx(metrics["sim_time_s"], abs=0.02)
    lines = stdout.strip().splitlines()
    assert lines[0].startswith("run") and "dirt removed" in lines[0] and lines[2].startswith("tactex")
    assert f"{100 * metrics['dirt_removed_fraction']:.1f} %" in lines[2]
    assert lines[-1] == f"report: {out / 'report.html'}"


@pytest.mark.slow
def test_wipe_compare_end_to_end(tmp_path, capsys) -> None:
    out = tmp_path / "wipe"
    code = main(["wipe", "--compare", "--duration-s", "2", "--quiet", "--no-video", "--out", str(out)])
    stdout = capsys.readouterr().out
    assert code == 0
    for name in ("tactex", "cartesian"):
        metrics = json.loads((out / name / "metrics.json").read_text())
        assert set(WIPE_METRIC_KEYS) <= set(metrics), name
        assert json.loads((out / name / "config.json").read_text())["baseline"] == ("" if name == "tactex" else name)
        assert (out / name / "fig3c_force.png").read_bytes()[:8] == PNG_MAGIC
    index = (out / "index.html").read_text()
    assert "href='tactex/report.html'" in index and "href='cartesian/report.html'" in index
    assert (out / "compare.png").read_bytes()[:8] == PNG_MAGIC  # the overlay of the two, above the table
    assert index.index("src='compare.png'") < index.index("<table")
    table = (out / "summary.txt").read_text().splitlines()
    assert [ln.split()[0] for ln in table[2:]] == ["tactex", "cartesian"] and "force MAE [N]" in table[0]
    assert stdout.strip().splitlines()[-1] == f"report: {out / 'index.html'}"


@pytest.mark.slow
def test_demo_quick_end_to_end(tmp_path, capsys) -> None:
    out = tmp_path / "demo"
    # --quick takes a quarter of the budgets: 8 s of cleaning (first contact ~5.5 s) and 2 s of wiping.
    code = main(["demo", "--quick", "--clean-budget-s", "32", "--wipe-duration-s", "8", "--quiet", "--no-video",
                 "--out", str(out)])
    stdout = capsys.readouterr().out
    assert code == 0
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["demo"]["quick"] is True and cfg["tasks"]["clean"]["budget_s"] == 8.0
    assert cfg["tasks"]["wipe"]["duration_s"] == 2.0
    assert set(CLEAN_METRIC_KEYS) <= set(json.loads((out / "clean" / "tactex" / "metrics.json").read_text()))
    assert set(WIPE_METRIC_KEYS) <= set(json.loads((out / "wipe" / "tactex" / "metrics.json").read_text()))
    index = (out / "index.html").read_text()
    assert "href='clean/tactex/report.html'" in index and "href='wipe/tactex/report.html'" in index
    assert (out / "clean" / "tactex" / "report.html").is_file() and (out / "wipe" / "tactex" / "report.html").is_file()
    lines = stdout.strip().splitlines()
    assert lines[0] == "clean:" and "wipe:" in lines and "dirt removed" in lines[1]
    assert lines[-1].endswith(f"report: {out / 'index.html'}") and lines[-1].startswith("2 runs in ")
    assert (out / "summary.txt").read_text().strip() == "\n".join(lines[:-2]).strip()


def test_a_directory_as_cloud_is_named_as_such(tmp_path, capsys) -> None:
    (tmp_path / "clouds.ply").mkdir()
    code = main(["explore", str(tmp_path / "clouds.ply"), "--out", str(tmp_path / "x")])
    _one_line_error(capsys, code, "is a directory")


def test_a_tiny_cloud_gets_no_impossible_n_eigen_hint() -> None:
    from tactex.errors import SpectralError
    from tactex.spectral.basis import _check_n_eigen

    with pytest.raises(SpectralError, match=r"only 1 point\(s\): too few"):
        _check_n_eigen(200, 1)
    with pytest.raises(SpectralError, match=r"fewer than 10 \(e\.g\. 5\)"):
        _check_n_eigen(20, 10)


def test_an_unreachable_capture_pose_names_the_parameter(tmp_path, capsys) -> None:
    # the level view (0°): 0.45 m out at the wall's mid-height is beyond the arm
    code = main(["clean", "--object-name", "cup", "--side-capture-distance-m", "0.45", "--side-capture-elevation-deg",
                 "0", "--out", str(tmp_path / "c")])
    _one_line_error(capsys, code, "out of the arm's reach", "lower --side-capture-distance-m (now 0.45 m)")


def test_safety_summary_says_how_often_and_why() -> None:
    from tactex.report.run_report import safety_summary

    assert safety_summary({"safety_counts": {}}) is None and safety_summary({}) is None
    said = safety_summary({"safety_counts": {"force_limit": 22, "retreat_end": 22, "torque_rate_limit": 310},
                           "safety_limits": {"max_contact_force_n": 40.0, "tau_rate_max_n_m_s": 1000.0},
                           "max_contact_force_n": 61.24})
    assert said == ("retreated 22× from a contact force above 40 N, peak |F| 61.2 N; "
                    "clipped the torque rate (1000 N·m/s) on 310 tick(s)")
    dry = safety_summary({"safety_counts": {"torque_limit": 4362}, "dry_run": True})
    assert dry == "dry run, on torques computed but not sent; saturated the torque at the joint limits on 4362 tick(s)"


def test_a_wipe_says_when_its_duration_cut_the_policy_file_short() -> None:
    from tactex.report.run_pages import run_remarks

    cut = {"policy": {"file": "long.toml", "duration_s": 20.0, "own_duration_s": 5000.0}}
    assert run_remarks(cut) == [("policy", "the run ended at --duration-s 20 s, 4980 s before the policy's end "
                                           "(5000 s): give --duration-s 5000 to run all of it")]
    for whole in ({"file": "short.toml", "duration_s": 12.0, "own_duration_s": 12.0},
                  {"file": "", "duration_s": 20.0, "own_duration_s": float("inf")}):  # the sinusoid: no end
        assert run_remarks({"policy": whole}) == []


def test_a_clean_says_what_its_first_leg_was_and_why() -> None:
    from tactex.experiments.run import remark_lines

    sweep = "a planned sweep over strokes (3 legs, 0.40 m)"
    lines = remark_lines([("tactex", {"first_leg": sweep}), ("region raster", {"first_leg": ""}),
                          ("wipe", {})])
    assert lines == [f"first leg (tactex): {sweep}"]


@pytest.mark.slow
def test_a_run_whose_safety_layer_stepped_in_says_so_in_its_last_lines(tmp_path, capsys, monkeypatch) -> None:
    """A clean at 60 N retreated 22 times and the terminal said only "dirt removed 43.6 %"."""
    from tactex.control.safety import SafetyLimits
    from tactex.robots import loop

    argv = ["wipe", "--duration-s", "3", "--quiet", "--no-video"]
    assert main([*argv, "--out", str(tmp_path / "calm")]) == 0
    assert json.loads((tmp_path / "calm" / "metrics.json").read_text())["safety_counts"] == {}
    assert "safety layer" not in capsys.readouterr().out
    real = loop.ControlLoop.__init__

    def low_cap(self, backend, limits=None, **kw) -> None:  # the layer trips below the wipe's 15 N set point
        real(self, backend, SafetyLimits(max_contact_force=8.0), **kw)

    monkeypatch.setattr(loop.ControlLoop, "__init__", low_cap)
    out = tmp_path / "tripped"
    assert main([*argv, "--out", str(out)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    m = json.loads((out / "metrics.json").read_text())
    n = m["safety_counts"]["force_limit"]
    assert n >= 1 and m["safety_limits"]["max_contact_force_n"] == 8.0
    # after the table, before the report's path (a motion line on the alignment may follow it)
    said = f"safety layer (tactex): retreated {n}× from a contact force above 8 N, peak |F| "
    line = next(line for line in lines[-3:-1] if line.startswith(said))
    # the peak it quotes is the magnitude the layer judged, over every tick: above the cap that tripped it
    assert float(line[len(said):].split(" N")[0]) == pytest.approx(m["max_force_norm_n"], abs=0.05)
    assert m["max_force_norm_n"] > 8.0 and m["max_force_norm_n"] >= m["max_force_n"]
    assert lines[-1] == f"report: {out / 'report.html'}"
