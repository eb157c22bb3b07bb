"""`tactex sweep --tune SPACE`: search HEDAC's parameters against a metric with Ray Tune.

Where the grid of ``tactex sweep`` compares a few fixed values, tuning samples a search space and
keeps the best: each trial explores every cloud from the same starts as the sweep with the trial's
n_K, α and agent radius, and reports the mean over clouds and starts of the final value of the
metric. The clouds and their largest basis are built once and handed to the trials through Ray's
object store (``tune.with_parameters``). The search space file (TOML or YAML)::

    metric = "final_ergodicity"      # or final_coverage_residual, path_length_m
    mode = "min"                     # min or max
    samples = 16                     # trials
    seed = 0                         # seed of the random search: the same trials every time
    [space]
    alpha = {loguniform = [1.0, 100.0]}
    n_eigen = {integers = [25, 200]}   # a basis of the largest n_eigen is built
    agent_radius = {uniform = [0.005, 0.02]}

Outputs beside the sweep's: ``tune.json`` (space, best configuration and its metric, every
trial), ``tune_table.csv`` (one row per trial) and ``tune_<param>.png`` (metric against each
parameter). Ray Tune's own trial folders go to ``<out>/ray_tune``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tactex.config import write_json
from tactex.errors import ConfigError, InputError, MissingDependencyError

__all__ = ["TUNE_METRICS", "TuneResult", "TuneSpec", "load_tune_spec", "run_tune"]

TUNE_METRICS = ("final_ergodicity", "final_coverage_residual", "path_length_m")
#: Tunable HEDAC parameters and what they are.
TUNE_PARAMS = {"alpha": "diffusion scale α [-]", "n_eigen": "eigencomponents n_K [-]",
               "agent_radius": "agent footprint radius r_a [m]"}


@dataclass(frozen=True)
class TuneSpec:
    """The search: its space (name → (distribution, args)), metric, direction, trials and seed."""

    space: dict[str, tuple]
    metric: str = "final_ergodicity"
    mode: str = "min"
    samples: int = 16
    seed: int = 0

    def __post_init__(self) -> None:
        if self.metric not in TUNE_METRICS:
            raise ConfigError(f"tune metric '{self.metric}' is unknown; valid: {', '.join(TUNE_METRICS)}")
        if self.mode not in ("min", "max"):
            raise ConfigError(f"tune mode must be min or max, got {self.mode!r}")
        if isinstance(self.samples, bool) or not isinstance(self.samples, int) or self.samples < 1:
            raise ConfigError(f"tune samples must be an integer ≥ 1, got {self.samples!r}")
        if not self.space:
            raise ConfigError(f"the tune space is empty; give [space] with some of {', '.join(TUNE_PARAMS)}")
        space = {}
        for name, dist in self.space.items():
            if name not in TUNE_PARAMS:
                raise ConfigError(f"tune space: '{name}' cannot be tuned; valid: {', '.join(TUNE_PARAMS)}")
            if not isinstance(dist, dict) or len(dist) != 1:
                raise ConfigError(f"tune space: {name} must be one of {{uniform = [low, high]}}, {{loguniform = "
                                  f"[low, high]}}, {{integers = [low, high]}} or {{choice = [a, b, ...]}}")
            (kind, args), = dist.items()
            if kind not in ("uniform", "loguniform", "integers", "choice"):
                raise ConfigError(f"tune space: {name}: unknown distribution '{kind}'")
            try:
                values = tuple(float(a) for a in args)
            except (TypeError, ValueError) as exc:
                raise ConfigError(f"tune space: {name} = {args!r} must be numbers") from exc
            if not values or any(not math.isfinite(v) or v <= 0 for v in values):
                raise ConfigError(f"tune space: {name} values must be positive numbers, got {list(args)}")
            if kind != "choice" and (len(values) != 2 or values[0] >= values[1]):
                raise ConfigError(f"tune space: {name}: {kind} needs [low, high] with low < high, got {list(args)}")
            if name == "n_eigen" and any(v != int(v) for v in values):
                raise ConfigError(f"tune space: n_eigen values must be integers, got {list(args)}")
            space[name] = (kind, values)
        object.__setattr__(self, "space", space)

    @property
    def max_n_eigen(self) -> int | None:
        if "n_eigen" not in self.space:
            return None
        return int(max(self.space["n_eigen"][1]))

    def ray_space(self) -> dict[str, Any]:
        from ray import tune

        out = {}
        for name, (kind, v) in self.space.items():
            if kind == "choice":
                out[name] = tune.choice([int(x) if name == "n_eigen" else x for x in v])
            elif kind == "integers":
                out[name] = tune.randint(int(v[0]), int(v[1]) + 1)
            elif kind == "loguniform":
                out[name] = tune.loguniform(*v)
            else:
                out[name] = tune.uniform(*v)
        return out


def load_tune_spec(path: str | Path) -> TuneSpec:
    """A :class:`TuneSpec` from a TOML or YAML file (see the module docstring)."""
    from tactex.experiments.study_spec import read_table_file

    data = read_table_file(path, "--tune", {"metric", "mode", "samples", "seed", "space"})
    if not isinstance(data.get("space"), dict):
        raise InputError(f"tune file '{path}' needs a [space] table")
    return TuneSpec(space=data["space"], metric=data.get("metric", "final_ergodicity"), mode=data.get("mode", "min"),
                    samples=data.get("samples", 16), seed=data.get("seed", 0))


def _trial(config: dict[str, Any], clouds: dict[str, tuple], steps: int, normalization: str, metric: str,
           defaults: dict[str, Any]) -> None:
    """One Tune trial: every cloud from its starts with the trial's parameters; reports the mean."""
    from ray import tune
    from threadpoolctl import threadpool_limits

    from tactex.ergodic import HedacConfig, HedacExplorer

    values = []
    with threadpool_limits(limits=1):
        for cloud, basis, starts, radius, keep_out in clouds.values():
            hedac = HedacConfig(alpha=float(config.get("alpha", defaults["alpha"])),
                                n_eigen=int(config.get("n_eigen", defaults["n_eigen"])),
                                agent_radius_m=float(config.get("agent_radius", radius)),
                                coverage_normalization=normalization)
            explorer = HedacExplorer(cloud, basis, hedac, keep_out=keep_out)
            for x0 in starts:
                explorer.reset(x0)
                for _ in range(steps):
                    explorer.step()
                values.append({"final_ergodicity": explorer.ergodicity(),
                               "final_coverage_residual": explorer.coverage_residual(),
                               "path_length_m": explorer.path_length}[metric])
    tune.report({metric: float(np.mean(values))})


