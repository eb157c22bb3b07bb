"""The hand-eye calibration file: tool_T_camera, a 4×4 rigid transform in a .npy or .json file
(and, read the same way, a camera pose file: base_T_camera).

Read with its size and type checked before anything is allocated: a .npy header must announce a
4×4 array of numbers (no pickle), a .json file must be small (:data:`MAX_JSON_BYTES`) and hold a
nested list of numbers. Every refusal is one :class:`~tactex.errors.InputError` naming the file.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from tactex.errors import InputError

__all__ = ["MAX_JSON_BYTES", "load_hand_eye", "load_pose_file"]

#: A 4×4 transform as JSON text is a few hundred bytes; a file over this is not one [bytes].
MAX_JSON_BYTES = 1 << 16


_HAND_EYE = ("hand-eye calibration", "tool_T_camera")


def _read_npy(p: Path, what: tuple[str, str] = _HAND_EYE) -> np.ndarray:
    from tactex.pointcloud.npz_check import HEADER_ERRORS, NUMERIC_KINDS, kind_words, npy_header, quiet_numpy_header

    with p.open("rb") as f:
        try:
            shape, dtype = npy_header(f)
        except HEADER_ERRORS as exc:
            raise InputError(f"{what[0]} '{p}' is not a .npy array (give a .npy or .json 4×4 "
                             f"{what[1]}): {str(exc).strip()[:120]}") from None
        if dtype.kind not in NUMERIC_KINDS or dtype.kind == "b":
            raise InputError(f"{what[0]} '{p}' holds {kind_words(dtype)}, not a 4×4 array of numbers")
        if shape != (4, 4):
            raise InputError(f"{what[0]} '{p}' must hold a 4×4 rigid transform, got shape {shape}")
    try:
        with quiet_numpy_header():
            return np.load(p, allow_pickle=False)
    except HEADER_ERRORS as exc:
        raise InputError(f"{what[0]} '{p}' cannot be read (damaged or truncated): "
                         f"{str(exc).strip()[:120]}") from None


def _read_json(p: Path, what: tuple[str, str] = _HAND_EYE) -> np.ndarray:
    if p.stat().st_size > MAX_JSON_BYTES:
        raise InputError(f"{what[0]} '{p}' has {p.stat().st_size} bytes: not a 4×4 transform (a nested "
                         "list of 16 numbers)")
    try:
        return np.asarray(json.loads(p.read_bytes()), dtype=float)
    except (ValueError, TypeError, OverflowError, RecursionError) as exc:  # UnicodeDecodeError, JSONDecodeError
        raise InputError(f"{what[0]} '{p}' is not a JSON nested list of numbers (a 4×4 {what[1]}): "
                         f"{str(exc).strip()[:120]}") from None


def _read_rigid(path: str | Path, what: tuple[str, str]) -> tuple[Path, np.ndarray]:
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{what[0]} '{p}' is not a file (give a .npy or .json 4×4 {what[1]})")
    pose = _read_json(p, what) if p.suffix == ".json" else _read_npy(p, what)
    pose = np.asarray(pose, dtype=float)
    rot = pose[:3, :3] if pose.shape == (4, 4) else None
    # a finite rotation's entries are within ±1: larger ones fail the check without overflowing in it
    if rot is None:
        why = f"got shape {pose.shape}"
    elif not np.isfinite(pose).all():
        why = "it holds NaN or inf"
    elif np.abs(rot).max() > 1.0 + 1e-4 or not np.allclose(rot.T @ rot, np.eye(3), atol=1e-4):
        why = "its upper-left 3×3 is no rotation (Rᵀ·R is not the identity: a scale or a shear?)"
    elif not np.allclose(pose[3], [0, 0, 0, 1]):
        why = f"its last row is {np.round(pose[3], 4).tolist()}"
    elif np.linalg.det(rot) < 0:
        why = "its 3×3 is a reflection (determinant −1)"
    else:
        return p, pose
    raise InputError(f"{what[0]} '{p}' must hold a 4×4 rigid transform (rotation, translation in metres, last row "
                     f"0 0 0 1): {why}")


def load_pose_file(path: str | Path, what: str = "camera pose", name: str = "base_T_camera",
                   max_distance_m: float = 3.0) -> np.ndarray:
    """A 4×4 rigid transform ``name`` from a ``.npy`` array or a ``.json`` nested list (no pickle),
    read and checked as :func:`load_hand_eye` reads its file; ``what`` names the file in messages and
    a translation over ``max_distance_m`` [m] is refused as not in metres."""
    p, pose = _read_rigid(path, (what, name))
    if np.abs(pose[:3, 3]).max() > max_distance_m:
        raise InputError(f"{what} '{p}': a translation of {np.abs(pose[:3, 3]).max():.3g} is over "
                         f"{max_distance_m:g} m; give it in metres")
    return pose


def load_hand_eye(path: str | Path) -> np.ndarray:
    """tool_T_camera (4, 4) from a ``.npy`` array or a ``.json`` nested list (no pickle)."""
    p, pose = _read_rigid(path, _HAND_EYE)
    if np.abs(pose[:3, 3]).max() > 1.0:
        raise InputError(f"hand-eye calibration '{p}': the camera sits {np.abs(pose[:3, 3]).max():.3g} m from the "
                         "tool, farther than 1 m: give the translation in metres (not millimetres)")
    return pose
