"""``samples``: a path given as samples, e.g. drawn by a person: a CSV file with the header
``t_s,u_m,v_m,force_n`` (time [s], in-plane offset [m], normal force set point [N]).

The offset is interpolated by a cubic spline with zero rate at the first and last sample (C², so the
rate and acceleration the validator checks are the spline's own), the force linearly; the path is
shifted to start at (0, 0) and its time to start at 0."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline

from tactex.errors import ConfigError, InputError
from tactex.tasks.policies.base import ForceRamp, PolicyPoint, PolicySegment

__all__ = ["SAMPLE_COLUMNS", "SamplesPolicy", "read_sample_lines", "read_samples"]

SAMPLE_COLUMNS = ("t_s", "u_m", "v_m", "force_n")


def read_samples(path: str | Path) -> np.ndarray:
    """The (N, 4) samples of a CSV file, checked: the header, N ≥ 2 rows of finite numbers, time
    strictly increasing. An :class:`InputError` names the file, the line and the column."""
    return read_sample_lines(path)[0]


def read_sample_lines(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """:func:`read_samples`' samples (N, 4) and each one's line in the file (N,) (blank lines skipped, so a
    message can point at the line a user sees)."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"samples file '{p}' does not exist")
    try:
        with p.open(newline="", encoding="utf-8-sig") as fh:  # a spreadsheet's "CSV UTF-8" starts with a BOM
            reader = csv.reader(fh)
            rows = [(reader.line_num, r) for r in reader if r and any(c.strip() for c in r)]
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"samples file '{p}' cannot be read as CSV text: {exc}") from exc
    if not rows or tuple(c.strip() for c in rows[0][1]) != SAMPLE_COLUMNS:
        found = f"'{','.join(rows[0][1])}'" if rows else "nothing"
        raise InputError(f"samples file '{p}': the first line must be the header {','.join(SAMPLE_COLUMNS)}, "
                         f"found {found}")
    data = np.empty((len(rows) - 1, 4))
    lines = np.array([n for n, _ in rows[1:]], dtype=np.int64)
    for k, (i, row) in enumerate(rows[1:]):
        if len(row) != 4:
            raise InputError(f"samples file '{p}' line {i}: {len(row)} columns, expected 4 "
                             f"({','.join(SAMPLE_COLUMNS)})")
        for j, cell in enumerate(row):
            try:
                v = float(cell)
            except ValueError:
                raise InputError(f"samples file '{p}' line {i}: {SAMPLE_COLUMNS[j]} = {cell.strip()!r} is not a "
                                 "number") from None
            if not math.isfinite(v):
                raise InputError(f"samples file '{p}' line {i}: {SAMPLE_COLUMNS[j]} = {cell.strip()} is not a "
                                 "finite number")
            data[k, j] = v
    if len(data) < 2:
        raise InputError(f"samples file '{p}': at least 2 samples are needed, got {len(data)}")
    bad = np.flatnonzero(np.diff(data[:, 0]) <= 0.0)
    if bad.size:
        k = int(bad[0])
        raise InputError(f"samples file '{p}' line {lines[k + 1]}: t_s = {data[k + 1, 0]:g} does not increase "
                         f"(previous {data[k, 0]:g}); time must increase strictly")
    return data, lines


class SamplesPolicy(PolicySegment):
    """Samples (N, 4) = t_s, u_m, v_m, force_n, interpolated (see the module docstring)."""

    kind = "samples"
    fields = ("file",)

    def __init__(self, samples: np.ndarray, source: str = "", lines: np.ndarray | None = None) -> None:
        data = np.asarray(samples, dtype=float)
        if data.ndim != 2 or data.shape[1] != 4 or len(data) < 2 or not np.all(np.isfinite(data)) \
                or np.any(np.diff(data[:, 0]) <= 0):
            raise ConfigError("samples: need (N ≥ 2, 4) finite rows t_s,u_m,v_m,force_n with t_s increasing")
        t = data[:, 0] - data[0, 0]
        super().__init__(float(t[-1]), ForceRamp(float(data[0, 3]), float(data[-1, 3])))
        self.source = source
        self.samples = data
        # each sample's line in its file (a header, then one per line, where none was given)
        self.lines = np.arange(2, len(data) + 2) if lines is None else np.asarray(lines, dtype=np.int64)
        self._t, self._f = t, data[:, 3]
        self._spline = CubicSpline(t, data[:, 1:3] - data[0, 1:3], bc_type="clamped")
        self._rate = self._spline.derivative()
        lo, hi = float(self._f.min()), float(self._f.max())
        self.force_bounds_n = (lo, hi)

    def path(self, t_s: float) -> tuple[float, float, float, float]:
        (u, v), (du, dv) = self._spline(t_s), self._rate(t_s)
        return float(u), float(v), float(du), float(dv)

    def at(self, t_s: float) -> PolicyPoint:
        p = super().at(t_s)
        return p._replace(force_n=float(np.interp(t_s, self._t, self._f)))

    @property
    def constant_force_n(self) -> float | None:
        return float(self._f[0]) if np.all(self._f == self._f[0]) else None
