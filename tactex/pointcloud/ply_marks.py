"""Marks a person painted on a cloud, stored in a PLY: a per-point ``target`` and ``keep_out``.

``tactex annotate`` writes them; every command that reads a cloud file takes them back: the ``target``
(float, ≥ 0: the unnormalised mass to cover) is the file's stored target (``--target auto``/``stored``),
and ``keep_out`` (uchar, non-zero = no footprint may touch the point) is a keep-out zone merged with
the ``--keep-out-*`` options (:func:`tactex.pointcloud.keep_out.raw_keep_out`). A PLY written by
another tool may carry them too: any non-zero ``keep_out`` counts.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from tactex.errors import CloudError, InputError
from tactex.pointcloud.cloud import SurfaceCloud

__all__ = ["KEEP_OUT_PROPERTY", "TARGET_PROPERTY", "file_keep_out", "keep_out_note", "write_marked_ply"]

TARGET_PROPERTY = "target"
KEEP_OUT_PROPERTY = "keep_out"
#: The comment :func:`tactex.pointcloud.io.save_ply` writes for the spacing h [m]; written here too.
_SPACING_COMMENT = "tactex spacing_m "


def file_keep_out(vertex: Any, rows: Any = None) -> np.ndarray | None:
    """The ``keep_out`` property of a PLY's vertex element as booleans (True = kept out), or None when
    the file has none.

    Args:
        vertex: the plyfile vertex element.
        rows: callable that keeps the rows the cloud kept (NaN/inf points dropped), or None for all rows.
    """
    names = set(vertex.data.dtype.names or ())
    if KEEP_OUT_PROPERTY not in names:
        return None
    values = np.asarray(vertex[KEEP_OUT_PROPERTY])
    if values.dtype == object:
        raise CloudError(f"its vertex property '{KEEP_OUT_PROPERTY}' is a list; a vertex's keep-out is one number")
    values = np.nan_to_num(values.astype(np.float64)) != 0.0
    return values if rows is None else np.asarray(rows(values), dtype=bool)


def keep_out_note(mask: np.ndarray | None) -> tuple[str, ...]:
    """The line a command shows for a file's own keep-out zone (none for a file without one)."""
    if mask is None:
        return ()
    return (f"keep-out zone from the file's '{KEEP_OUT_PROPERTY}' property: {int(mask.sum())} points "
            "(merged with any --keep-out-* option)",)


def write_marked_ply(cloud: SurfaceCloud, target: np.ndarray, keep_out: np.ndarray, path: str | Path) -> Path:
    """Write a binary PLY: x y z [m], normals and 8-bit colours when the cloud has them, ``target``
    (float64, one per point) and ``keep_out`` (uchar, 1 = kept out); the spacing h goes in the comment
    :func:`tactex.pointcloud.io.load_ply` reads back."""
    from plyfile import PlyData, PlyElement

    n = len(cloud)
    target = np.asarray(target, dtype=np.float64)
    keep_out = np.asarray(keep_out, dtype=bool)
    if target.shape != (n,) or keep_out.shape != (n,):
        raise InputError(f"target and keep_out need one entry per point ({n}), got {target.shape} and {keep_out.shape}")
    if not np.isfinite(target).all() or (target < 0).any():
        raise InputError("the target must be finite and ≥ 0 at every point")
    fields: list[tuple[str, str]] = [("x", "f8"), ("y", "f8"), ("z", "f8")]
    if cloud.normals is not None:
        fields += [("nx", "f8"), ("ny", "f8"), ("nz", "f8")]
    if cloud.colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    fields += [(TARGET_PROPERTY, "f8"), (KEEP_OUT_PROPERTY, "u1")]
    data = np.empty(n, dtype=fields)
    data["x"], data["y"], data["z"] = cloud.points.T
    if cloud.normals is not None:
        data["nx"], data["ny"], data["nz"] = cloud.normals.T
    if cloud.colors is not None:
        data["red"], data["green"], data["blue"] = np.round(cloud.colors * 255.0).astype(np.uint8).T
    data[TARGET_PROPERTY] = target
    data[KEEP_OUT_PROPERTY] = keep_out.astype(np.uint8)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".part")
    # written aside then renamed: a save that fails half way never leaves a truncated file behind
    PlyData([PlyElement.describe(data, "vertex")], comments=[f"{_SPACING_COMMENT}{cloud.spacing!r}"]).write(str(tmp))
    tmp.replace(out)
    return out
