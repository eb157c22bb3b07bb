"""SO(3) closed forms against scipy, and the eq. 29 interpolation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tactex.geometry import exp_so3, interpolate_rotation, log_so3, orthonormalize, rotation_error_world
from tactex.geometry.so3 import (
    exp_so3_rows,
    log_so3_rows,
    matmul3_nt_rows,
    matmul3_rows,
    matmul3_tn_rows,
    rotation_error_world_rows,
)

TOL = 1e-10


def test_exp_log_match_scipy(rng):
    for _ in range(50):
        v = rng.normal(size=3)
        v *= rng.uniform(0, np.pi - 1e-3) / np.linalg.norm(v)
        np.testing.assert_allclose(exp_so3(v), Rotation.from_rotvec(v).as_matrix(), atol=TOL)
        np.testing.assert_allclose(log_so3(exp_so3(v)), v, atol=1e-8)


@pytest.mark.parametrize("angle", [0.0, 1e-10, np.pi - 1e-7, np.pi])
def test_log_edge_angles(angle):
    axis = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    r = exp_so3(angle * axis)
    np.testing.assert_allclose(exp_so3(log_so3(r)), r, atol=1e-7)


def test_interpolation_endpoints_and_geodesic(rng):
    r0 = exp_so3(rng.normal(size=3))
    r1 = exp_so3(rng.normal(size=3))
    np.testing.assert_allclose(interpolate_rotation(r0, r1, 0.0), r0, atol=TOL)
    np.testing.assert_allclose(interpolate_rotation(r0, r1, 1.0), r1, atol=1e-9)
    np.testing.assert_allclose(interpolate_rotation(r0, r1, 2.0), r1, atol=1e-9)  # ζ clipped to [0, 1]
    total = np.linalg.norm(log_so3(r1 @ r0.T))
    half = interpolate_rotation(r0, r1, 0.5)
    assert np.linalg.norm(log_so3(half @ r0.T)) == pytest.approx(total / 2, abs=1e-9)


def test_rotation_error_sign(rng):
    rd = exp_so3(rng.normal(size=3))
    w = np.array([0.0, 0.0, 0.1])
    r = exp_so3(w) @ rd  # rotated by +0.1 rad about world z from the desired orientation
    np.testing.assert_allclose(rotation_error_world(r, rd), w, atol=TOL)


def test_orthonormalize(rng):
    r = exp_so3(rng.normal(size=3)) + 1e-4 * rng.normal(size=(3, 3))
    q = orthonormalize(r)
    np.testing.assert_allclose(q @ q.T, np.eye(3), atol=TOL)
    assert np.linalg.det(q) == pytest.approx(1.0)


# -- the float-row variants the controllers use per tick ------------------------------------------------

def _rows(m: np.ndarray):
    return tuple(tuple(r) for r in m.tolist())


def _axis_angle_cases(rng):
    """Random rotations plus the edge angles of the log: 0, tiny, near π (both branches), π."""
    cases = []
    for _ in range(40):
        v = rng.normal(size=3)
        cases.append(v * rng.uniform(0.0, np.pi - 1e-3) / np.linalg.norm(v))
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    for angle in (0.0, 1e-14, 1e-10, 1e-9, 1e-6, np.pi - 1e-5, np.pi - 1e-6, np.pi - 1e-7, np.pi - 1e-9, np.pi):
        cases.append(angle * axis)
    for k in range(3):  # π about the coordinate axes (the symmetric-part branch picks a column)
        cases.append(np.pi * np.eye(3)[k])
    return cases


def test_exp_rows_equal_the_array_and_scipy(rng):
    for v in _axis_angle_cases(rng):
        rows = exp_so3_rows(*v.tolist())
        np.testing.assert_array_equal(np.array(rows), exp_so3(v))
        np.testing.assert_allclose(np.array(rows), Rotation.from_rotvec(v).as_matrix(), atol=TOL)


def test_log_rows_equal_the_array_version_and_invert_exp(rng):
    for v in _axis_angle_cases(rng):
        r = exp_so3(v)
        w = log_so3_rows(_rows(r))
        assert isinstance(w, tuple) and all(type(x) is float for x in w)
        np.testing.assert_array_equal(np.array(w), log_so3(r))
        np.testing.assert_allclose(exp_so3(np.array(w)), r, atol=1e-7)
        angle = np.linalg.norm(v)
        if angle < np.pi - 1e-3:  # away from π the rotation vector itself is unique
            np.testing.assert_allclose(np.array(w), v, atol=1e-9)
        else:
            assert np.linalg.norm(w) == pytest.approx(angle, abs=1e-6)


def test_log_rows_of_an_unnormalised_matrix_clamps_like_the_array_version():
    # trace slightly above 3 and below −1 (round-off in a product of rotations): cos is clamped to [−1, 1]
    for m in (np.eye(3) * (1.0 + 1e-12), np.diag([1.0, -1.0, -1.0]) * (1.0 + 1e-12)):
        np.testing.assert_array_equal(np.array(log_so3_rows(_rows(m))), log_so3(m))
        assert np.isfinite(log_so3(m)).all()


def test_matmul_rows_match_numpy(rng):
    for _ in range(20):
        a, b = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
        np.testing.assert_allclose(np.array(matmul3_rows(_rows(a), _rows(b))), a @ b, rtol=0, atol=1e-14)
        np.testing.assert_allclose(np.array(matmul3_tn_rows(_rows(a), _rows(b))), a.T @ b, rtol=0, atol=1e-14)
        np.testing.assert_allclose(np.array(matmul3_tn_rows(a.tolist(), b.tolist())), a.T @ b, rtol=0, atol=1e-14)
        np.testing.assert_allclose(np.array(matmul3_nt_rows(_rows(a), _rows(b))), a @ b.T, rtol=0, atol=1e-14)


def test_rotation_error_rows_match_the_array_version(rng):
    for v in _axis_angle_cases(rng):
        rd = exp_so3(rng.normal(size=3))
        r = exp_so3(v) @ rd
        np.testing.assert_allclose(np.array(rotation_error_world_rows(r.tolist(), rd.tolist())),
                                   rotation_error_world(r, rd), atol=1e-12 if np.linalg.norm(v) < 3.1 else 1e-6)
