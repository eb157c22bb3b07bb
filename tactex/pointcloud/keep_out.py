"""Keep-out zones: cloud points no footprint may touch (a sticker, a sensor, a label on the object).

TEC §VII names on-surface constraints as future work. A user marks the zone as the target is
marked: by a colour channel at or above a threshold (``--keep-out-channel``, ``--keep-out-threshold``),
or by a boolean mask with one entry per point of the cloud file (``--keep-out-mask FILE.npy``). The
marking is read on the points of the file, before any voxel grid; a voxel is kept out when any of its
points is (a zone only ever grows on the grid, never shrinks: the conservative side of a constraint).
The explorer then holds no target there and keeps its footprint off the zone
(:class:`tactex.ergodic.HedacExplorer`, ``keep_out``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tactex.errors import ConfigError, InputError
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.pointcloud.target import CHANNELS
from tactex.pointcloud.voxel import voxel_indices

__all__ = ["KEEP_OUT_CHANNELS", "check_keep_out_options", "keep_out_on_voxels", "load_keep_out_mask",
           "raw_keep_out"]

#: Colour channels a keep-out zone may be marked in ("" = none).
KEEP_OUT_CHANNELS = ("", *CHANNELS)


def check_keep_out_options(channel: str, threshold: float, mask_path: str) -> None:
    """ConfigError for a bad ``--keep-out-channel`` / ``--keep-out-threshold`` / ``--keep-out-mask``."""
    if channel not in KEEP_OUT_CHANNELS:
        raise ConfigError(f"unknown --keep-out-channel '{channel}'; valid: {', '.join(CHANNELS)} (or none)")
    if not (isinstance(threshold, (int, float)) and 0.0 <= threshold <= 1.0):
        raise ConfigError(f"--keep-out-threshold must lie in [0, 1] (colours scaled to [0, 1]), got {threshold!r}")
    if mask_path and not str(mask_path).endswith(".npy"):
        raise ConfigError(f"--keep-out-mask '{mask_path}' must be a .npy file holding one boolean per cloud point")


def load_keep_out_mask(path: str | Path, n_points: int) -> np.ndarray:
    """The boolean mask (n_points,) stored in ``path`` (.npy, no pickle)."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"--keep-out-mask '{p}' does not exist")
    try:
        mask = np.load(p, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise InputError(f"--keep-out-mask '{p}' is not a readable .npy array ({exc})") from exc
    if mask.dtype != bool:
        if mask.dtype.kind in "iu" and np.isin(mask, (0, 1)).all():
            mask = mask.astype(bool)
        else:
            raise InputError(f"--keep-out-mask '{p}' holds {mask.dtype} values; save a boolean array (True = keep out)")
    if mask.shape != (n_points,):
        raise InputError(
            f"--keep-out-mask '{p}' has shape {mask.shape} but the cloud file has {n_points} points; "
            "give one boolean per point of the file (before the voxel grid)"
        )
    return mask


def raw_keep_out(cloud: SurfaceCloud, channel: str, threshold: float, mask_path: str) -> np.ndarray | None:
    """The kept-out points (N,) of a cloud as loaded (union of the channel and the mask), or None
    when neither is given."""
    if not channel and not mask_path:
        return None
    mask = np.zeros(len(cloud), dtype=bool)
    if channel:
        if cloud.colors is None:
            raise InputError(f"the cloud has no colours, so --keep-out-channel {channel} marks nothing; "
                             "give --keep-out-mask FILE.npy instead")
        mask |= cloud.colors[:, CHANNELS[channel]] >= threshold - 1e-9
    if mask_path:
        mask |= load_keep_out_mask(mask_path, len(cloud))
    if not mask.any():
        raise InputError(
            f"the keep-out marking selects no point (channel {channel or '-'} ≥ {threshold:g}, mask "
            f"{mask_path or '-'}); lower --keep-out-threshold or check the mask"
        )
    return mask


def keep_out_on_voxels(points_m: np.ndarray, mask: np.ndarray, voxel_size_m: float) -> np.ndarray:
    """A raw keep-out mask carried onto :func:`~tactex.pointcloud.voxel.voxel_down_sample`'s voxels
    of edge ``voxel_size_m`` (same order): a voxel is kept out when any of its points is."""
    inverse, counts = voxel_indices(points_m, voxel_size_m)
    out = np.zeros(counts.size, dtype=bool)
    out[inverse[mask]] = True
    return out
