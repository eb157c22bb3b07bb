"""A user's cloud file as a target: read, voxelised, its target chosen and its keep-out zone carried along.

The one pipeline every command that takes a cloud file runs (``tactex explore``, ``tactex clean --cloud``):
the file (:func:`~tactex.pointcloud.io.read_cloud`) → the keep-out zone on its rows
(:func:`~tactex.pointcloud.keep_out.raw_keep_out`) → the voxel grid and the target
(:func:`~tactex.pointcloud.target.file_target`) → the keep-out zone on the voxels.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tactex.errors import InputError
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.pointcloud.io import DEFAULT_MESH_SPACING_M, CloudFile, read_cloud
from tactex.pointcloud.keep_out import DEFAULT_KEEP_OUT_THRESHOLD, keep_out_on_voxels, raw_keep_out
from tactex.pointcloud.target import TargetRule, file_target

__all__ = ["TargetFile", "load_target_file"]


@dataclass(frozen=True)
class TargetFile:
    """A cloud file loaded as a target.

    Attributes:
        cloud: the voxelised cloud (a mesh: its samples as they are) with its target.
        keep_out: a boolean per point of ``cloud`` (True: no footprint may touch it), None without a zone.
        read: what reading the file did (the raw points, dropped rows, a mesh's faces, notes).
        target_rule: how the target was chosen, in words.
    """

    cloud: SurfaceCloud
    keep_out: np.ndarray | None
    read: CloudFile
    target_rule: str


def load_target_file(path: str | Path, voxel_size_m: float, rule: TargetRule, *, keep_out_channel: str = "",
                     keep_out_threshold: float = DEFAULT_KEEP_OUT_THRESHOLD, keep_out_mask: str = "",
                     label: str = "", unmarked_hint: str | None = None, units: str = "m") -> TargetFile:
    """Load the cloud or mesh file ``path`` as a target.

    Args:
        path: a .ply/.pcd/.npz cloud or an .stl/.obj mesh [m].
        voxel_size_m: voxel grid of a cloud and sampling spacing of a mesh [m]; 0: a cloud as it is (a mesh
            then at the default spacing).
        rule: which points are target (a stored target, a colour, the whole surface).
        keep_out_channel, keep_out_threshold, keep_out_mask: the keep-out zone
            (:func:`~tactex.pointcloud.keep_out.raw_keep_out`).
        label: how messages name the file's option (``"--cloud "``), '' for none.
        unmarked_hint: when given, a file with neither colours nor a stored target is refused up front with
            this advice (for a caller whose rule cannot be the whole surface); None: the rule decides.
        units: the file's length unit (m, mm, in), converted to metres as it is read.

    Raises:
        InputError: the file is unreadable, unmarked, or its keep-out options do not fit it.
    """
    read = read_cloud(path, mesh_spacing_m=voxel_size_m or DEFAULT_MESH_SPACING_M, units=units)
    raw = read.cloud
    voxel = 0.0 if read.n_faces else voxel_size_m  # a mesh is sampled at the voxel spacing already
    keep_out = raw_keep_out(raw, keep_out_channel, keep_out_threshold, keep_out_mask, read)
    if unmarked_hint is not None and raw.colors is None and raw.n_target == 0:
        raise InputError(f"{label}'{path}' has neither a target nor colours: {unmarked_hint}")
    cloud, words = file_target(raw, voxel, rule, str(path))
    if keep_out is not None and voxel > 0:
        keep_out = keep_out_on_voxels(raw.points, keep_out, voxel)
    return TargetFile(cloud, keep_out, read, words)
