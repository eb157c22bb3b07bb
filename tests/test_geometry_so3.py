"""SO(3) closed forms against scipy, and the eq. 29 interpolation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tactex.geometry import exp_so3, interpolate_rotation, log_so3, orthonormalize, rotation_error_world

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
