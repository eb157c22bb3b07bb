"""What a study runs: a grid and/or random draws over a task's parameters, times seeds.

A spec comes from a small TOML or YAML file or from CLI lists (``tactex study``)::

    task = "clean"               # clean or wipe
    seeds = 5                    # seeds 0..4; or a list [0, 3, 7]
    draws = 0                    # random draws per grid setting (from [random])
    draw_seed = 0                # seed of the draws (the plan is the same every time)

    [fixed]                      # every run; any CleanConfig / WipeConfig field
    budget_s = 30.0

    [grid]                       # every combination
    object_name = ["plate", "bowl", "cup"]
    tool_friction = [0.2, 0.4, 0.8]
    baseline = ["", "raster"]

    [random]                     # one value per draw
    force_n = {uniform = [5.0, 15.0]}
    alpha = {loguniform = [1.0, 100.0]}
    ft_noise_n = {choice = [0.0, 0.5]}
    n_eigen = {integers = [50, 200]}

    [success]                    # what counts as a successful run (besides not failing or aborting)
    metric = "dirt_removed_fraction"
    at_least = 0.9

The plan is grid settings × draws × seeds, in that order; each run is the task's config with the
fixed, grid, drawn and seed values. A run's id is a hash of its task and config, so a study re-run
into the same folder (or one with more seeds or levels) recognises the runs it already has.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tactex.errors import ConfigError, InputError, MissingDependencyError

__all__ = ["DEFAULT_SUCCESS", "StudyRun", "StudySpec", "level_label", "load_spec_file", "parse_assignment"]

#: Success of a run per task: the metric and the least value that counts (with no error and no abort).
DEFAULT_SUCCESS = {"clean": ("dirt_removed_fraction", 0.9), "wipe": ("contact_fraction_after_first_contact", 0.9)}
DISTRIBUTIONS = ("uniform", "loguniform", "choice", "integers")
#: Most runs a study plans (grid × draws × seeds): 100,000 runs of 30 s are a month of one core,
#: and a plan ten times that takes seconds just to list.
MAX_RUNS = 100_000
#: Largest bound of an integers draw: numpy draws within int64.
_INT_BOUND = 2**62
#: Fields a study must not set: it runs in simulation, the seed comes from ``seeds``.
NOT_STUDY_FIELDS = ("seed",)


def _config_cls(task: str) -> type:
    from tactex.experiments.tasks import task_spec

    return task_spec(task).config_cls


def _coerce(cls: type, name: str, value: Any, where: str) -> Any:
    """``value`` as the type of ``cls.name`` (CLI strings and TOML ints become floats where needed)."""
    names = {f.name for f in dataclasses.fields(cls)}
    if name not in names:
        close = sorted(n for n in names if name.split("_")[0] in n)[:5]
        hint = f" (did you mean {', '.join(close)}?)" if close else ""
        raise ConfigError(f"{where}: '{name}' is not a parameter of {cls.__name__}{hint}")
    if name in NOT_STUDY_FIELDS:
        raise ConfigError(f"{where}: set the seeds with seeds (--seeds), not '{name}'")
    typ = typing.get_type_hints(cls)[name]
    origin = typing.get_origin(typ)
    if isinstance(value, dict) or (isinstance(value, (list, tuple)) and origin is not tuple):
        raise ConfigError(f"{where}: {name} = {value!r:.60} is not a single value")
    try:
        if typ is bool:
            if isinstance(value, str):
                if value.lower() not in ("true", "false", "1", "0", "yes", "no"):
                    raise ValueError(value)
                return value.lower() in ("true", "1", "yes")
            return bool(value)
        if typ is int:
            if isinstance(value, float) and not value.is_integer():
                raise ValueError(value)
            return int(value)
        if typ is float:
            v = float(value)
            if not math.isfinite(v):
                raise ValueError(value)
            return v
        if typ is str:
            return "" if value is None else str(value)
        if origin is tuple:
            if isinstance(value, str):
                value = [x for x in value.replace(",", " ").split() if x]
            return tuple(float(x) for x in value)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: {name} = {value!r} is not a valid {getattr(typ, '__name__', typ)}") from exc
    return value


@dataclass(frozen=True)
class StudyRun:
    """One run of a study: its place in the plan, the values of the factors, the task config."""

    index: int
    run_id: str
    factors: dict[str, Any]
    config: dict[str, Any]


@dataclass(frozen=True)
class StudySpec:
    """A study's task, factors and seeds (see the module docstring for the file format)."""

    task: str = "clean"
    grid: dict[str, tuple] = field(default_factory=dict)
    fixed: dict[str, Any] = field(default_factory=dict)
    random: dict[str, tuple] = field(default_factory=dict)
    draws: int = 0
    seeds: tuple[int, ...] = (0,)
    draw_seed: int = 0
    success_metric: str = ""
    success_at_least: float = math.nan

    def __post_init__(self) -> None:
        if not isinstance(self.task, str) or self.task not in DEFAULT_SUCCESS:
            raise ConfigError(f"unknown study task {self.task!r:.60}; valid: {', '.join(DEFAULT_SUCCESS)} (--task)")
        cls = _config_cls(self.task)
        grid = {}
        for name, levels in self.grid.items():
            levels = levels if isinstance(levels, (list, tuple)) else [levels]
            if not levels:
                raise ConfigError(f"grid: {name} has no levels; give at least one value")
            values = tuple(_coerce(cls, name, v, "grid") for v in levels)
            if len(set(values)) != len(values):
                raise ConfigError(f"grid: {name} lists a level twice: {list(levels)}")
            grid[name] = values
        fixed = {name: _coerce(cls, name, v, "fixed") for name, v in self.fixed.items()}
        random = {name: self._distribution(cls, name, d) for name, d in self.random.items()}
        both = (set(grid) & set(fixed)) | (set(grid) & set(random)) | (set(fixed) & set(random))
        if both:
            raise ConfigError(f"{sorted(both)[0]} is given twice (grid, fixed, random): keep one")
        seeds = self.seeds
        if isinstance(seeds, int) and not isinstance(seeds, bool):
            if not 1 <= seeds <= MAX_RUNS:
                raise ConfigError(f"seeds must be a count from 1 to {MAX_RUNS:,} or a list of seeds, got {seeds:.3g}")
            seeds = tuple(range(seeds))
        try:
            seeds = tuple(int(s) for s in seeds)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"seeds must be a count or a list of integers ≥ 0, got {self.seeds!r}") from exc
        if not seeds or any(s < 0 for s in seeds) or len(set(seeds)) != len(seeds):
            raise ConfigError(f"seeds must be distinct integers ≥ 0, got {self.seeds!r}")
        if isinstance(self.draws, bool) or not isinstance(self.draws, int) or not 0 <= self.draws <= MAX_RUNS:
            raise ConfigError(f"draws must be an integer from 0 to {MAX_RUNS:,}, got {self.draws!r:.40}")
        if isinstance(self.draw_seed, bool) or not isinstance(self.draw_seed, int) or self.draw_seed < 0:
            raise ConfigError(f"draw_seed must be an integer ≥ 0, got {self.draw_seed!r:.40}")
        n_runs = math.prod(len(v) for v in grid.values()) * max(self.draws, 1) * len(seeds)
        if n_runs > MAX_RUNS:
            raise ConfigError(f"the study plans {n_runs:,} runs (grid × draws × seeds), more than {MAX_RUNS:,}: "
                              "fewer levels, draws or seeds")
        if random and self.draws == 0:
            raise ConfigError(f"[random] gives {', '.join(random)} but draws = 0; set draws (--draws N) to sample them")
        if self.draws and not random:
            raise ConfigError("draws > 0 needs [random] distributions (--random NAME=uniform:LOW:HIGH)")
        metric, at_least = DEFAULT_SUCCESS[self.task]
        if not isinstance(self.success_metric, str):
            raise ConfigError(f"success: metric must be a metric's name, got {self.success_metric!r:.40}")
        if isinstance(self.success_at_least, bool) or not isinstance(self.success_at_least, (int, float)):
            raise ConfigError(f"success: at_least must be a number, got {self.success_at_least!r:.40}")
        metric = self.success_metric or metric
        at_least = at_least if math.isnan(self.success_at_least) else float(self.success_at_least)
        object.__setattr__(self, "grid", grid)
        object.__setattr__(self, "fixed", fixed)
        object.__setattr__(self, "random", random)
        object.__setattr__(self, "seeds", seeds)
        object.__setattr__(self, "success_metric", metric)
        object.__setattr__(self, "success_at_least", at_least)
        # every level must make a valid config: check each one now (with the first run's other factors), not in
        # the 500th run; what only a combination of levels refuses still fails in its run
        first = self.runs()[0].config
        self._check_config(cls, first)
        for name, values in grid.items():
            for value in values[1:]:
                self._check_config(cls, {**first, name: value}, f"grid: {name} = {value!r}: ")
        for name, (kind, *args) in random.items():
            for value in args[0] if kind == "choice" else [int(args[0])] if kind == "integers" else args:
                self._check_config(cls, {**first, name: value}, f"random: {name} = {value!r}: ")

    @staticmethod
    def _distribution(cls: type, name: str, spec: Any) -> tuple:
        where = f"random: {name}"
        if not isinstance(spec, dict) or len(spec) != 1:
            raise ConfigError(f"{where} must be one of {{uniform = [low, high]}}, {{loguniform = [low, high]}}, "
                              f"{{integers = [low, high]}} or {{choice = [a, b, ...]}}, got {spec!r}")
        (kind, args), = spec.items()
        if kind not in DISTRIBUTIONS:
            raise ConfigError(f"{where}: unknown distribution '{kind}'; valid: {', '.join(DISTRIBUTIONS)}")
        if kind == "choice":
            if not isinstance(args, (list, tuple)) or not args:
                raise ConfigError(f"{where}: choice needs a non-empty list of values")
            return (kind, tuple(_coerce(cls, name, v, where) for v in args))
        if not isinstance(args, (list, tuple)) or len(args) != 2:
            raise ConfigError(f"{where}: {kind} needs [low, high], got {args!r}")
        low, high = (_coerce(cls, name, v, where) for v in args)
        if isinstance(low, (str, bool, tuple)):
            raise ConfigError(f"{where}: {kind} draws numbers, but {name} is not a number; use choice = [...]")
        if not low < high or (kind == "loguniform" and low <= 0):
            raise ConfigError(f"{where}: {kind} needs low < high{' and low > 0' if kind == 'loguniform' else ''}, "
                              f"got [{low}, {high}]")
        # numpy draws integers within int64 and uniform numbers over a finite width
        if (kind == "integers" and not -_INT_BOUND <= low < high <= _INT_BOUND) or \
                (kind == "uniform" and not math.isfinite(float(high) - float(low))):
            raise ConfigError(f"{where}: {kind} [{low:.4g}, {high:.4g}] is too wide to draw from; give a range "
                              "the parameter can take")
        return (kind, float(low), float(high))

    @staticmethod
    def _check_config(cls: type, config: dict[str, Any], where: str = "") -> None:
        try:
            cls(**config)
        except TypeError as exc:
            raise ConfigError(f"{where}invalid parameters for {cls.__name__}: {exc}") from exc
        except ConfigError as exc:
            if not where:
                raise
            raise type(exc)(f"{where}{exc}") from None

    @property
    def factors(self) -> tuple[str, ...]:
        """The columns that vary: grid factors, random factors, then ``seed``."""
        return (*self.grid, *self.random, "seed")

    def _draws(self) -> list[dict[str, Any]]:
        if not self.draws:
            return [{}]
        rng = np.random.default_rng(self.draw_seed)
        out = []
        for _ in range(self.draws):
            d = {}
            for name, (kind, *args) in self.random.items():
                if kind == "uniform":
                    d[name] = float(rng.uniform(args[0], args[1]))
                elif kind == "loguniform":
                    d[name] = float(np.exp(rng.uniform(np.log(args[0]), np.log(args[1]))))
                elif kind == "integers":
                    d[name] = int(rng.integers(int(args[0]), int(args[1]), endpoint=True))
                else:
                    d[name] = args[0][int(rng.integers(len(args[0])))]
            out.append(d)
        return out

    def runs(self) -> list[StudyRun]:
        """The plan: every grid setting × draw × seed, in that order."""
        names = list(self.grid)
        draws = self._draws()
        runs = []
        for levels in itertools.product(*(self.grid[n] for n in names)):
            for draw in draws:
                for seed in self.seeds:
                    factors = {**dict(zip(names, levels, strict=True)), **draw, "seed": seed}
                    config = {**self.fixed, **factors}
                    runs.append(StudyRun(len(runs), run_id(self.task, config), factors, config))
        return runs

    def to_json(self) -> dict[str, Any]:
        return {"task": self.task, "grid": {k: list(v) for k, v in self.grid.items()}, "fixed": dict(self.fixed),
                "random": {k: [v[0], *(list(v[1]) if v[0] == "choice" else v[1:])] for k, v in self.random.items()},
                "draws": self.draws, "seeds": list(self.seeds), "draw_seed": self.draw_seed,
                "success": {"metric": self.success_metric, "at_least": self.success_at_least}}


