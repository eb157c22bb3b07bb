"""An agent's path split into what it walked on the surface and what it flew (relocations), for plots.

Both parts come back as one polyline each with NaN rows between their pieces: matplotlib and plotly
break a line at a NaN, so each part is one line to draw (solid on the surface, dashed in the air).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from tactex.errors import InputError

__all__ = ["flight_indices", "split_flights"]


def flight_indices(flights: Sequence[int], n_points: int) -> np.ndarray:
    """The flights' indices into a path of ``n_points`` points, sorted and unique; each must lie in
    1..n_points − 1 (a flight ends at a point reached from the one before)."""
    idx = np.unique(np.asarray(list(flights), dtype=np.intp))
    if idx.size and (idx[0] < 1 or idx[-1] >= n_points):
        raise InputError(f"flights must be step indices in 1..{n_points - 1}, got {idx.tolist()}")
    return idx


def split_flights(path: np.ndarray, flights: Sequence[int]) -> tuple[np.ndarray, np.ndarray | None]:
    """The path (T, 3) [m] as (surface, air) polylines with NaN rows between pieces.

    Args:
        path: the agent's points in order [m].
        flights: indices k (1 ≤ k < T) where the agent reached ``path[k]`` from ``path[k - 1]`` through
            the air (a relocation's lift-off to its touch-down).

    Returns:
        surface: the path with a NaN row in place of each flight; air: the flights' chords
        (lift-off, touch-down, NaN, …), or None without flights.
    """
    idx = flight_indices(flights, path.shape[0])
    if idx.size == 0:
        return path, None
    gap = np.full((1, 3), np.nan)
    pieces = np.split(path, idx)
    surface = np.vstack([p for piece in pieces for p in (piece, gap)][:-1])
    air = np.vstack([np.vstack([path[k - 1], path[k], gap[0]]) for k in idx])[:-1]
    return surface, air
