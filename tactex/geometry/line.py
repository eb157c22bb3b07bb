"""Oriented lines in 3-D: the numpy view of CGA lines L = P₁ ∧ P₂ ∧ e∞ (TEC eq. 10).

A :class:`Line3` is a point and a unit direction. :meth:`Line3.to_gafro` builds the same
line as a ``pygafro.Line`` (through ``point`` and ``point + direction``) so every closed form
here can be checked against the library (``tests/test_geometry_lines.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tactex.errors import InputError

__all__ = ["Line3"]


def _vec3(name: str, value: object) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (3,) or not np.isfinite(arr).all():
        raise InputError(f"{name} must be a finite 3-vector, got {arr!r} (shape {arr.shape})")
    return arr


@dataclass(frozen=True)
class Line3:
    """Oriented line through ``point`` [m] along the unit vector ``direction``."""

    point: np.ndarray
    direction: np.ndarray

    def __post_init__(self) -> None:
        p = _vec3("Line3.point", self.point)
        d = _vec3("Line3.direction", self.direction)
        n = float(np.linalg.norm(d))
        if n < 1e-9:
            raise InputError(f"Line3.direction must be non-zero, got {d!r}")
        object.__setattr__(self, "point", p)
        object.__setattr__(self, "direction", d / n)

    def transformed(self, rot: np.ndarray, trans: np.ndarray) -> Line3:
        """The line moved by x ↦ rot·x + trans."""
        return Line3(rot @ self.point + trans, rot @ self.direction)

    def distance_to_point(self, x: np.ndarray) -> float:
        """Euclidean distance of point ``x`` from the line [m]."""
        w = np.asarray(x, dtype=float) - self.point
        return float(np.linalg.norm(w - (w @ self.direction) * self.direction))

    def to_gafro(self):
        """The same line as ``pygafro.Line`` (P₁ ∧ P₂ ∧ e∞)."""
        import pygafro

        p1 = pygafro.Point(*self.point)
        p2 = pygafro.Point(*(self.point + self.direction))
        return pygafro.Line(p1, p2)
