"""Which points of a big cloud a page draws: a spatially even subset under a point budget.

A browser draws a few hundred thousand WebGL markers slowly and a page holding them all is tens of
megabytes, while a screen of ~1.5 million pixels shows no more detail with the whole cloud than with a
tenth of it. So a page draws at most a budget of points: one per cell of a voxel grid whose cell is
the smallest that meets the budget (found by bisection), the point nearest each cell's centre. The
points that must read on the page as they are in the run (the target, the points the path touched)
are kept first, up to a share of the budget, so that a small target or a thin trail of coverage does
not thin away. Only the drawing is thinned: the run's files keep every point.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from tactex.errors import ConfigError

__all__ = ["check_budget", "display_subset", "even_pick", "touched_points"]

#: Bisection steps on the cell size: the cell's bracket shrinks by 2^-steps in log scale (from a
#: millionth of the cloud's size to all of it), far finer than a budget needs.
CELL_SEARCH_STEPS = 40
#: The search stops early once the pick holds this share of its budget or more.
GOOD_ENOUGH = 0.97


def check_budget(max_points: object, keep_share: object = 0.5) -> tuple[int, float]:
    """``(max_points, keep_share)`` checked: a whole number of points ≥ 1 and a share in [0, 1]."""
    if isinstance(max_points, bool) or not isinstance(max_points, (int, np.integer)) or max_points < 1:
        raise ConfigError(f"the page's point budget must be a whole number ≥ 1, got {max_points!r}")
    if isinstance(keep_share, bool) or not isinstance(keep_share, (int, float, np.floating)) \
            or not 0.0 <= float(keep_share) <= 1.0:
        raise ConfigError(f"the share of the point budget kept for the target and the path must be in [0, 1], "
                          f"got {keep_share!r}")
    return int(max_points), float(keep_share)


def _cells(points: np.ndarray, origin: np.ndarray, size_m: float) -> np.ndarray:
    """One int64 key per point naming its cell of edge ``size_m`` [m] (cells counted from ``origin``)."""
    ijk = np.floor((points - origin) / size_m).astype(np.int64)
    dims = ijk.max(axis=0) + 1
    return (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]


def even_pick(points: np.ndarray, budget: int) -> np.ndarray:
    """Indices (sorted) of at most ``budget`` of ``points`` (M, 3) [m], spread evenly over the cloud.

    One point per cell of the finest voxel grid with no more occupied cells than ``budget`` — the
    point nearest the cell's centre (ties: the lower index), so the pick is deterministic."""
    n = points.shape[0]
    if n <= budget:
        return np.arange(n)
    if budget <= 0:
        return np.zeros(0, dtype=np.intp)
    origin = points.min(axis=0)
    size = float(np.ptp(points, axis=0).max())
    if size == 0.0:  # every point at one place: any one of them shows it
        return np.zeros(1, dtype=np.intp)
    # Cells of a millionth of the cloud's size keep the key in int64 (at most 1e18 cells).
    lo, hi = size * 1e-6, size * 1.0001  # lo: more cells than the budget, hi: one cell
    for _ in range(CELL_SEARCH_STEPS):
        mid = float(np.sqrt(lo * hi))
        count = np.unique(_cells(points, origin, mid)).size
        if count > budget:
            lo = mid
        else:
            hi = mid
            if count >= GOOD_ENOUGH * budget:
                break
    key = _cells(points, origin, hi)
    centre = origin + (np.floor((points - origin) / hi) + 0.5) * hi
    off = np.einsum("ij,ij->i", points - centre, points - centre)
    order = np.lexsort((np.arange(n), off, key))  # by cell, then nearest the centre, then index
    first = np.ones(n, dtype=bool)
    first[1:] = key[order[1:]] != key[order[:-1]]
    return np.sort(order[first])


def touched_points(points: np.ndarray, path: np.ndarray | None) -> np.ndarray:
    """(N,) bool: the cloud point nearest each of the path's (T, 3) points [m] (the points it walked over)."""
    mask = np.zeros(points.shape[0], dtype=bool)
    if path is not None and path.shape[0]:
        _, idx = cKDTree(points).query(path)
        mask[idx] = True
    return mask


def display_subset(points: np.ndarray, max_points: int, keep: np.ndarray | None = None,
                   keep_share: float = 0.5) -> np.ndarray:
    """Indices (sorted) of the points a page draws: all of them up to ``max_points``, else an even subset.

    Args:
        points: (N, 3) positions [m].
        max_points: the budget: at most this many indices come back.
        keep: (N,) bool, points to keep first (the target, the points the path touched): all of them
            when they are at most ``keep_share × max_points``, else an even pick of that many.
        keep_share: the share of the budget the ``keep`` points may take [0–1]; the rest of the budget
            goes to an even pick of the other points.
    """
    max_points, keep_share = check_budget(max_points, keep_share)
    n = points.shape[0]
    if n <= max_points:
        return np.arange(n)
    first = np.zeros(0, dtype=np.intp)
    if keep is not None and keep.any():
        wanted = np.flatnonzero(keep)
        first = wanted[even_pick(points[wanted], int(keep_share * max_points))]
    rest = np.ones(n, dtype=bool)
    rest[first] = False
    others = np.flatnonzero(rest)
    picked = others[even_pick(points[others], max_points - first.size)]
    return np.sort(np.concatenate([first, picked]))
