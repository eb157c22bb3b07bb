"""Shared argument checks of the report helpers (shapes are echoed in the messages)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from tactex.errors import InputError

__all__ = ["as_fields", "as_mask", "as_path", "as_points"]


def as_points(points: object, name: str = "points") -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] == 0:
        raise InputError(f"{name} must have shape (N, 3) with N ≥ 1, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise InputError(f"{name} holds NaN/inf values")
    return arr


def as_fields(fields: Mapping[str, object] | np.ndarray | None, n: int) -> dict[str, np.ndarray]:
    """Named per-point fields (N,) — a bare array becomes {"value": array}; None → {}."""
    if fields is None:
        return {}
    if not isinstance(fields, Mapping):
        fields = {"value": fields}
    out = {}
    for name, value in fields.items():
        arr = np.asarray(value, dtype=np.float64)
        if arr.shape != (n,):
            raise InputError(f"field '{name}' must have shape ({n},) to match the points, got {arr.shape}")
        out[str(name)] = arr
    return out


def as_path(path: object, name: str = "trajectory") -> np.ndarray | None:
    """A polyline (T, 3) [m], or None; NaN rows are refused (a plot must not hide them)."""
    if path is None:
        return None
    arr = np.asarray(path, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"{name} must have shape (T, 3), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise InputError(f"{name} holds NaN/inf values")
    return arr


def as_mask(mask: object, n: int, name: str = "mask") -> np.ndarray:
    """A boolean per point (n,)."""
    arr = np.asarray(mask)
    if arr.shape != (n,) or arr.dtype != bool:
        raise InputError(f"{name} must be a boolean array of shape ({n},) to match the points, got {arr.dtype} "
                         f"{arr.shape}")
    return arr
