"""Rotation helpers in closed form (numpy): hat, exp/log on SO(3), geodesic interpolation.

Written out by hand rather than through ``scipy.spatial.transform.Rotation`` because the
controllers call them at 1 kHz and scipy's object construction alone takes a sizeable share of a
1 ms tick per call; the formulas are tested against scipy in ``tests/test_geometry_so3.py``.

The ``*_rows`` variants take rotations as three rows of Python floats (tuples, or the lists
``rot.tolist()`` gives) and return tuples: a controller tick needs a log and up to three 3×3
products (plus an exp while re-orienting), and each numpy call on a 3×3 array costs more at 1 kHz
than the few dozen float operations it replaces. ``exp_so3`` and ``log_so3`` are thin wrappers
around their row variants, so both give the same numbers.
"""

from __future__ import annotations

import math

import numpy as np

from tactex.errors import InputError

__all__ = [
    "exp_so3",
    "exp_so3_rows",
    "hat",
    "interpolate_rotation",
    "log_so3",
    "log_so3_rows",
    "matmul3_nt_rows",
    "matmul3_rows",
    "matmul3_tn_rows",
    "orthonormalize",
    "rotate_towards",
    "rotation_error_world",
    "rotation_error_world_rows",
]

Rows = tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]

_EPS = 1e-12