@dataclass
class TuneResult:
    """The best configuration, its metric, and every trial (in trial order)."""

    best: dict[str, Any]
    best_value: float
    trials: list[dict[str, Any]]
    files: dict[str, Path] = field(default_factory=dict)


def run_tune(sources: Sequence[str | Path], out_dir: str | Path, spec: TuneSpec, config, *,
             workers: int = 0, ray_address: str | None = None,
             progress: Callable[[str], None] | None = None) -> TuneResult:
    """Tune HEDAC on ``sources`` (``config`` a :class:`~tactex.experiments.sweep.SweepConfig` for
    the fixed parameters: starts, steps, voxel size, ...) with Ray Tune's seeded random search."""
    try:
        from ray import tune
        from ray.tune.search.basic_variant import BasicVariantGenerator
    except ImportError as exc:
        raise MissingDependencyError("ray[tune]", "distributed", "tuning with --tune") from exc
    from tactex.experiments.executor import RayExecutor
    from tactex.experiments.run_folder import prepare_out_dir
    from tactex.experiments.study_table import write_csv
    from tactex.experiments.sweep import prepare_clouds

    say = progress or (lambda msg: None)
    out = prepare_out_dir(out_dir)
    if spec.max_n_eigen is not None:
        from dataclasses import replace

        config = replace(config, n_eigen=(spec.max_n_eigen,))
    clouds, _ = prepare_clouds(sources, config, say)
    defaults = {"alpha": config.alpha[0], "n_eigen": max(config.n_eigen)}
    with RayExecutor(workers, address=ray_address) as ex:
        say(f"tuning {', '.join(spec.space)} for {spec.mode} {spec.metric}: {spec.samples} trials on "
            f"{ex.describe()}")
        t0 = time.perf_counter()
        trainable = tune.with_parameters(_trial, clouds=clouds, steps=config.steps,
                                         normalization=config.coverage_normalization, metric=spec.metric,
                                         defaults=defaults)
        tuner = tune.Tuner(
            tune.with_resources(trainable, {"cpu": 1}), param_space=spec.ray_space(),
            tune_config=tune.TuneConfig(metric=spec.metric, mode=spec.mode, num_samples=spec.samples,
                                        search_alg=BasicVariantGenerator(random_state=spec.seed)),
            run_config=tune.RunConfig(name="hedac", storage_path=str((out / "ray_tune").resolve()), verbose=0),
        )
        grid = tuner.fit()
        elapsed = time.perf_counter() - t0
    trials = []
    for i in range(len(grid)):
        r = grid[i]
        value = (r.metrics or {}).get(spec.metric)
        trials.append({"trial": i, **{k: r.config[k] for k in spec.space},
                       spec.metric: float(value) if value is not None else math.nan,
                       "error": "" if r.error is None else f"{type(r.error).__name__}: {r.error}".splitlines()[0]})
    # the order Tune lists trials in follows their sampling (seeded): sort by the sampled values anyway
    trials.sort(key=lambda t: tuple(t[k] for k in spec.space))
    good = [t for t in trials if math.isfinite(t[spec.metric])]
    if not good:
        raise InputError(f"every tune trial failed; the first: {trials[0]['error']}")
    best = (min if spec.mode == "min" else max)(good, key=lambda t: t[spec.metric])
    cols = ["trial", *spec.space, spec.metric, "error"]
    files = {"table": write_csv(out / "tune_table.csv", cols, [[t[c] for c in cols] for t in trials])}
    files["tune"] = write_json({"space": {k: [v[0], list(v[1])] for k, v in spec.space.items()},
                                "metric": spec.metric, "mode": spec.mode, "samples": spec.samples, "seed": spec.seed,
                                "best": {k: best[k] for k in spec.space}, "best_value": best[spec.metric],
                                "elapsed_s": elapsed, "trials": trials}, out / "tune.json")
    files.update(_plot(out, spec, trials, best))
    say(f"best of {len(good)} trials: " + ", ".join(f"{k} = {best[k]:g}" for k in spec.space)
        + f" → {spec.metric} {best[spec.metric]:.4f} ({elapsed:.0f} s)")
    return TuneResult(best={k: best[k] for k in spec.space}, best_value=best[spec.metric], trials=trials, files=files)


def _plot(out: Path, spec: TuneSpec, trials: list[dict[str, Any]], best: dict[str, Any]) -> dict[str, Path]:
    from tactex.experiments.study_plots import _figure

    files = {}
    for name in spec.space:
        fig = _figure(5.0, 3.5)
        ax = fig.add_subplot(1, 1, 1)
        x = np.array([t[name] for t in trials], dtype=float)
        y = np.array([t[spec.metric] for t in trials], dtype=float)
        ax.scatter(x, y, s=14, label="trials")
        ax.scatter([best[name]], [best[spec.metric]], s=60, color="tab:red", marker="*", label="best")
        if spec.space[name][0] == "loguniform":
            ax.set_xscale("log")
        ax.set_xlabel(f"{name}: {TUNE_PARAMS[name]}")
        ax.set_ylabel(f"{spec.metric} (mean over clouds and starts)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        path = out / f"tune_{name}.png"
        fig.savefig(path)
        files[f"tune_{name}"] = path
    return files
