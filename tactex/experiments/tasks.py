"""The task registry: every closed-loop task by name, with its config class, its runner and its
baselines. Each entry loads its task's module only when asked for (each pulls in MuJoCo), so the
registry itself is light enough for the CLI's help and a study's plan."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from tactex.errors import ConfigError

__all__ = ["TASKS", "TaskSpec", "baseline_names", "task_spec"]


@dataclass(frozen=True)
class TaskSpec:
    """A closed-loop task: its config class, its runner, its baselines ('' is tactex itself), and the
    config field that bounds a run's simulated time [s] (what a short run shortens)."""

    name: str
    config_cls: type
    run: Callable[..., Any]
    baselines: tuple[str, ...]
    budget_field: str


def _clean() -> TaskSpec:
    from tactex.tasks.clean import CLEAN_BASELINES, CleanConfig, run_clean

    return TaskSpec("clean", CleanConfig, run_clean, tuple(CLEAN_BASELINES), "budget_s")


def _wipe() -> TaskSpec:
    from tactex.tasks.wipe import WIPE_BASELINES, WipeConfig, run_wipe

    return TaskSpec("wipe", WipeConfig, run_wipe, tuple(WIPE_BASELINES), "duration_s")


#: Task name → the loader of its :class:`TaskSpec` (cleaning, TEC §V-A; wiping, VA-UFIC §III).
TASKS: dict[str, Callable[[], TaskSpec]] = {"clean": _clean, "wipe": _wipe}


def task_spec(kind: str) -> TaskSpec:
    """The registered task ``kind``; a :class:`ConfigError` lists the valid names."""
    loader = TASKS.get(kind)
    if loader is None:
        raise ConfigError(f"unknown task '{kind}'; valid: {', '.join(TASKS)}")
    return loader()


def baseline_names(kind: str) -> tuple[str, ...]:
    """The named baselines of a task (without tactex itself)."""
    return tuple(b for b in task_spec(kind).baselines if b)
