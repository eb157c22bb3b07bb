"""Where a documented figure comes from: a key into a committed file that a program wrote from a run.

A key is ``[FILE#]PATH``. FILE is a path relative to the repository (default ``bench/results.json``):
a ``.json`` file is read as nested dicts and lists, a ``.csv`` file (a study's ``summary.csv`` or
``table.csv``) as a list of rows. PATH is ``/``-separated steps, each applied to what the steps
before selected:

- on a dict, a key; with ``*`` in it, every key it matches (``fnmatch``), which makes a list;
- on a list, an index (``0``, ``-1``), ``*`` for every element, or a filter ``col=value[,col=value]``
  keeping the rows whose columns hold that text (``baseline=`` is the empty cell; ``*`` in a value
  matches any text, so ``policy=*spiral*`` reaches a cell that holds a path);
- on a list of rows, a column name picks that column of each row.

A step that finds nothing drops that branch; when nothing is left the figure is missing (``None``),
which the page renders "not measured". Keys hold no spaces (a key with spaces in a committed file is
reached with ``*``), so that several keys can stand side by side in one marker.
"""

from __future__ import annotations

import csv
import json
import math
from fnmatch import fnmatchcase
from pathlib import Path
from typing import Any

DEFAULT_SOURCE = "bench/results.json"


class Sources:
    """The committed result files under ``root``, each read once; ``overrides`` maps a source name to
    another file (``--results`` of readme_status)."""

    def __init__(self, root: Path, overrides: dict[str, Path] | None = None) -> None:
        self.root = Path(root)
        self.overrides = dict(overrides or {})
        self._loaded: dict[str, Any] = {}

    def data(self, name: str) -> Any:
        """The parsed file, or None when it does not exist (a stage never run: "not measured")."""
        if name not in self._loaded:
            path = self.overrides.get(name, self.root / name)
            self._loaded[name] = _read(path) if path.is_file() else None
        return self._loaded[name]

    def values(self, key: str) -> list[Any] | None:
        """The values ``key`` selects, flattened into one list (a JSON list at the end counts as its
        elements); None when the key selects nothing."""
        name, _, path = key.rpartition("#")
        nodes = _walk(self.data(name or DEFAULT_SOURCE), [s for s in path.split("/") if s])
        if nodes is None:
            return None
        out: list[Any] = []
        for node in nodes:
            out.extend(node if isinstance(node, list) else [node])
        # a stage that ran without producing the figure writes NaN (JSON) or an empty cell (CSV)
        out = [v for v in out if v is not None and not (isinstance(v, float) and math.isnan(v))]
        return out or None


def _read(path: Path) -> Any:
    if path.suffix == ".csv":
        with path.open(newline="") as f:
            return list(csv.DictReader(f))
    return json.loads(path.read_text())


def _walk(node: Any, steps: list[str]) -> list[Any] | None:
    """The nodes the steps select from ``node``; None when none is left."""
    if node is None:
        return None
    nodes = [node]
    for step in steps:
        nodes = [found for n in nodes for found in _step(n, step)]
        if not nodes:
            return None
    return [_cell(n) for n in nodes]


def _step(node: Any, step: str) -> list[Any]:
    if isinstance(node, dict):
        if "*" in step:
            return [v for k, v in node.items() if fnmatchcase(k, step)]
        return [node[step]] if step in node else []
    if isinstance(node, list):
        if step == "*":
            return list(node)
        if "=" in step:
            wanted = dict(part.split("=", 1) for part in step.split(","))
            return [row for row in node if isinstance(row, dict)
                    and all(fnmatchcase(str(row.get(col)), val) for col, val in wanted.items())]
        try:
            return [node[int(step)]]
        except (ValueError, IndexError):
            # a column of every row (rows of a CSV, or a JSON list of records)
            return [row[step] for row in node if isinstance(row, dict) and step in row]
    return []


def _cell(value: Any) -> Any:
    """A CSV cell as the number it spells (the JSON files hold numbers already); an empty cell is missing."""
    if not isinstance(value, str):
        return value
    if value == "":
        return None
    for kind in (int, float):
        try:
            return kind(value)
        except ValueError:
            pass
    return value
