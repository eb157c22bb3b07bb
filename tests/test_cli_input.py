"""What a new user meets with their own files and careless input, through the CLI: every mistake is
one line on stderr, exit code 2, no traceback, no Python or numpy advice, and names the option as
the user typed it, once. Python warnings reach stderr as one plain line, never with a source path.
A run folder that was made always says how the run ended (status.json)."""

from __future__ import annotations

import argparse
import json
import re

import numpy as np
import pytest

from tactex.cli import build_parser, main
from tactex.config import dataclass_from_args
from tactex.errors import ConfigError
from tactex.pointcloud import SurfaceCloud, save_ply
from tests.format_fixtures import box_mesh, camera_like_cloud, write_pcd

# Words a CLI user must never be shown: Python's and numpy's advice, library internals, source paths.
FORBIDDEN = ("Traceback", "allow_pickle", "pickled data", "pydantic", "http", "validation error", ".py:",
             "Config.", "np.", "numpy", "ValueError", "(default: None)")


def _fields(command: str) -> set[str]:
    """The Python names (argparse destinations) of a command's options: voxel_size_m, n_eigen, ..."""
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {a.dest for a in sub.choices[command]._actions if a.option_strings and a.dest != "help"}


def _unquoted(line: str) -> str:
    return re.sub(r"'[^']*'", "''", line)


def _one_line(capsys, code: int, command: str, *needles: str) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith(f"tactex {command}: warning:")]
    assert code == 2, err
    assert len(lines) == 1, err
    line = lines[0]
    assert line.startswith(f"tactex {command}: error: "), line
    for word in FORBIDDEN:
        assert word not in line, line
    words = set(re.findall(r"(?<![-\w])[a-z][a-z0-9_]*(?![\w-])", _unquoted(line)))
    assert not {w for w in words & _fields(command) if "_" in w or f"{w} must" in line}, line
    for needle in needles:
        assert needle in line, line
    return line


