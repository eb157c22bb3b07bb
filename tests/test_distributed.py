"""Studies and sweeps on a real local Ray instance (num_cpus=2), against the local executor.

Needs the distributed extra (pip install 'tactex[distributed]'); CI installs it. Each test module
run starts one Ray instance and shuts it down at the end.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

ray = pytest.importorskip("ray", reason="the distributed extra is not installed (pip install 'tactex[distributed]')")

from tactex.experiments.executor import LocalExecutor, RayExecutor, start_local_ray  # noqa: E402
from tactex.experiments.study import run_study  # noqa: E402
from tactex.experiments.study_spec import spec_from_dict  # noqa: E402
from tactex.experiments.sweep import SweepConfig, run_sweep  # noqa: E402

pytestmark = [pytest.mark.slow, pytest.mark.distributed]

# Short cleaning runs: tactex and the raster baseline on the plate, two seeds with F/T noise (so the
# seeds differ), and one run that raises in its worker (n_eigen above the capture's point count).
STUDY = {"task": "clean", "fixed": {"object_name": "plate", "budget_s": 1.0, "ft_noise_n": 0.5},
         "grid": {"baseline": ["", "raster"]}, "seeds": 2}
SWEEP = {"n_eigen": (10, 30), "alpha": (5.0, 20.0), "starts": 2, "steps": 30}


@pytest.fixture(scope="module")
def local_ray():
    if ray.is_initialized():
        ray.shutdown()
    start_local_ray(num_cpus=2)
    yield ray
    ray.shutdown()


@pytest.fixture(autouse=True)
def _cache_dir(tmp_path_factory, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TACTEX_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "basis-cache"))


def test_sweep_tables_are_identical_on_ray_and_local(local_ray, tmp_path):
    local = run_sweep(["cup"], tmp_path / "local", SweepConfig(**SWEEP), executor=LocalExecutor(2))
    with RayExecutor() as ex:
        assert ex.slots == 2
        on_ray = run_sweep(["cup"], tmp_path / "ray", SweepConfig(**SWEEP), executor=ex)
    assert (tmp_path / "local" / "table.csv").read_bytes() == (tmp_path / "ray" / "table.csv").read_bytes()
    for name in ("ergodicity", "coverage_residual", "path_length_m", "first_path"):
        np.testing.assert_array_equal(on_ray.curves["cup"][name], local.curves["cup"][name])
    assert on_ray.summary["executor"].startswith("ray") and not on_ray.summary["failed"]


def test_study_tables_are_identical_on_ray_and_local_and_a_raising_run_is_recorded(local_ray, tmp_path):
    spec = spec_from_dict({**STUDY, "grid": {**STUDY["grid"], "n_eigen": [50, 100000]}})
    # the local one in worker processes, in another order of completion than Ray's
    local = run_study(spec, tmp_path / "local", LocalExecutor(2))
    with RayExecutor() as ex:
        on_ray = run_study(spec, tmp_path / "ray", ex)
    for name in ("table.csv", "table.parquet", "summary.csv"):
        assert (tmp_path / "local" / name).read_bytes() == (tmp_path / "ray" / name).read_bytes(), name
    assert len(on_ray.records) == 8
    failed = on_ray.failed
    assert [(r["factors"]["baseline"], r["factors"]["n_eigen"]) for r in failed] == [("", 100000)] * 2
    assert all("n_eigen = 100000" in r["error"] for r in failed)
    ok = [r for r in on_ray.records if r["status"] == "ok"]
    # the seeds sample the F/T noise: the two seeds of a setting are different runs
    by_seed = {r["factors"]["seed"]: r["metrics"]["max_contact_force_n"] for r in ok if r["factors"]["baseline"] == ""}
    assert by_seed[0] != by_seed[1]
    assert {r["worker"] for r in on_ray.records} != {r["worker"] for r in local.records}


def _ray_run_workers() -> list[int]:
    """PIDs of Ray worker processes executing one of our runs (Ray titles them ``ray::_call``)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmd = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        if cmd.startswith(b"ray::_call"):
            pids.append(int(entry.name))
    return pids


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="finds the Ray worker to kill through /proc (Linux)")
def test_killing_a_ray_worker_mid_study_still_completes_every_run(local_ray, tmp_path):
    spec = spec_from_dict({**STUDY, "fixed": {**STUDY["fixed"], "budget_s": 3.0}})
    killed: list[int] = []

    def kill_one() -> None:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not killed:
            pids = _ray_run_workers()
            if pids:
                time.sleep(1.0)  # well into its run
                try:
                    os.kill(pids[0], signal.SIGKILL)
                    killed.append(pids[0])
                except ProcessLookupError:
                    continue
            time.sleep(0.2)

    killer = threading.Thread(target=kill_one, daemon=True)
    killer.start()
    with RayExecutor() as ex:
        result = run_study(spec, tmp_path, ex)
    killer.join(timeout=5)
    assert killed, "no Ray worker was running a study run to kill"
    assert len(result.records) == 4 and not result.failed
    assert {r["factors"]["seed"] for r in result.records} == {0, 1}


def test_ray_executor_records_errors_and_shares_input_once(local_ray):
    from tests.executor_tasks import square

    with RayExecutor() as ex:
        outs = sorted(ex.run(square, list(range(5)), 10), key=lambda o: o.index)
    assert [o.value for o in outs if o.ok] == [10, 11, 14, 26]
    assert outs[3].error == "ValueError: three is not allowed"


def test_resume_on_ray_skips_finished_runs(local_ray, tmp_path):
    spec = spec_from_dict(STUDY)
    first = spec_from_dict({**STUDY, "seeds": [0]})
    with RayExecutor() as ex:
        run_study(first, tmp_path, ex)
        done = run_study(spec, tmp_path, ex)
    assert done.skipped == 2 and len(done.records) == 4
    assert len((tmp_path / "runs.jsonl").read_text().splitlines()) == 4


def test_tune_returns_the_best_configuration_and_the_trial_table(local_ray, tmp_path):
    import json

    from tactex.experiments.tune import TuneSpec, run_tune

    spec = TuneSpec(space={"alpha": {"loguniform": [1.0, 100.0]}, "n_eigen": {"choice": [10, 20]}}, samples=2, seed=1)
    result = run_tune(["cup"], tmp_path, spec, SweepConfig(n_eigen=(20,), alpha=(5.0,), starts=1, steps=10))
    lines = (tmp_path / "tune_table.csv").read_text().splitlines()
    assert lines[0] == "trial,alpha,n_eigen,final_ergodicity,error" and len(lines) == 3
    values = [float(line.split(",")[3]) for line in lines[1:]]
    assert result.best_value == min(values) and all(1.0 <= t["alpha"] <= 100.0 for t in result.trials)
    saved = json.loads((tmp_path / "tune.json").read_text())
    assert saved["best"] == result.best and saved["best"]["n_eigen"] in (10, 20)
    assert (tmp_path / "tune_alpha.png").is_file()


def test_local_ray_workers_run_at_our_nice_level(local_ray):
    """Ray lowers its workers to nice 15 by default: on a machine busy with anything else they would crawl."""
    import os

    @ray.remote
    def niceness() -> int:
        return os.nice(0)

    assert ray.get(niceness.remote(), timeout=300) == os.nice(0)
