"""The fuzzed readers: for each, the file suffix of an input, the call that reads it, and its seeds.

A reader passes an input when it returns a valid result or raises a :mod:`tactex.errors` type whose
message names the file; anything else is a crash (see ``run.py``).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import seeds


class LogRecords(logging.Handler):
    """The log records of warning level and above that one read emitted (a reader must log nothing a user
    would see as noise: the fuzzer counts them)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


@dataclass(frozen=True)
class Target:
    """One reader under fuzzing.

    Attributes:
        suffix: the suffix of the file written from an input; a callable picks it from the input's
            first byte (the rest is the file) for readers of two formats.
        read: reads the file at a path; returns what the reader returns.
        seeds: the starting corpus.
        names_file: whether an expected error must name the file (the study reader's checks of the
            tables name the table and key instead; the command adds the file).
    """

    suffix: str | Callable[[bytes], tuple[str, bytes]]
    read: Callable[[Path], Any]
    seeds: Callable[[], list[bytes]]
    names_file: bool = True


def _read_cloud(path: Path) -> Any:
    from tactex.pointcloud.io import read_cloud

    got = read_cloud(path)
    cloud = got.cloud
    pts = cloud.points
    if pts.dtype != np.float64 or pts.ndim != 2 or pts.shape[1] != 3 or not np.isfinite(pts).all():
        raise AssertionError(f"read_cloud returned invalid points {pts.dtype} {pts.shape}")
    if cloud.colors is not None and not (np.isfinite(cloud.colors).all() and cloud.colors.min(initial=0) >= 0
                                         and cloud.colors.max(initial=0) <= 1):
        raise AssertionError("read_cloud returned colours outside [0, 1]")
    return got


def _hand_eye_suffix(data: bytes) -> tuple[str, bytes]:
    return (".json" if data[:1] and data[0] & 1 else ".npy"), data[1:]


def _read_hand_eye(path: Path) -> Any:
    from tactex.tasks.robot import load_hand_eye

    pose = load_hand_eye(path)
    if pose.shape != (4, 4) or not np.isfinite(pose).all():
        raise AssertionError(f"load_hand_eye returned {pose.shape}")
    return pose


def _read_study_spec(path: Path) -> Any:
    from tactex.experiments.study_spec import load_spec_file, spec_from_dict

    return spec_from_dict(load_spec_file(path))


TARGETS: dict[str, Target] = {
    "ply": Target(".ply", _read_cloud, seeds.ply_seeds),
    "pcd_ascii": Target(".pcd", _read_cloud, lambda: seeds.pcd_seeds("ascii")),
    "pcd_binary": Target(".pcd", _read_cloud, lambda: seeds.pcd_seeds("binary")),
    "pcd_binary_compressed": Target(".pcd", _read_cloud, lambda: seeds.pcd_seeds("binary_compressed")),
    "npz": Target(".npz", _read_cloud, seeds.npz_seeds),
    "obj": Target(".obj", _read_cloud, seeds.obj_seeds),
    "stl": Target(".stl", _read_cloud, seeds.stl_seeds),
    "hand_eye": Target(_hand_eye_suffix, _read_hand_eye, seeds.hand_eye_seeds),
    "study_spec": Target(".toml", _read_study_spec, seeds.study_spec_seeds, names_file=False),
}
