"""Cheap run functions for the executor tests (a module of their own: spawned workers import it
fast, without the test modules' imports)."""

from __future__ import annotations

import os
from pathlib import Path


def square(task, shared):
    if task == 3:
        raise ValueError("three is not allowed")
    return task * task + shared


def die_once(task, shared):
    """Kills its own worker process the first time it sees task 1 (a marker file remembers)."""
    marker = Path(shared) / f"died-{task}"
    if task == 1 and not marker.exists():
        marker.write_text("x")
        os._exit(1)
    return task
