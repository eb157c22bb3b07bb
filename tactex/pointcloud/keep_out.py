"""Keep-out zones: cloud points no footprint may touch (a sticker, a sensor, a label on the object).

TEC §VII names on-surface constraints as future work. A user marks the zone as the target is
marked: by a colour channel at or above a threshold (``--keep-out-channel``, ``--keep-out-threshold``),
or by a boolean mask with one entry per point of the cloud file (``--keep-out-mask FILE.npy``; rows with
NaN/inf coordinates included, as the file holds them). The marking is read on the points of the file,
before any voxel grid; a voxel is kept out when any of its points is (a zone only ever grows on the
grid, never shrinks: the conservative side of a constraint). A channel level is the raw rule the
target's ``--target-threshold`` uses, not the target's hue rule: white and light grey pass every
channel's threshold, so a zone marked by colour on a white object needs a saturated colour and a
threshold above the surface's level, or a mask; a marking that takes most of the cloud is warned about.
The explorer then holds no target there and keeps its footprint off the zone
(:class:`tactex.ergodic.HedacExplorer`, ``keep_out``).

A PLY's own ``keep_out`` property (painted with ``tactex annotate``, :mod:`tactex.pointcloud.ply_marks`)
is a zone too, merged with the options.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from tactex.errors import ConfigError, InputError
from tactex.pointcloud.cloud import CloudFile, SurfaceCloud
from tactex.pointcloud.target import CHANNELS
from tactex.pointcloud.voxel import voxel_indices

__all__ = ["KEEP_OUT_CHANNELS", "check_keep_out_options", "keep_out_on_voxels", "load_keep_out_mask",
           "raw_keep_out"]

#: Colour channels a keep-out zone may be marked in ("" = none).
KEEP_OUT_CHANNELS = ("", *CHANNELS)
#: ``--keep-out-threshold``'s default [-]; another value without ``--keep-out-channel`` is refused.
DEFAULT_KEEP_OUT_THRESHOLD = 1.0
#: A colour marking that keeps out more than this share of the cloud is warned about [-]: a white or grey
#: surface passes every channel's threshold.
WIDE_ZONE_SHARE = 0.5


def check_keep_out_options(channel: str, threshold: float, mask_path: str) -> None:
    """ConfigError for a bad ``--keep-out-channel`` / ``--keep-out-threshold`` / ``--keep-out-mask``."""
    if channel not in KEEP_OUT_CHANNELS:
        raise ConfigError(f"unknown --keep-out-channel '{channel}'; valid: {', '.join(CHANNELS)} (or none)")
    if not (isinstance(threshold, (int, float)) and 0.0 <= threshold <= 1.0):
        raise ConfigError(f"--keep-out-threshold must lie in [0, 1] (colours scaled to [0, 1]), got {threshold!r}")
    if not channel and threshold != DEFAULT_KEEP_OUT_THRESHOLD:
        raise ConfigError(f"--keep-out-threshold {threshold:g} needs --keep-out-channel (red, green or blue): "
                          "the threshold applies to that channel's level")
    if mask_path and not str(mask_path).endswith(".npy"):
        raise ConfigError(f"--keep-out-mask '{mask_path}' must be a .npy file holding one boolean per cloud point")


def load_keep_out_mask(path: str | Path, n_points: int, n_finite: int | None = None) -> np.ndarray:
    """The boolean mask (n_points,) stored in ``path`` (.npy, no pickle); ``n_finite``: how many of the file's
    rows have finite coordinates, when not all (a mask of that length gets a message of its own)."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"--keep-out-mask '{p}' does not exist")
    try:
        mask = np.load(p, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise InputError(f"--keep-out-mask '{p}' is not a .npy array of booleans (np.save(path, mask) writes "
                         f"one): {exc}") from exc
    if mask.dtype != bool:
        if mask.dtype.kind in "iu" and np.isin(mask, (0, 1)).all():
            mask = mask.astype(bool)
        else:
            raise InputError(f"--keep-out-mask '{p}' holds {mask.dtype} values; save a boolean array (True = keep out)")
    if n_finite is not None and mask.shape == (n_finite,) != (n_points,):
        raise InputError(
            f"--keep-out-mask '{p}' has one entry per finite point ({n_finite}), but the cloud file has {n_points} "
            f"rows, {n_points - n_finite} of them with NaN/inf coordinates: give one boolean per row of the file, "
            "those rows included")
    if mask.shape != (n_points,):
        raise InputError(
            f"--keep-out-mask '{p}' has shape {mask.shape} but the cloud file has {n_points} points; "
            "give one boolean per point of the file (before the voxel grid)"
        )
    return mask


def raw_keep_out(cloud: SurfaceCloud, channel: str, threshold: float, mask_path: str,
                 read: CloudFile | None = None) -> np.ndarray | None:
    """The kept-out points (N,) of a cloud as loaded (union of the channel, the mask and the file's own
    ``keep_out`` property), or None when none of them is given.

    Args:
        cloud: the cloud's points as loaded (finite rows only).
        read: what reading the file did, when ``cloud`` came from one (``read.cloud``): the mask then
            has one entry per row of the file, its NaN/inf rows included, and a mesh (whose points are
            samples of its faces at the run's spacing) takes no mask.
    """
    from_file = None if read is None else read.keep_out  # a PLY's own keep_out property
    if not channel and not mask_path:
        return None if from_file is None or not from_file.any() else from_file.copy()
    mask = np.zeros(len(cloud), dtype=bool) if from_file is None else from_file.copy()
    if channel:
        if cloud.colors is None:
            raise InputError(f"the cloud has no colours, so --keep-out-channel {channel} marks nothing; "
                             "give --keep-out-mask FILE.npy instead")
        mask |= cloud.colors[:, CHANNELS[channel]] >= threshold - 1e-9
        share = float(mask.mean()) if mask.size else 0.0
        if share > WIDE_ZONE_SHARE:
            warnings.warn(
                f"--keep-out-channel {channel} ≥ {threshold:g} keeps out {share:.0%} of the cloud: white and grey "
                f"surfaces pass every channel's threshold; mark the zone in a saturated colour with a threshold "
                f"above the surface's {channel} level, or give --keep-out-mask", RuntimeWarning, stacklevel=2)
    if mask_path:
        if read is not None and read.n_faces:
            raise InputError(
                f"--keep-out-mask '{mask_path}' cannot index a mesh: its points are samples of the faces at "
                "--voxel-size-m, not the file's vertices; mark the zone in the vertex colours "
                "(--keep-out-channel), or convert the mesh to a point cloud file and give one boolean per point")
        rows = None if read is None else read.kept
        file_mask = load_keep_out_mask(mask_path, len(cloud) if rows is None else rows.size,
                                       n_finite=None if rows is None else len(cloud))
        mask |= file_mask if rows is None else file_mask[rows]
    if from_file is not None and from_file.any():
        options = " and ".join(o for o, given in (("--keep-out-channel", channel), ("--keep-out-mask", mask_path))
                               if given)
        warnings.warn(f"the file's own keep-out zone ({int(from_file.sum())} points) is merged with {options}: "
                      f"{int(mask.sum())} points kept out in all", RuntimeWarning, stacklevel=2)
    if not mask.any():
        if not channel:
            raise InputError(f"--keep-out-mask '{mask_path}' marks no point (no True entry): nothing is kept out")
        raise InputError(
            f"the keep-out marking selects no point (channel {channel} ≥ {threshold:g}"
            + (f", mask '{mask_path}'" if mask_path else "") + "); lower --keep-out-threshold"
            + (" or check the mask" if mask_path else "")
        )
    return mask


def keep_out_on_voxels(points_m: np.ndarray, mask: np.ndarray, voxel_size_m: float) -> np.ndarray:
    """A raw keep-out mask carried onto :func:`~tactex.pointcloud.voxel.voxel_down_sample`'s voxels
    of edge ``voxel_size_m`` (same order): a voxel is kept out when any of its points is."""
    inverse, counts = voxel_indices(points_m, voxel_size_m)
    out = np.zeros(counts.size, dtype=bool)
    out[inverse[mask]] = True
    return out
