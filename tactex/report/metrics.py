"""Metrics files: one JSON per run (NaN/inf written as null), read back with checks."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from tactex.config import write_json
from tactex.errors import InputError

__all__ = ["read_metrics", "write_metrics"]


def write_metrics(metrics: Mapping[str, Any], path: str | Path) -> Path:
    """Write a metrics dictionary (dataclasses, numpy arrays and scalars allowed) as indented JSON."""
    if not isinstance(metrics, Mapping):
        raise InputError(f"metrics must be a mapping of names to values, got {type(metrics).__name__}")
    return write_json(dict(metrics), path)


def read_metrics(path: str | Path) -> dict[str, Any]:
    """Read a metrics JSON file written by :func:`write_metrics`."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"metrics file '{p}' does not exist")
    try:
        data = json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise InputError(f"metrics file '{p}' is not valid JSON: {exc}") from exc
    if not isinstance(data, dict):
        raise InputError(f"metrics file '{p}' must hold a JSON object, got {type(data).__name__}")
    return data
