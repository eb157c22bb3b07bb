"""Rotation helpers in closed form (numpy): hat, exp/log on SO(3), geodesic interpolation.

Written out by hand rather than through ``scipy.spatial.transform.Rotation`` because the
controllers call them at 1 kHz and scipy's object construction costs ~20 µs per call; the
formulas are tested against scipy in ``tests/test_geometry_so3.py``.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["exp_so3", "hat", "interpolate_rotation", "log_so3", "orthonormalize", "rotation_error_world"]

_EPS = 1e-12


def hat(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix [v]× with hat(v) @ w == cross(v, w)."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def exp_so3(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation matrix of the rotation vector ``rotvec`` = angle·axis [rad].

    Written out element by element on Python floats: with K = [k]× for the unit axis k,
    K² = kkᵀ − I, and one array construction costs less than the numpy expression at 1 kHz."""
    x, y, z = float(rotvec[0]), float(rotvec[1]), float(rotvec[2])
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < _EPS:
        return np.array([[1.0, -z, y], [z, 1.0, -x], [-y, x, 1.0]])
    x, y, z = x / angle, y / angle, z / angle
    s = math.sin(angle)
    c = 1.0 - math.cos(angle)
    cxy, cxz, cyz = c * x * y, c * x * z, c * y * z
    return np.array([
        [1.0 - c * (y * y + z * z), cxy - s * z, cxz + s * y],
        [cxy + s * z, 1.0 - c * (x * x + z * z), cyz - s * x],
        [cxz - s * y, cyz + s * x, 1.0 - c * (x * x + y * y)],
    ])


def log_so3(rot: np.ndarray) -> np.ndarray:
    """Rotation vector angle·axis [rad] of a rotation matrix, angle in [0, π]."""
    # scalar arithmetic on the nine entries (one tolist) is cheaper per tick than numpy indexing
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = np.ravel(rot).tolist()
    cos_a = max(-1.0, min(1.0, 0.5 * (r00 + r11 + r22 - 1.0)))
    wx, wy, wz = r21 - r12, r02 - r20, r10 - r01
    sin_a = 0.5 * math.sqrt(wx * wx + wy * wy + wz * wz)
    angle = math.atan2(sin_a, cos_a)
    if angle < 1e-9:
        return np.array([0.5 * wx, 0.5 * wy, 0.5 * wz])
    if math.pi - angle > 1e-6:
        f = angle / (2.0 * sin_a)
        return np.array([wx * f, wy * f, wz * f])
    w = np.array([wx, wy, wz])
    # Near π the antisymmetric part vanishes: take the axis from the symmetric part.
    sym = 0.5 * (rot + rot.T) - cos_a * np.eye(3)
    col = int(np.argmax(np.diag(sym)))
    axis = sym[:, col] / math.sqrt(max(sym[col, col], _EPS))
    if w @ axis < 0.0:
        axis = -axis
    return axis / np.linalg.norm(axis) * angle


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
