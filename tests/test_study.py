"""`tactex study` and the local executor: plans, failures recorded, resume, Ctrl-C, worker loss, bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tactex.cli import main
from tactex.errors import ConfigError, InputError
from tactex.experiments.executor import LocalExecutor, make_executor
from tactex.experiments.study import run_study
from tactex.experiments.study_spec import StudySpec, load_spec_file, spec_from_dict
from tactex.experiments.study_table import t_interval, wilson_interval
from tests.executor_tasks import die_once, square

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
# Short runs on the plate; n_eigen = 100000 is more than a capture has points, so that run raises
# (after its capture) inside the worker: a failure the study records and goes on from.
SMALL = {"task": "clean", "fixed": {"object_name": "plate", "budget_s": 1.0, "camera_width": 160,
                                     "camera_height": 120},
         "grid": {"baseline": ["", "raster"]}, "seeds": 1}


# -- executor units (cheap functions) --------------------------------------------------------------------
@pytest.mark.parametrize("workers", [1, 2])
def test_local_executor_runs_every_task_and_records_errors(workers):
    with LocalExecutor(workers) as ex:
        outs = sorted(ex.run(square, list(range(5)), 10), key=lambda o: o.index)
    assert [o.value for o in outs if o.ok] == [10, 11, 14, 26]
    bad = outs[3]
    assert not bad.ok and bad.error == "ValueError: three is not allowed" and "square" in bad.traceback
    assert all(o.worker and o.seconds >= 0 for o in outs)


def test_a_lost_local_worker_has_its_run_retried(tmp_path):
    with LocalExecutor(2) as ex:
        outs = sorted(ex.run(die_once, list(range(4)), str(tmp_path)), key=lambda o: o.index)
    assert (tmp_path / "died-1").exists()  # the worker did die
    assert [o.value for o in outs] == [0, 1, 2, 3] and all(o.ok for o in outs)


def test_executor_options_are_checked():
    with pytest.raises(ConfigError, match="--workers"):
        LocalExecutor(-1)
    with pytest.raises(ConfigError, match="--ray-address"):
        make_executor(ray_address=" ")


def test_intervals():
    lo, hi = wilson_interval(0, 10)
    assert lo == pytest.approx(0.0, abs=1e-12) and 0.2 < hi < 0.35
    lo, hi = wilson_interval(10, 10)
    assert 0.65 < lo < 0.8 and hi == pytest.approx(1.0, abs=1e-12)
    mean, std, half = t_interval(np.array([1.0, 2.0, 3.0]))
    assert mean == 2.0 and std == 1.0 and half == pytest.approx(4.302653 / np.sqrt(3), rel=1e-6)
    assert np.isnan(t_interval(np.array([1.0]))[2])


# -- the plan --------------------------------------------------------------------------------------------
def test_plan_is_grid_times_draws_times_seeds_and_reproducible():
    spec = StudySpec(task="clean", grid={"object_name": ["plate", "cup"], "tool_friction": ["0.2", 0.8]},
                     random={"force_n": {"uniform": [5, 15]}, "n_eigen": {"integers": [50, 200]}},
                     draws=3, seeds=2, fixed={"budget_s": "5"})
    runs = spec.runs()
    assert len(runs) == 2 * 2 * 3 * 2
    assert spec.factors == ("object_name", "tool_friction", "force_n", "n_eigen", "seed")
    assert runs[0].config == {"budget_s": 5.0, "object_name": "plate", "tool_friction": 0.2,
                              "force_n": runs[0].config["force_n"], "n_eigen": runs[0].config["n_eigen"], "seed": 0}
    assert all(5.0 <= r.config["force_n"] <= 15.0 and isinstance(r.config["n_eigen"], int) for r in runs)
    assert len({r.run_id for r in runs}) == len(runs)
    again = StudySpec(task="clean", grid={"object_name": ["plate", "cup"], "tool_friction": [0.2, 0.8]},
                      random={"force_n": {"uniform": [5, 15]}, "n_eigen": {"integers": [50, 200]}},
                      draws=3, seeds=2, fixed={"budget_s": 5.0})
    assert [r.run_id for r in again.runs()] == [r.run_id for r in runs]


@pytest.mark.parametrize("changes, match", [
    ({"task": "fly"}, "unknown study task"),
    ({"grid": {"frobnicate": [1]}}, "not a parameter of CleanConfig"),
    ({"grid": {"tool_friction": []}}, "no levels"),
    ({"grid": {"tool_friction": [0.2, 0.2]}}, "twice"),
    ({"grid": {"tool_friction": ["slippery"]}}, "not a valid float"),
    ({"grid": {"seed": [1, 2]}}, "seeds"),
    ({"fixed": {"tool_friction": 0.3}, "grid": {"tool_friction": [0.2]}}, "given twice"),
    ({"seeds": 0}, "seeds must be"),
    ({"seeds": [1, 1]}, "distinct"),
    ({"random": {"force_n": {"uniform": [5, 15]}}}, "draws = 0"),
    ({"draws": 2}, "needs \\[random\\]"),
    ({"random": {"force_n": {"normal": [5, 1]}}, "draws": 1}, "unknown distribution"),
    ({"random": {"force_n": {"uniform": [15, 5]}}, "draws": 1}, "low < high"),
    ({"grid": {"object_name": ["teapot"]}}, "teapot"),
    # every level is checked before the first run, not only the first combination
    ({"grid": {"object_name": ["plate", "teapot"]}}, "^grid: object_name = 'teapot': unknown object 'teapot'"),
    ({"grid": {"force_n": [10.0, 500.0]}}, "^grid: force_n = 500.0"),
    ({"random": {"force_n": {"choice": [10.0, 500.0]}}, "draws": 1}, "force_n = 500"),
    ({"fixed": {"budget_s": -1.0}}, "budget_s"),
])
def test_spec_validation(changes, match):
    with pytest.raises(ConfigError, match=match):
        spec_from_dict({"task": "clean", **changes})


def test_spec_files(tmp_path):
    toml = tmp_path / "s.toml"
    toml.write_text('task = "clean"\nseeds = [0, 3]\n[grid]\ntool_friction = [0.2, 0.8]\n[fixed]\nbudget_s = 5\n')
    spec = spec_from_dict(load_spec_file(toml))
    assert spec.seeds == (0, 3) and spec.grid == {"tool_friction": (0.2, 0.8)} and spec.fixed == {"budget_s": 5.0}
    bad = tmp_path / "b.toml"
    bad.write_text('task = "clean"\ngird = 1\n')
    with pytest.raises(InputError, match="unknown key 'gird'"):
        load_spec_file(bad)
    with pytest.raises(InputError, match="does not exist"):
        load_spec_file(tmp_path / "missing.toml")
    with pytest.raises(InputError, match=r"\.toml, \.yaml"):
        load_spec_file(bad.rename(tmp_path / "s.json"))
    yaml = pytest.importorskip("yaml", reason="YAML study files need pyyaml (it comes with the distributed extra)")
    y = tmp_path / "s.yaml"
    y.write_text(yaml.safe_dump({"task": "clean", "grid": {"marking": ["X", "RLI"]}}))
    assert spec_from_dict(load_spec_file(y)).grid == {"marking": ("X", "RLI")}


def test_the_committed_example_study_file_is_valid():
    path = Path(__file__).resolve().parents[1] / "examples" / "studies" / "clean_robustness.toml"
    spec = spec_from_dict(load_spec_file(path))
    assert len(spec.runs()) == 270


# -- a real (short) study --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def small_study(tmp_path_factory):
    out = tmp_path_factory.mktemp("study")
    spec = spec_from_dict({**SMALL, "grid": {**SMALL["grid"], "n_eigen": [50, 100000]}})
    return spec, run_study(spec, out, LocalExecutor(1))


@pytest.mark.slow
def test_study_writes_table_summary_plots_and_records_the_failing_run(small_study):
    _, result = small_study
    out = result.out_dir
    assert len(result.records) == 4 and result.skipped == 0
    failed = result.failed
    # n_eigen = 100000 raises for tactex (the raster baseline builds no basis, so it runs)
    assert [(r["factors"]["baseline"], r["factors"]["n_eigen"]) for r in failed] == [("", 100000)]
    assert "n_eigen = 100000" in failed[0]["error"] and "Traceback" in failed[0]["traceback"]
    assert failed[0]["config"]["n_eigen"] == 100000
    lines = (out / "table.csv").read_text().splitlines()
    assert lines[0].startswith("run,run_id,baseline,n_eigen,seed,status,success,error,")
    assert len(lines) == 5 and [line.split(",")[5] for line in lines[1:]] == ["ok", "failed", "ok", "ok"]
    from tactex.experiments.study_table import WALL_CLOCK_METRICS

    assert "start_plan_time_s" in WALL_CLOCK_METRICS
    assert not any(k in lines[0] for k in WALL_CLOCK_METRICS)  # wall-clock values stay out of the table
    study = json.loads((out / "study.json").read_text())
    assert study["runs_failed"] == 1 and study["runs_ok"] == 3 and len(study["runs"]) == 4
    assert all("wall_time_s" in r["metrics"] for r in study["runs"] if r["status"] == "ok")
    assert [len(json.loads(x)) > 0 for x in (out / "runs.jsonl").read_text().splitlines()] == [True] * 4
    summary = (out / "summary.txt").read_text()
    assert "tactex" in summary and "raster" in summary
    for name in ("baseline", "n_eigen"):
        assert (out / f"factor_{name}.png").read_bytes()[:8] == PNG_MAGIC


@pytest.mark.slow
def test_resume_skips_finished_runs(small_study):
    spec, first = small_study
    table = (first.out_dir / "table.csv").read_bytes()
    again = run_study(spec, first.out_dir, LocalExecutor(1))
    assert again.skipped == 4 and len(again.records) == 4
    assert len((first.out_dir / "runs.jsonl").read_text().splitlines()) == 4  # nothing ran again
    assert (first.out_dir / "table.csv").read_bytes() == table


@pytest.mark.slow
def test_resume_after_ctrl_c_runs_only_what_is_missing(tmp_path):
    class InterruptAfterOne(LocalExecutor):
        def run(self, fn, tasks, shared=None):
            for i, outcome in enumerate(super().run(fn, tasks, shared)):
                yield outcome
                if i == 0:
                    raise KeyboardInterrupt

    from tactex.errors import RunInterrupted

    spec = spec_from_dict(SMALL)
    with pytest.raises(RunInterrupted, match=r"1 runs finished in this session, 1 in all, are recorded in .*jsonl"):
        run_study(spec, tmp_path, InterruptAfterOne(1))
    assert len((tmp_path / "runs.jsonl").read_text().splitlines()) == 1
    assert len((tmp_path / "table.csv").read_text().splitlines()) == 2  # the finished run is in the table
    done = run_study(spec, tmp_path, LocalExecutor(1))
    assert done.skipped == 1 and len(done.records) == 2 and not done.failed


def test_cli_lists_build_the_spec_and_bad_options_exit_2(tmp_path, capsys):
    from tactex.cli import build_parser
    from tactex.commands.study import spec_from_args

    args = build_parser().parse_args(["study", "--out", str(tmp_path), "--grid", "tool-friction=0.2,0.8",
                                      "--grid", "baseline=,raster", "--set", "budget_s=3", "--seeds", "0,4",
                                      "--random", "force_n=uniform:5:15", "--draws", "2"])
    spec = spec_from_args(args)
    assert spec.grid == {"tool_friction": (0.2, 0.8), "baseline": ("", "raster")}
    assert spec.fixed == {"budget_s": 3.0} and spec.seeds == (0, 4) and len(spec.runs()) == 16
    assert main(["study", "--out", str(tmp_path / "x"), "--grid", "tool_friction"]) == 2
    assert "NAME=VALUE" in capsys.readouterr().err
    assert main(["study", "--out", str(tmp_path / "x"), "--seeds", "two"]) == 2
    assert main(["study", "--out", str(tmp_path / "x"), "--set", "budget_s=1,2"]) == 2


def test_the_cli_exits_1_when_a_run_failed_and_says_so(tmp_path, monkeypatch, capsys):
    import types

    import tactex.experiments.study as study

    ok, bad = {"factors": {"seed": 0}, "error": ""}, {"factors": {"seed": 1}, "error": "SimulationError: boom\nmore"}
    done = types.SimpleNamespace(files={}, records=[ok, bad], skipped=0, out_dir=tmp_path / "s")
    done.failed = [bad]
    monkeypatch.setattr(study, "run_study", lambda *a, **k: done)
    assert main(["study", "--out", str(tmp_path / "s"), "--set", "budget_s=3", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "failed: {'seed': 1}: SimulationError: boom" in err and "1 of 2 runs failed" in err
    done.failed = []
    assert main(["study", "--out", str(tmp_path / "t"), "--set", "budget_s=3", "--quiet"]) == 0


def test_ray_without_the_extra_says_how_to_get_it(monkeypatch):
    import sys

    from tactex.errors import MissingDependencyError

    monkeypatch.setitem(sys.modules, "ray", None)  # import ray now fails as on a base install
    with pytest.raises(MissingDependencyError, match=r"tactex\[distributed\]"):
        make_executor(ray=True)
    with pytest.raises(MissingDependencyError, match=r"tactex\[distributed\]"):
        make_executor(ray_address="ray://127.0.0.1:10001")


@pytest.mark.parametrize("changes, match", [
    ({"metric": "speed"}, "unknown"),
    ({"mode": "best"}, "min or max"),
    ({"samples": 0}, "samples"),
    ({"space": {}}, "empty"),
    ({"space": {"force_n": {"uniform": [1, 2]}}}, "cannot be tuned"),
    ({"space": {"alpha": {"normal": [1, 2]}}}, "unknown distribution"),
    ({"space": {"alpha": {"uniform": [2, 1]}}}, "low < high"),
    ({"space": {"alpha": {"uniform": [-1, 1]}}}, "positive"),
    ({"space": {"n_eigen": {"choice": [10, 20.5]}}}, "integers"),
])
def test_tune_space_validation(changes, match):
    from tactex.experiments.tune import TuneSpec

    with pytest.raises(ConfigError, match=match):
        TuneSpec(**{"space": {"alpha": {"uniform": [1, 10]}}, **changes})


def test_tune_space_file(tmp_path):
    from tactex.experiments.tune import load_tune_spec

    path = tmp_path / "space.toml"
    path.write_text('samples = 3\n[space]\nalpha = {loguniform = [1, 100]}\nn_eigen = {choice = [25, 50]}\n')
    spec = load_tune_spec(path)
    assert spec.samples == 3 and spec.max_n_eigen == 50 and spec.space["alpha"] == ("loguniform", (1.0, 100.0))
    path.write_text("samples = 3\n")
    with pytest.raises(InputError, match=r"\[space\]"):
        load_tune_spec(path)


def test_table_columns_leave_out_wall_clock_and_series_and_split_axes():
    from tactex.experiments.study_table import flat_scalars

    flat = flat_scalars({"dirt_removed_fraction": 0.5, "wall_time_s": 3.2, "basis_time_s": 1.0,
                          "ergodicity": [[0.0, 1.0]], "vision_update_times_s": [1.0, 2.0, 3.0],
                          "motion_rmse_m": [0.1, None, 0.3], "tank_force_energy_j": {"min": 1.0, "max": 2.0},
                          "baseline": "raster"})
    assert flat == {"dirt_removed_fraction": 0.5, "motion_rmse_m.x": 0.1, "motion_rmse_m.y": None,
                    "motion_rmse_m.z": 0.3, "tank_force_energy_j.min": 1.0, "tank_force_energy_j.max": 2.0,
                    "baseline": "raster"}
    # a re-planned wipe's first pass: nested dicts and per-axis lists inside them get columns too
    nested = flat_scalars({"replan": {"from": "the first pass", "first_pass": {
        "force_mae_n": 0.3, "motion_mae_tangent_m": [0.001, 0.002, 0.0], "aligned_at_s": None}}})
    assert nested == {"replan.from": "the first pass", "replan.first_pass.force_mae_n": 0.3,
                      "replan.first_pass.motion_mae_tangent_m.x": 0.001,
                      "replan.first_pass.motion_mae_tangent_m.y": 0.002,
                      "replan.first_pass.motion_mae_tangent_m.z": 0.0, "replan.first_pass.aligned_at_s": None}


def test_a_run_cut_by_ctrl_c_stops_the_study_instead_of_counting_as_done(monkeypatch) -> None:
    """The task's loop turns Ctrl-C into an early stop (metrics "aborted"); in a study on one worker that
    run was recorded as finished, the study went on, and a resumed study skipped it."""
    from types import SimpleNamespace

    from tactex.experiments import tasks
    from tactex.experiments.study import run_study_task

    spec = tasks.task_spec("wipe")
    outcome = {"aborted": "KeyboardInterrupt", "partial": True}
    stub = SimpleNamespace(config_cls=spec.config_cls, run=lambda cfg, progress: SimpleNamespace(metrics=outcome))
    monkeypatch.setitem(tasks.TASKS, "wipe", lambda: stub)
    with pytest.raises(KeyboardInterrupt):
        run_study_task({"task": "wipe", "config": {}})
    outcome.update(aborted="RobotError: reflex", partial=True)  # a robot's stop is the run's result
    assert run_study_task({"task": "wipe", "config": {}})["aborted"] == "RobotError: reflex"


def test_the_input_files_of_a_study_travel_with_its_runs(tmp_path, monkeypatch):
    """A run gets the files its config names from the study (its machine may not have them): its own
    copy, written once per content; a file the study cannot read is an actionable ConfigError."""
    from tactex.errors import ConfigError
    from tactex.experiments.study_files import local_config, pack_files

    (tmp_path / "scan.npz").write_bytes(b"cloud bytes")
    monkeypatch.chdir(tmp_path)
    configs = [{"cloud": "scan.npz", "seed": s} for s in range(3)] + [{"cloud": "", "seed": 9}]
    files = pack_files(configs)
    assert files == {"scan.npz": (".npz", b"cloud bytes")}
    elsewhere = tmp_path / "worker-tmp"
    elsewhere.mkdir()
    monkeypatch.setenv("TMPDIR", str(elsewhere))
    monkeypatch.setattr("tempfile.tempdir", None)  # gettempdir() reads TMPDIR again
    local = [local_config(c, files) for c in configs[:2]]
    assert local[0]["cloud"] == local[1]["cloud"] != "scan.npz" and local[0]["seed"] == 0
    assert Path(local[0]["cloud"]).is_relative_to(elsewhere) and Path(local[0]["cloud"]).read_bytes() == b"cloud bytes"
    assert local_config(configs[3], files) == configs[3] and local_config(configs[0], None) == configs[0]
    assert pack_files([{"seed": 0}]) is None
    with pytest.raises(ConfigError, match=r"keep_out_mask = 'gone\.npy': cannot read"):
        pack_files([{"keep_out_mask": "gone.npy"}])


def test_a_ray_client_session_that_fails_to_start_is_tried_again_and_a_dead_address_is_not(monkeypatch):
    """A ray:// server that answered but whose session for this client failed (a loaded head) gets
    two more tries; a connection refused is reported at once as the --ray-address's fault."""
    from tactex.errors import ConfigError
    from tactex.experiments import executor

    class FakeRay:
        def __init__(self, errors):
            self.errors, self.inits, self.env = list(errors), 0, None

        def init(self, address, runtime_env, **kwargs):
            self.inits += 1
            self.env = runtime_env
            if self.errors:
                raise self.errors.pop(0)

        def shutdown(self):
            pass

    monkeypatch.setattr(executor.time, "sleep", lambda s: None)
    flaky = FakeRay([ConnectionError("Initialization failure from server: ZombieProcess")])
    executor._connect(flaky, "ray://head:10001")
    assert flaky.inits == 2
    assert flaky.env["py_modules"] == [str(Path(executor.__file__).parents[1])]  # this tactex, shipped
    dead = FakeRay([ConnectionError("connection refused")] * 3)
    with pytest.raises(ConfigError, match="--ray-address 'ray://head:10001'"):
        executor._connect(dead, "ray://head:10001")
    assert dead.inits == 1