def _run(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as exc:  # argparse's own refusals exit from parse_args, as the console script does
        return int(exc.code)


# --- cloud files -----------------------------------------------------------------------------------


@pytest.fixture
def files(tmp_path):
    """Broken and awkward files as users have them."""
    f = {}
    good = save_ply(SurfaceCloud(points=np.random.default_rng(0).random((50, 3)) * 0.05), tmp_path / "good.ply")
    f["good"] = good
    raw = good.read_bytes()
    (tmp_path / "truncated.ply").write_bytes(raw[: len(raw) // 2])
    f["truncated"] = tmp_path / "truncated.ply"
    (tmp_path / "empty.ply").write_text("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
                                        "property float z\nend_header\n")
    f["empty"] = tmp_path / "empty.ply"
    (tmp_path / "x.npz").write_text("hello")
    f["fake_npz"] = tmp_path / "x.npz"
    np.savez(tmp_path / "objects.npz", points=np.array([{"a": 1}], dtype=object))
    f["object_npz"] = tmp_path / "objects.npz"
    (tmp_path / "bad.pcd").write_text("VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1\nPOINTS 1\n"
                                      "DATA ascii\n1 2 3\n")
    f["bad_pcd"] = tmp_path / "bad.pcd"
    (tmp_path / "v9.pcd").write_text("VERSION .9\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 1\nDATA ascii\n1 2 3\n")
    f["v9_pcd"] = tmp_path / "v9.pcd"
    (tmp_path / "notes.txt").write_text("x")
    f["txt"] = tmp_path / "notes.txt"
    (tmp_path / "folder.ply").mkdir()
    f["dir"] = tmp_path / "folder.ply"
    box_mesh(2.0).export(str(tmp_path / "cube.ply"))
    f["cube"] = tmp_path / "cube.ply"
    box_mesh(200.0).export(str(tmp_path / "part_mm.stl"))
    f["mm"] = tmp_path / "part_mm.stl"
    save_ply(SurfaceCloud(points=np.random.default_rng(1).random((300, 3)) * 0.05, colors=np.full((300, 3), 0.9)),
             tmp_path / "white.ply")
    f["white"] = tmp_path / "white.ply"
    return f


@pytest.mark.parametrize(
    ("name", "extra", "needles"),
    [
        ("truncated", [], ("not a readable PLY file",)),
        ("empty", [], ("empty",)),
        ("fake_npz", [], ("is not an .npz file",)),
        ("object_npz", [], ("Python objects",)),
        ("bad_pcd", [], ("3 FIELDS but 2 COUNT",)),
        ("v9_pcd", [], ("VERSION .9", ".5, .6 or .7")),
        ("txt", [], ("unknown suffix", ".stl")),
        ("dir", [], ("is a directory",)),
        ("cube", [], ("--voxel-size-m 0.011",)),
        ("cube", ["--voxel-size", "0.003"], ("--voxel-size 0.011",)),
        ("mm", [], ("millimetres", "give --units mm")),
        ("white", [], ("no point of", "red by hue", "--target-saturation", "--target-threshold")),
        ("white", ["--target", "green"], ("green by hue",)),
        ("white", ["--target-threshold", "1.0"], ("red channel ≥ 1", "lower --target-threshold")),
    ],
)
def test_explore_file_mistakes(files, tmp_path, capsys, name, extra, needles) -> None:
    code = _run(["explore", str(files[name]), *extra, "--quiet", "--out", str(tmp_path / "run")])
    _one_line(capsys, code, "explore", *needles)
    assert not (tmp_path / "run").exists()  # nothing ran, no empty folder


def test_clean_cloud_mistakes(files, tmp_path, capsys) -> None:
    code = _run(["clean", "--cloud", str(files["fake_npz"]), "--quiet", "--out", str(tmp_path / "c")])
    _one_line(capsys, code, "clean", "is not an .npz file")


def test_marking_with_cloud_is_refused_only_when_given(files, tmp_path, capsys) -> None:
    """--cloud's target is the dirt: a --marking beside it was ignored without a word."""
    from tactex.tasks.clean import CleanConfig

    out = tmp_path / "c"
    code = _run(["clean", "--cloud", str(files["good"]), "--marking", "RLI", "--quiet", "--out", str(out)])
    _one_line(capsys, code, "clean", "--marking has no effect with --cloud", "drop --marking")
    assert not out.exists()
    # the default marking, which the user did not give, is no mistake
    args = build_parser().parse_args(["clean", "--cloud", str(files["good"]), "--out", str(out)])
    assert dataclass_from_args(CleanConfig, args).cloud == str(files["good"])


def test_sweep_file_mistakes(files, tmp_path, capsys) -> None:
    code = _run(["sweep", str(files["bad_pcd"]), "--quiet", "--out", str(tmp_path / "s")])
    _one_line(capsys, code, "sweep", "3 FIELDS but 2 COUNT")


# --- option values ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("argv", "needles"),
    [
        (["explore", "cup", "--steps", "abc"], ("--steps", "needs a whole number, got 'abc'")),
        (["explore", "cup", "--alpha", "x"], ("--alpha", "needs a number, got 'x'")),
        (["explore", "cup", "--steps", "0"], ("--steps 0",)),
        (["explore", "cup", "--n-eigen", "-2"], ("--n-eigen -2",)),
        (["explore", "cup", "--voxel-size-m", "-1"], ("--voxel-size-m -1",)),
        (["explore", "cup", "--voxel-size", "-1"], ("--voxel-size -1",)),
        (["explore", "cup", "--agent-radius-m", "5"], ("--agent-radius-m 5",)),
        (["explore", "cup", "--agent-radius", "0"], ("--agent-radius 0",)),
        (["explore", "cup", "--target", "purple"], ("unknown target 'purple'", "red")),
        (["explore", "cup", "--target-saturation", "2"], ("--target-saturation 2",)),
        (["explore", "cup", "--target", "all", "--target-threshold", "0.5"], ("--target-threshold", "--target all")),
        (["explore", "cup", "--marking", "Z"], ("unknown marking 'Z'", "RLI")),
        (["explore", "teapot"], ("'teapot'", "plate")),
        (["explore", "cup", "--x0", "1", "2"], ("--x0", "expected 3 arguments")),
        (["explore", "cup", "--n-eigen", "99999"], ("--n-eigen",)),
        (["explore", "cup", "--coverage-normalization", "cloud"], ("--coverage-normalization",)),
        (["explore", "cup", "--bogus", "1"], ("unrecognized arguments: --bogus 1",)),
        (["clean", "--obj", "plate"], ("ambiguous option: --obj could match --object, --object-position",)),
        (["clean", "--object", "teapot"], ("unknown object 'teapot'", "plate")),
        (["clean", "--object-name", "teapot"], ("unknown object 'teapot'",)),
        (["clean", "--marking", "Q"], ("unknown marking 'Q'",)),
        (["clean", "--force-n", "-5"], ("--force-n must be a positive number",)),
        (["clean", "--voxel-size-m", "0"], ("--voxel-size-m must be a positive number",)),
        # the safety layer retreats at 40 N of contact: a set point whose peaks (2× it) reach that cannot work
        (["clean", "--force-n", "60"], ("--force-n 60 N", "retreats at a contact force of 40 N",
                                        "give at most 20 N")),
        (["wipe", "--force-n", "20.5"], ("--force-n 20.5 N", "at most 20 N")),
        (["clean", "--approach-force-n", "0.5"], ("--approach-force-n 0.5 N", "--contact-threshold-n")),
        (["wipe", "--object", "nope"], ("unknown object 'nope'",)),
        (["wipe", "--force-n", "nan"], ("--force-n",)),
        (["sweep", "cup", "--n-eigen", "0"], ("--n-eigen values must be positive",)),
        (["sweep", "cup", "--alpha", "-1"], ("--alpha values must be positive",)),
        (["sweep", "cup", "--voxel-size-m", "3"], ("--voxel-size-m 3", "in metres")),
        (["demo", "--clean-budget-s", "-1"], ("--clean-budget-s",)),
    ],
)
def test_option_mistakes_name_the_option_once(tmp_path, capsys, argv, needles) -> None:
    code = _run([*argv, "--quiet", "--out", str(tmp_path / "run")])
    line = _one_line(capsys, code, argv[0], *needles)
    typed = [a for a in argv if a.startswith("--")]
    if typed and "ambiguous" not in line and "unrecognized" not in line:
        assert line.count(typed[0] + " ") + line.count(typed[0] + ":") <= 1 or typed[0] in ("--target",), line


def test_object_names_and_markings_in_any_case() -> None:
    parser = build_parser()
    from tactex.tasks.clean import CleanConfig
    from tactex.tasks.wipe import WipeConfig

    args = parser.parse_args(["clean", "--object", "Plate", "--marking", "x", "--out", "o"])
    cfg = dataclass_from_args(CleanConfig, args)
    assert (cfg.object_name, cfg.marking) == ("plate", "X")
    args = parser.parse_args(["clean", "--object-name", "BOWL", "--marking", "rli", "--out", "o"])
    assert (dataclass_from_args(CleanConfig, args).object_name, dataclass_from_args(CleanConfig, args).marking) == (
        "bowl", "RLI")
    args = parser.parse_args(["wipe", "--object", "Sine_Panel", "--out", "o"])
    assert dataclass_from_args(WipeConfig, args).object_name == "sine_panel"
    from tactex.experiments.explore import ExploreConfig, load_explore_cloud

    cloud, info = load_explore_cloud("CUP", ExploreConfig(voxel_size_m=0.006, marking="x"))
    assert info["name"] == "cup" and info["marking"] == "X" and cloud.n_target > 0


def test_clean_takes_its_preston_estimate_by_the_old_name_too() -> None:
    """clean's k_p is its wear model's estimate (--preston-estimate), the twin's --preston-coefficient the simulated
    sponge's true one: clean's old spelling still works, hidden from its help."""
    parser = build_parser()
    from tactex.tasks.clean import CleanConfig

    for flag in ("--preston-estimate", "--preston-coefficient"):
        args = parser.parse_args(["clean", flag, "0.004", "--out", "o"])
        assert dataclass_from_args(CleanConfig, args).preston_coefficient == 0.004
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    shown = {s for a in sub.choices["clean"]._actions if a.help != "==SUPPRESS==" for s in a.option_strings}
    assert "--preston-estimate" in shown and "--preston-coefficient" not in shown


def test_clean_sets_the_simulated_dirts_true_coefficient_apart_from_its_estimate() -> None:
    """--dirt-preston-coefficient is the simulated dirt's k_p (the scene's), --preston-estimate the wear model's: a
    miscalibrated estimate is one set apart from the other; a value that is no coefficient is refused by name."""
    from tactex.tasks.clean import CleanConfig

    args = build_parser().parse_args(["clean", "--dirt-preston-coefficient", "0.0035", "--out", "o"])
    cfg = dataclass_from_args(CleanConfig, args)
    assert cfg.scene().preston_coefficient == 0.0035 and cfg.preston_coefficient == CleanConfig().preston_coefficient
    assert CleanConfig().scene().preston_coefficient == CleanConfig().preston_coefficient  # calibrated by default
    for bad in (0.0, -1e-3, float("nan"), float("inf")):
        with pytest.raises(ConfigError, match="dirt_preston_coefficient must be a positive number"):
            CleanConfig(dirt_preston_coefficient=bad)


def test_the_simulated_dirts_coefficient_is_refused_on_a_robot(tmp_path, capsys) -> None:
    code = main(["clean", "--robot", "franka", "--robot-ip", "127.0.0.1", "--dirt-preston-coefficient", "0.003",
                 "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 2 and "--dirt-preston-coefficient sets the simulated dirt's" in err
    assert "tactex twin --preston-coefficient" in err and not (tmp_path / "run").exists()


def test_help_shows_each_default_once_as_typed(capsys) -> None:
    parser = build_parser()
    for command in ("explore", "sweep", "clean", "wipe", "demo", "twin"):
        with pytest.raises(SystemExit):
            parser.parse_args([command, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        for bad in ("(default: None)", "(default: )", "(default: (", "(default: [", "(default: '')"):
            assert bad not in text, (command, bad)
        assert not re.search(r"default[^()]*\) \(default:", text), command
        assert "--object-name" not in text and "--voxel-size " not in text  # old names work, help shows one
        assert "--voxel-size VOXEL" not in text and "--target-channel" not in text


def test_one_vocabulary_across_commands() -> None:
    """The same parameter has the same option in every command (README 'Options')."""
    parser = build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    shown = {}
    for name, p in sub.choices.items():
        shown[name] = {s for a in p._actions if a.help != "==SUPPRESS==" for s in a.option_strings}
    for command in ("explore", "sweep"):
        assert {"--voxel-size-m", "--agent-radius-m", "--n-eigen", "--alpha", "--steps", "--seed", "--target",
                "--out", "--quiet"} <= shown[command], command
    for command in ("clean", "wipe"):
        assert {"--object", "--voxel-size-m", "--agent-radius-m", "--n-eigen", "--alpha", "--out",
                "--quiet"} <= shown[command] | {"--voxel-size-m", "--agent-radius-m", "--n-eigen", "--alpha"}
    assert "--object" in shown["twin"] and "--object" in shown["clean"]
    assert "--pad-radius-m" in shown["twin"] and "--pad-radius-m" in shown["clean"]  # one sponge, one name
    assert "--tool-pad-radius-m" not in shown["twin"]
    for command, options in shown.items():
        assert not {"--voxel-size", "--agent-radius", "--object-name", "--target-channel"} & options, command


# --- warnings, notes, run folders ------------------------------------------------------------------


def test_warnings_reach_stderr_as_one_plain_line(tmp_path, capsys) -> None:
    """The voxel filter's warning (a cloud sparser than the voxel) printed "…/voxel.py:81: RuntimeWarning"."""
    g = np.arange(0.0, 0.1, 0.01)
    x, y = np.meshgrid(g, g)
    pts = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    path = save_ply(SurfaceCloud(points=pts, colors=np.tile([1.0, 0.0, 0.0], (len(pts), 1))), tmp_path / "sparse.ply")
    code = _run(["explore", str(path), "--steps", "5", "--n-eigen", "8", "--no-html", "--no-cache",
                 "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 0, err
    warning = [ln for ln in err.splitlines() if "warning:" in ln]
    assert any(ln.startswith("tactex explore: warning: voxel size 3 mm is finer") and "--voxel-size-m 0.01 or more"
               in ln for ln in warning), err
    assert not re.search(r"\.py:\d+", err) and "RuntimeWarning" not in err and "warnings.warn" not in err


def test_nan_points_are_dropped_counted_and_said(tmp_path, capsys) -> None:
    pts, rgb, _ = camera_like_cloud(spacing_m=0.004)
    path = write_pcd(tmp_path / "table.pcd", pts, ".5", "binary", rgb)
    code = _run(["explore", str(path), "--steps", "5", "--n-eigen", "8", "--no-html", "--no-cache",
                 "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "tactex explore: cloud: dropped 25 of 2500 points with NaN/inf coordinates or normals" in err
    target = [ln for ln in err.splitlines() if ln.startswith("tactex explore: target: red by hue")]
    assert len(target) == 1 and "points are target" in target[0] and "within x" in target[0], err
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["source"]["n_dropped_nonfinite"] == 25
    # only the red stroke (|y - 0.1 m| < 4 mm) is target
    fields = np.load(tmp_path / "run" / "fields.npz", allow_pickle=False)
    marked = fields["points"][fields["target"] > 0]
    assert len(marked) > 0 and np.abs(marked[:, 1] - 0.1).max() < 0.004 + 0.003


def _status(out) -> dict:
    return json.loads((out / "status.json").read_text())


def test_a_failed_run_says_why_in_its_folder(tmp_path, capsys) -> None:
    out = tmp_path / "far"
    code = _run(["explore", "cup", "--x0", "5", "5", "5", "--quiet", "--no-cache", "--out", str(out)])
    line = _one_line(capsys, code, "explore", "--x0")
    status = _status(out)
    assert status["status"] == "failed" and status["error"] == line.split("error: ", 1)[1]
    assert status["options"]["x0"] == [5.0, 5.0, 5.0] and status["argv"][:2] == ["explore", "cup"]
    out = tmp_path / "eigen"
    code = _run(["explore", "cup", "--voxel-size-m", "0.01", "--n-eigen", "5000", "--quiet", "--out", str(out)])
    _one_line(capsys, code, "explore", "--n-eigen 5000")
    assert _status(out)["status"] == "failed"


def test_an_interrupted_run_says_so(tmp_path, capsys, monkeypatch) -> None:
    from tactex.ergodic import HedacExplorer

    def interrupt(self):
        raise KeyboardInterrupt

    monkeypatch.setattr(HedacExplorer, "step", interrupt)
    out = tmp_path / "ctrl_c"
    assert _run(["explore", "cup", "--steps", "5", "--n-eigen", "8", "--quiet", "--no-cache", "--out", str(out)]) == 130
    assert "tactex explore: interrupted" in capsys.readouterr().err
    assert _status(out)["status"] == "interrupted"


def test_a_folder_holding_another_run_is_refused_without_force(tmp_path, capsys) -> None:
    """explore --out DIR wrote over another run's folder without a word."""
    argv = ["explore", "cup", "--steps", "5", "--n-eigen", "8", "--quiet", "--no-html", "--no-cache"]
    out = tmp_path / "run"
    assert _run([*argv, "--out", str(out)]) == 0
    capsys.readouterr()
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    code = _run([*argv, "--seed", "1", "--out", str(out)])
    _one_line(capsys, code, "explore", f"--out '{out}' holds a tactex explore run (done, ",
              "give a new folder, or add --force")
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # status.json included
    # a bad option there leaves the other run's status alone too
    _one_line(capsys, _run([*argv[:2], "--steps", "0", "--out", str(out)]), "explore", "--steps 0")
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    # other commands refuse it as well, before any work
    for command in (["sweep", "cup", "--steps", "5"], ["clean"], ["wipe"], ["demo"], ["study"]):
        _one_line(capsys, _run([*command, "--quiet", "--out", str(out)]), command[0], "holds a tactex explore run")
    assert _run([*argv, "--seed", "1", "--force", "--out", str(out)]) == 0
    assert _status(out)["status"] == "done" and _status(out)["options"]["seed"] == 1
    # a folder of files without a run in it is no other run's, nor one whose run failed (a typo fixed, run again)
    plain = tmp_path / "plain"
    plain.mkdir()
    (plain / "notes.txt").write_text("x")
    assert _run([*argv[:2], "--steps", "0", "--out", str(plain)]) == 2
    assert _status(plain)["status"] == "failed"
    assert _run([*argv, "--out", str(plain)]) == 0


def test_sweep_study_and_demo_take_over_only_their_own_folder(tmp_path) -> None:
    """sweep and study resume their own folder (the same command again) and the demo replaces its own
    (make demo twice in a row); a folder of another command's run is still refused."""
    from tactex.errors import InputError
    from tactex.experiments.run_folder import check_run_folder

    for command in ("sweep", "study", "demo"):
        out = tmp_path / command
        out.mkdir()
        (out / "status.json").write_text(json.dumps({"command": command, "status": "done",
                                                     "started": "2026-12-02T01:00:00"}))
        check_run_folder(out, command, own=True)
        with pytest.raises(InputError, match=f"holds a tactex {command} run"):
            check_run_folder(out, "explore")
        with pytest.raises(InputError, match="add --force"):
            check_run_folder(out, "sweep" if command != "sweep" else "study", own=True)
    (tmp_path / "lib").mkdir()
    (tmp_path / "lib" / "metrics.json").write_text("{}")  # a run written by the library: no status.json
    with pytest.raises(InputError, match="holds a run;"):
        check_run_folder(tmp_path / "lib", "demo", own=True)
    check_run_folder(tmp_path / "lib", "explore", force=True)


def test_a_study_killed_before_its_status_is_resumed_in_its_folder(tmp_path) -> None:
    """A study or sweep killed outright (SIGKILL, a lost ray:// client) leaves its results but no
    status.json: its files say whose folder it is, so the same command resumes there and another is
    refused."""
    from tactex.errors import InputError
    from tactex.experiments.run_folder import check_run_folder

    for command, name in (("study", "runs.jsonl"), ("study", "study.json"), ("sweep", "sweep.json")):
        out = tmp_path / command / name
        out.mkdir(parents=True)
        (out / name).write_text("{}\n")
        check_run_folder(out, command, own=True)
        with pytest.raises(InputError, match=f"holds a tactex {command} run"):
            check_run_folder(out, "explore")


def test_a_finished_run_says_done(tmp_path, capsys) -> None:
    out = tmp_path / "ok"
    assert _run(["explore", "cup", "--steps", "5", "--n-eigen", "8", "--quiet", "--no-html", "--no-cache",
                 "--out", str(out)]) == 0
    assert _status(out)["status"] == "done" and (out / "metrics.json").is_file()


def test_long_runs_keep_small_files_and_say_how_long(tmp_path, capsys, monkeypatch) -> None:
    """--steps 200000 wrote an 11 MB metrics.json and a 14 MB page: per-step series go to series.npz,
    the page's path is decimated, and progress comes every few seconds with the time left."""
    from tactex.experiments import explore
    from tactex.report.html import cloud_html

    monkeypatch.setattr(explore, "PROGRESS_EVERY_S", 0.0)  # every step is "a few seconds" later
    out = tmp_path / "run"
    assert _run(["explore", "cup", "--steps", "40", "--n-eigen", "8", "--no-cache", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    steps = [ln for ln in err.splitlines() if ": step " in ln]
    # the first step says its own time (it may lay a pass plan); the time left comes from the steps after it
    assert len(steps) == 40 and "(the first step: " in steps[0] and "s left)" in steps[1] and "left" not in steps[-1]
    metrics = json.loads((out / "metrics.json").read_text())
    assert "ergodicity" not in metrics and metrics["series_file"] == "series.npz"
    with np.load(out / "series.npz", allow_pickle=False) as z:
        assert z["ergodicity"].shape == z["step_time_s"].shape == (40,)
    pts = np.random.default_rng(0).random((500, 3)) * 0.1
    long_path = np.cumsum(np.random.default_rng(1).normal(0, 1e-3, (200_000, 3)), axis=0)
    short = cloud_html(pts, None, tmp_path / "short.html", trajectory=long_path[:4000], include_plotlyjs=False)
    long = cloud_html(pts, None, tmp_path / "long.html", trajectory=long_path, include_plotlyjs=False)
    assert long.stat().st_size < 1.2 * short.stat().st_size


def test_a_warning_names_its_command_once(capsys) -> None:
    import argparse

    from tactex.cli import _show_warning

    show = _show_warning(argparse.Namespace(command="clean"), {})
    show("clean: no hover pose over [0.5, 0.0, 0.1] m within reach", RuntimeWarning, "program.py", 1)
    show("cleaning ends early", RuntimeWarning, "program.py", 2)  # a word that only starts like the command
    assert capsys.readouterr().err.splitlines() == [
        "tactex clean: warning: no hover pose over [0.5, 0.0, 0.1] m within reach",
        "tactex clean: warning: cleaning ends early"]


def test_a_start_off_the_surface_is_refused_before_the_basis(tmp_path, capsys, monkeypatch) -> None:
    import tactex.experiments.explore as explore

    def no_basis(*args, **kwargs):
        raise AssertionError("the basis was built before the start was checked")

    monkeypatch.setattr(explore, "_set_up", no_basis)
    assert main(["explore", "plate", "--x0", "5", "5", "5", "--out", str(tmp_path / "r"), "--quiet"]) == 2
    assert "--x0 [5.0, 5.0, 5.0] m is 8543.7 mm from the nearest cloud point" in capsys.readouterr().err
