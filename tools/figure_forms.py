"""How a documented figure is written: the steps after the keys of a figure marker.

The values the keys select pass through the steps left to right:

- ``%`` multiplies by 100 (a share as a percentage); ``*F`` multiplies by F and ``/F`` divides by F
  (``*1e3``: seconds as milliseconds);
- ``min``, ``max``, ``sum``, ``prod``, ``mean``, ``median``, ``count`` reduce them to one value; ``div`` divides
  the first by the second (exactly two values);
- ``range`` writes the smallest and the largest as ``a–b`` (one figure when both read the same);
  ``list`` writes every value, joined by ", ";
- anything else is a Python format spec (``.2f``, ``.0f``, ``,d``, ``,.0f``) for each number written.

Without ``range`` or ``list`` the steps must end with one value. Without a format spec an integer is
written as it is and any other number with ``.3g``. Text values (a date) are written as they are and
take no step.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable
from typing import Any

NOT_MEASURED = "not measured"

_REDUCE: dict[str, Callable[[list[float]], float]] = {
    "min": min, "max": max, "sum": sum, "mean": statistics.fmean, "median": statistics.median,
    "prod": math.prod,
}


class FigureError(ValueError):
    """A marker that cannot be rendered whatever the sources hold (a typo in its steps)."""


def render(values: list[Any] | None, steps: list[str]) -> str:
    """The text of a figure: ``values`` (None: missing) through ``steps``."""
    if values is None:
        return NOT_MEASURED
    join, spec = None, None
    for step in steps:
        if spec is not None:
            raise FigureError(f"the format spec {spec!r} must be the last step, not before {step!r}")
        if step in ("range", "list"):
            if join is not None:
                raise FigureError(f"{join} and {step} in one figure")
            join = step
            continue
        if join is None:
            values, is_form = _apply(values, step)
            if is_form:
                continue
        elif _apply([1.0, 1.0], step)[1]:
            raise FigureError(f"{step!r} must come before {join}: after it only a format spec")
        spec = _spec(step)
    if any(isinstance(v, float) and math.isnan(v) for v in values):  # a ratio over a zero
        return NOT_MEASURED
    if join == "range":
        low, high = _fmt(min(values), spec), _fmt(max(values), spec)
        return low if low == high else f"{low}–{high}"
    if join == "list":
        return ", ".join(_fmt(v, spec) for v in values)
    if len(values) != 1:
        raise FigureError(f"{len(values)} values and no step that makes them one (range, list, min, max, …)")
    return _fmt(values[0], spec)


def _apply(values: list[Any], step: str) -> tuple[list[Any], bool]:
    """The values after a numeric step, and whether ``step`` was one (else it is a format spec)."""
    if step == "%":
        return [_number(v) * 100 for v in values], True
    if step[:1] in ("*", "×", "/") and _is_float(step[1:]):
        factor = float(step[1:])
        return [_number(v) / factor if step[0] == "/" else _number(v) * factor for v in values], True
    if step == "count":  # of anything the keys select, numbers or not
        return [len(values)], True
    if step in _REDUCE:
        return [_REDUCE[step]([_number(v) for v in values])], True
    if step == "div":
        if len(values) != 2:
            raise FigureError(f"div needs exactly two values, the keys gave {len(values)}")
        num, den = _number(values[0]), _number(values[1])
        return [num / den if den else math.nan], True
    return values, False


def _spec(step: str) -> str:
    try:
        format(1.5, step)
    except ValueError:
        try:
            format(1, step)
        except ValueError:
            raise FigureError(f"{step!r} is neither a step of figure_forms nor a format spec") from None
    return step


def _fmt(value: Any, spec: str | None) -> str:
    if isinstance(value, str):
        return value
    if spec is None:
        return str(value) if isinstance(value, int) else format(value, ".3g")
    try:
        return format(value, spec)
    except ValueError:  # an integer spec (",d") on a float that holds a whole number
        return format(round(value), spec)


def _number(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise FigureError(f"{value!r} is not a number")
    return value


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