def test_a_folder_holding_another_study_is_refused_without_force(tmp_path, monkeypatch, capsys):
    import types

    import tactex.experiments.study as study
    from tactex.experiments.study import check_same_study

    clean = spec_from_dict({"task": "clean", "fixed": {"budget_s": 3.0}, "seeds": 2})
    out = tmp_path / "s"
    out.mkdir()
    (out / "runs.jsonl").write_text(json.dumps({"run_id": clean.runs()[0].run_id, "task": "clean"}) + "\n")
    check_same_study(clean, out)  # the same study: resumed
    check_same_study(spec_from_dict({"task": "clean", "fixed": {"budget_s": 3.0}, "seeds": 4}), out)  # more seeds
    with pytest.raises(ConfigError, match=r"holds another study \(1 clean runs, none of this wipe study's plan\)"):
        check_same_study(spec_from_dict({"task": "wipe", "fixed": {"duration_s": 1.0}}), out)
    with pytest.raises(ConfigError, match="none of this clean study's plan"):  # every run's config differs
        check_same_study(spec_from_dict({"task": "clean", "fixed": {"budget_s": 4.0}}), out)
    done = types.SimpleNamespace(files={}, records=[], skipped=0, out_dir=out, failed=[])
    monkeypatch.setattr(study, "run_study", lambda *a, **k: done)
    argv = ["study", "--task", "wipe", "--set", "duration_s=1", "--out", str(out), "--quiet"]
    assert main(argv) == 2 and "--force to record these runs beside them" in capsys.readouterr().err
    assert main([*argv, "--force"]) == 0


def test_a_ray_address_that_is_malformed_or_dead_is_refused_at_once():
    import socket

    from tactex.experiments.executor import check_ray_address

    for bad in ("nonsense", "head:", ":6379", "ray://head", "head:99999"):
        with pytest.raises(ConfigError, match=f"--ray-address '{bad}' is not HOST:PORT"):
            check_ray_address(bad)
    with socket.socket() as s:  # a port nobody serves
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(ConfigError, match=rf"nothing answers at --ray-address '127.0.0.1:{port}' within 5 s .*"
                                          rf"ray start --head --port {port}"):
        check_ray_address(f"127.0.0.1:{port}")
    with pytest.raises(ConfigError, match=rf"ray start --head --ray-client-server-port {port}"):
        check_ray_address(f"ray://127.0.0.1:{port}")
    with socket.socket() as s:  # a port that answers: on to Ray
        s.bind(("127.0.0.1", 0))
        s.listen()
        check_ray_address(f"127.0.0.1:{s.getsockname()[1]}")
        check_ray_address("auto")