def hat(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix [v]× with hat(v) @ w == cross(v, w)."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def exp_so3_rows(x: float, y: float, z: float) -> Rows:
    """Rodrigues on Python floats: the rows of the rotation matrix of the rotation vector
    (x, y, z) = angle·axis [rad]. With K = [k]× for the unit axis k, K² = kkᵀ − I."""
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < _EPS:
        return (1.0, -z, y), (z, 1.0, -x), (-y, x, 1.0)
    x, y, z = x / angle, y / angle, z / angle
    s = math.sin(angle)
    c = 1.0 - math.cos(angle)
    cxy, cxz, cyz = c * x * y, c * x * z, c * y * z
    return (
        (1.0 - c * (y * y + z * z), cxy - s * z, cxz + s * y),
        (cxy + s * z, 1.0 - c * (x * x + z * z), cyz - s * x),
        (cxz - s * y, cyz + s * x, 1.0 - c * (x * x + y * y)),
    )


def exp_so3(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation matrix of the rotation vector ``rotvec`` = angle·axis [rad]
    (:func:`exp_so3_rows` as an array)."""
    return np.array(exp_so3_rows(float(rotvec[0]), float(rotvec[1]), float(rotvec[2])))


def log_so3_rows(rows) -> tuple[float, float, float]:
    """Rotation vector angle·axis [rad] (angle in [0, π]) of the rotation given by its rows as
    Python floats. Near π, where the antisymmetric part vanishes, :func:`log_so3`'s array branch
    takes the axis from the symmetric part."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rows
    cos_a = 0.5 * (r00 + r11 + r22 - 1.0)
    cos_a = cos_a if cos_a < 1.0 else 1.0  # max(-1, min(1, ·)) without two builtin calls (a NaN gives 1 too)
    cos_a = cos_a if cos_a > -1.0 else -1.0
    wx, wy, wz = r21 - r12, r02 - r20, r10 - r01
    sin_a = 0.5 * math.sqrt(wx * wx + wy * wy + wz * wz)
    angle = math.atan2(sin_a, cos_a)
    if angle < 1e-9:
        return 0.5 * wx, 0.5 * wy, 0.5 * wz
    if math.pi - angle > 1e-6:
        f = angle / (2.0 * sin_a)
        return wx * f, wy * f, wz * f
    return _log_near_pi(np.array(rows, dtype=float), cos_a, angle, wx, wy, wz)


def _log_near_pi(rot: np.ndarray, cos_a: float, angle: float, wx: float, wy: float, wz: float
                 ) -> tuple[float, float, float]:
    # Near π the antisymmetric part vanishes: take the axis from the symmetric part.
    sym = 0.5 * (rot + rot.T) - cos_a * np.eye(3)
    col = int(np.argmax(np.diag(sym)))
    axis = sym[:, col] / math.sqrt(max(sym[col, col], _EPS))
    if wx * axis[0] + wy * axis[1] + wz * axis[2] < 0.0:
        axis = -axis
    x, y, z = (axis / np.linalg.norm(axis) * angle).tolist()
    return x, y, z


def log_so3(rot: np.ndarray) -> np.ndarray:
    """Rotation vector angle·axis [rad] of a rotation matrix, angle in [0, π]
    (:func:`log_so3_rows` on the array's entries)."""
    return np.array(log_so3_rows(np.asarray(rot, dtype=float).tolist()))


def matmul3_rows(a, b) -> Rows:
    """A·B for two 3×3 matrices given as rows of Python floats."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = b
    return (
        (a00 * b00 + a01 * b10 + a02 * b20, a00 * b01 + a01 * b11 + a02 * b21, a00 * b02 + a01 * b12 + a02 * b22),
        (a10 * b00 + a11 * b10 + a12 * b20, a10 * b01 + a11 * b11 + a12 * b21, a10 * b02 + a11 * b12 + a12 * b22),
        (a20 * b00 + a21 * b10 + a22 * b20, a20 * b01 + a21 * b11 + a22 * b21, a20 * b02 + a21 * b12 + a22 * b22),
    )


def matmul3_tn_rows(a, b) -> Rows:
    """Aᵀ·B (BLAS "TN") for two 3×3 matrices given as rows of Python floats (no transpose is built)."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = b
    return (
        (a00 * b00 + a10 * b10 + a20 * b20, a00 * b01 + a10 * b11 + a20 * b21, a00 * b02 + a10 * b12 + a20 * b22),
        (a01 * b00 + a11 * b10 + a21 * b20, a01 * b01 + a11 * b11 + a21 * b21, a01 * b02 + a11 * b12 + a21 * b22),
        (a02 * b00 + a12 * b10 + a22 * b20, a02 * b01 + a12 * b11 + a22 * b21, a02 * b02 + a12 * b12 + a22 * b22),
    )


def matmul3_nt_rows(a, b) -> Rows:
    """A·Bᵀ (BLAS "NT") for two 3×3 matrices given as rows of Python floats (no transpose is built)."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = b
    return (
        (a00 * b00 + a01 * b01 + a02 * b02, a00 * b10 + a01 * b11 + a02 * b12, a00 * b20 + a01 * b21 + a02 * b22),
        (a10 * b00 + a11 * b01 + a12 * b02, a10 * b10 + a11 * b11 + a12 * b12, a10 * b20 + a11 * b21 + a12 * b22),
        (a20 * b00 + a21 * b01 + a22 * b02, a20 * b10 + a21 * b11 + a22 * b12, a20 * b20 + a21 * b21 + a22 * b22),
    )


def orthonormalize(rot: np.ndarray) -> np.ndarray:
    """Nearest rotation matrix (SVD), for matrices that drifted numerically."""
    u, _, vt = np.linalg.svd(rot)
    r = u @ vt
    if np.linalg.det(r) < 0.0:
        u[:, -1] = -u[:, -1]
        r = u @ vt
    return r


def interpolate_rotation(rot_init: np.ndarray, rot_goal: np.ndarray, zeta: float) -> np.ndarray:
    """VA-UFIC eq. 29: (R_goal R_initᵀ)^ζ R_init, the geodesic from R_init (ζ=0) to R_goal (ζ=1)."""
    z = min(1.0, max(0.0, float(zeta)))
    return exp_so3(z * log_so3(rot_goal @ rot_init.T)) @ rot_init


def rotation_error_world(rot: np.ndarray, rot_desired: np.ndarray) -> np.ndarray:
    """Orientation error x̃_rot of the pose ``rot`` w.r.t. ``rot_desired`` as a world-frame
    rotation vector [rad]: log(R R_dᵀ), so that a stiffness −K·x̃ rotates R back to R_d."""
    return log_so3(rot @ rot_desired.T)


def rotation_error_world_rows(rot, rot_desired) -> tuple[float, float, float]:
    """:func:`rotation_error_world` on rotations given as rows of Python floats (per-tick path)."""
    return log_so3_rows(matmul3_nt_rows(rot, rot_desired))


def rotate_towards(current: np.ndarray, target: np.ndarray, max_angle_rad: float) -> np.ndarray:
    """The unit vector ``current`` (3,) turned towards the unit vector ``target`` (3,) by at most
    ``max_angle_rad`` [rad] on the great circle through both (``target`` itself when nearer).
    Antiparallel vectors have no unique great circle: any perpendicular axis is used.
    Both vectors are normalised first; zero-length or non-finite vectors and a negative or
    non-finite angle raise :class:`~tactex.errors.InputError`."""
    current, target = np.asarray(current, dtype=float), np.asarray(target, dtype=float)
    nc, nt = float(np.sqrt(current @ current)), float(np.sqrt(target @ target))
    if not (np.isfinite(nc) and np.isfinite(nt) and nc > 0.0 and nt > 0.0):
        raise InputError(
            f"rotate_towards needs two finite non-zero 3-vectors, got {current.tolist()} and {target.tolist()}"
        )
    if not (np.isfinite(max_angle_rad) and max_angle_rad >= 0.0):
        raise InputError(f"rotate_towards: max_angle_rad must be finite and ≥ 0, got {max_angle_rad!r}")
    current, target = current / nc, target / nt
    c = float(np.clip(current @ target, -1.0, 1.0))
    angle = float(np.arccos(c))
    if angle <= max_angle_rad:
        return target.copy()
    axis = np.cross(current, target)
    norm = float(np.sqrt(axis @ axis))
    if norm < 1e-12:
        trial = np.array([1.0, 0.0, 0.0]) if abs(current[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        axis = np.cross(current, trial)
        norm = float(np.sqrt(axis @ axis))
    return exp_so3(axis * (max_angle_rad / norm)) @ current