def level_label(name: str, value: Any) -> str:
    """A factor's value as shown in summaries and plots (the baseline '' is tactex itself)."""
    if name == "baseline" and value == "":
        return "tactex"
    if name == "policy":  # a policy file by its name; '' is the wipe's own §III sinusoid
        return Path(value).stem if value else "sinusoid (built in)"
    return f"{value:g}" if isinstance(value, float) else str(value)


def run_id(task: str, config: dict[str, Any]) -> str:
    """A run's identity: a hash of its task and its config (sorted keys; floats as their repr)."""
    text = json.dumps({"task": task, "config": config}, sort_keys=True, default=list)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def parse_assignment(text: str, option: str) -> tuple[str, list[str]]:
    """``NAME=V1,V2,...`` (CLI lists) → (name with '_' for '-', [values])."""
    name, sep, values = text.partition("=")
    name = name.strip().replace("-", "_")
    if not sep or not name:
        raise ConfigError(f"{option} '{text}': write NAME=VALUE[,VALUE...], e.g. {option} tool_friction=0.2,0.4")
    return name, [v.strip() for v in values.split(",")] if values.strip() else [""]


def read_table_file(path: str | Path, option: str, known: set[str]) -> dict[str, Any]:
    """The tables of a ``.toml``, ``.yaml`` or ``.yml`` file as a dict whose keys are all in ``known``."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{option} file '{p}' does not exist")
    suffix = p.suffix.lower()
    if suffix not in (".toml", ".yaml", ".yml"):
        raise InputError(f"{option} file '{p}': give a .toml, .yaml or .yml file")
    if suffix == ".toml":
        try:
            import tomllib
        except ImportError:  # Python 3.10
            try:
                import tomli as tomllib
            except ImportError as exc:
                raise MissingDependencyError("tomli", "", "reading a TOML file on Python 3.10",
                                             fix="pip install tomli, or write the file as YAML") from exc
        try:
            data = tomllib.loads(p.read_text())
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise InputError(f"{option} file '{p}' is not valid TOML: {exc}") from exc
    else:
        try:
            import yaml
        except ImportError as exc:
            raise MissingDependencyError("pyyaml", "distributed", f"reading a YAML {option} file") from exc
        try:
            data = yaml.safe_load(p.read_text()) or {}
        except (yaml.YAMLError, UnicodeDecodeError) as exc:
            raise InputError(f"{option} file '{p}' is not valid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise InputError(f"{option} file '{p}' must hold a table of keys ({', '.join(sorted(known))}), "
                         f"got {type(data).__name__}")
    unknown = sorted(set(data) - known)
    if unknown:
        raise InputError(f"{option} file '{p}': unknown key '{unknown[0]}'; valid: {', '.join(sorted(known))}")
    return data


def load_spec_file(path: str | Path) -> dict[str, Any]:
    """The tables of a ``.toml``, ``.yaml`` or ``.yml`` study file as a dict (not yet checked)."""
    return read_table_file(path, "--spec", {"task", "grid", "fixed", "random", "draws", "seeds", "draw_seed",
                                            "success"})


def spec_from_dict(data: dict[str, Any]) -> StudySpec:
    """A :class:`StudySpec` from a study file's tables."""
    success = data.get("success") or {}
    if not isinstance(success, dict) or set(success) - {"metric", "at_least"}:
        raise ConfigError("success must be a table with metric and at_least")
    for key in ("grid", "fixed", "random"):
        if not isinstance(data.get(key, {}), dict):
            raise ConfigError(f"{key} must be a table of parameter names, got {data[key]!r}")
    return StudySpec(task=data.get("task", "clean"), grid=data.get("grid", {}), fixed=data.get("fixed", {}),
                     random=data.get("random", {}), draws=data.get("draws", 0), seeds=data.get("seeds", (0,)),
                     draw_seed=data.get("draw_seed", 0), success_metric=success.get("metric", ""),
                     success_at_least=success.get("at_least", math.nan))
