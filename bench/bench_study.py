"""Study throughput (issue 20): a 40-run cleaning study with 1 and 2 workers on the local-process
and the Ray executor, and what Ray adds per run.

The study: short cleaning runs of the plate with the raster baseline (no eigenbasis; the run is
the capture, the IK and the contact loop), F/T noise seeded per run, 40 seeds (``--quick``: 8).
Each configuration runs into a fresh folder in the order local 1, Ray 1, local 2, Ray 2 (this
machine's speed drifts: compare the executors within a worker count). Recorded per configuration:

- ``runs_per_min`` — finished runs per minute of wall time, Ray's start-up not counted;
- ``run_s_mean`` — mean wall time of one run inside its worker [s];
- ``overhead_per_run_s`` — ``workers · wall / runs − run_s_mean``: the time a worker slot spends
  per run on anything but the run (dispatch, result transfer, the driver writing the table);
- ``ray_start_s`` — starting the local Ray instance.

``noop_overhead_ms``: 200 tasks that return at once, per executor with 2 workers — the bare cost of
dispatching one run and collecting its result.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

RUNS, QUICK_RUNS = 40, 8
NOOPS = 200
FIXED = {"object_name": "plate", "baseline": "raster", "budget_s": 1.0, "ft_noise_n": 0.3}

TARGETS: dict[str, tuple[str, float]] = {}


def _study(executor, seeds: int, out: Path) -> dict:
    from tactex.experiments.study import run_study
    from tactex.experiments.study_spec import spec_from_dict

    spec = spec_from_dict({"task": "clean", "fixed": FIXED, "seeds": seeds})
    t0 = time.perf_counter()
    result = run_study(spec, out, executor)
    wall = time.perf_counter() - t0
    run_s = sum(r["seconds"] for r in result.records) / len(result.records)
    return {"runs": len(result.records), "failed": len(result.failed), "wall_s": wall,
            "runs_per_min": 60.0 * len(result.records) / wall, "run_s_mean": run_s,
            "overhead_per_run_s": executor.slots * wall / len(result.records) - run_s}


def _noops(executor) -> float:
    from tactex.experiments.executor import echo

    t0 = time.perf_counter()
    outs = list(executor.run(echo, list(range(NOOPS))))
    assert len(outs) == NOOPS and all(o.ok for o in outs)
    return 1e3 * (time.perf_counter() - t0) / NOOPS


def run(args) -> dict:
    from tactex.experiments.executor import LocalExecutor

    seeds = QUICK_RUNS if getattr(args, "quick", False) else RUNS
    try:
        import ray  # noqa: F401
        has_ray = True
    except ImportError:
        has_ray = False
        print("   ray not installed (pip install 'tactex[distributed]'): local executor only", flush=True)
    out: dict = {"runs": seeds}
    with tempfile.TemporaryDirectory(prefix="tactex-bench-study-") as tmp:
        for workers in (1, 2):
            print(f"   local, {workers} worker(s): {seeds} runs ...", flush=True)
            with LocalExecutor(workers) as ex:
                out[f"local_{workers}"] = _study(ex, seeds, Path(tmp) / f"local{workers}")
                if workers == 2:
                    out["local_2"]["noop_overhead_ms"] = _noops(ex)
            if has_ray:
                from tactex.experiments.executor import RayExecutor

                print(f"   ray, {workers} worker(s): {seeds} runs ...", flush=True)
                t0 = time.perf_counter()
                with RayExecutor(workers) as ex:
                    start = time.perf_counter() - t0
                    out[f"ray_{workers}"] = {**_study(ex, seeds, Path(tmp) / f"ray{workers}"), "ray_start_s": start}
                    if workers == 2:
                        out["ray_2"]["noop_overhead_ms"] = _noops(ex)
    for workers in (1, 2):
        if has_ray:
            out[f"ray_over_local_throughput_{workers}"] = (out[f"ray_{workers}"]["runs_per_min"]
                                                          / out[f"local_{workers}"]["runs_per_min"])
    return {"study": out}
