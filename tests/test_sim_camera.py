"""Ray-cast wrist camera: depth geometry, pose, colour from dirt, frame rate, noise."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.robots import MujocoBackend
from tactex.sim import SceneConfig

DEPTH_TOL_M = 1e-3
DOWN = np.diag([1.0, -1.0, -1.0])


def _look_down(backend, height=0.15):
    pos, _ = backend.object_pose()
    q = backend.solve_ik(pos + np.array([0.0, 0.0, height]), DOWN)
    backend.reset(seed=0, q0=q)


def _plane_depth(frame, p0, n):
    """Analytic depth of the plane through p0 with normal n, per pixel (NaN where parallel)."""
    k = frame.intrinsics
    u, v = np.meshgrid(np.arange(k.width), np.arange(k.height))
    d_opt = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u, dtype=float)], axis=-1)
    rot, c = frame.world_T_camera[:3, :3], frame.world_T_camera[:3, 3]
    d_world = d_opt @ rot.T
    t = (n @ (p0 - c)) / (d_world @ n)
    return t, c + d_world * t[..., None]


@pytest.mark.parametrize("name", ["plane", "tilted_plane"])
def test_depth_of_a_known_plane_is_exact(name):
    backend = MujocoBackend(SceneConfig(object_name=name))
    _look_down(backend)
    frame = backend.render_depth()
    pos, rot = backend.object_pose()
    depth_true, hit = _plane_depth(frame, pos, rot[:, 2])
    local = (hit - pos) @ rot
    surf = backend.scene.sim_object.surface
    inside = (np.abs(local[..., 0]) < surf.size_x_m / 2 - 0.005) & (np.abs(local[..., 1]) < surf.size_y_m / 2 - 0.005)
    assert inside.sum() > 1000
    err = np.abs(frame.depth_m[inside] - depth_true[inside])
    assert frame.depth_m[inside].min() > 0
    assert err.max() < DEPTH_TOL_M
    # pixels beyond the object see the table top (z = 0)
    table_t, table_hit = _plane_depth(frame, np.zeros(3), np.array([0.0, 0.0, 1.0]))
    local_t = (table_hit - pos) @ rot
    half = np.array([surf.size_x_m, surf.size_y_m]) / 2 + 0.03
    outside = (np.abs(local_t[..., 0]) > half[0]) | (np.abs(local_t[..., 1]) > half[1])
    if name == "plane":
        outside &= frame.depth_m > 0
        assert outside.sum() > 100
        assert np.abs(frame.depth_m[outside] - table_t[outside]).max() < DEPTH_TOL_M


def test_camera_pose_and_intrinsics():
    cfg = SceneConfig(object_name="plane", camera_width=64, camera_height=48)
    backend = MujocoBackend(cfg)
    frame = backend.render_depth()
    assert frame.depth_m.shape == (48, 64) and frame.rgb.shape == (48, 64, 3) and frame.rgb.dtype == np.uint8
    assert frame.intrinsics == cfg.intrinsics
    rot = frame.world_T_camera[:3, :3]
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-9)
    # VA-UFIC: the optical axis is aligned with the tool z axis
    np.testing.assert_allclose(rot[:, 2], backend.state().ee_rotation[:, 2], atol=1e-9)
    assert frame.timestamp == pytest.approx(0.0)


def test_colour_shows_the_dirt_and_its_removal():
    backend = MujocoBackend(SceneConfig(object_name="plane", marking="blobs"))
    _look_down(backend, 0.25)
    red = lambda f: (f.rgb[..., 0] > 200) & (f.rgb[..., 1] < 60) & (f.depth_m > 0)  # noqa: E731
    before = red(backend.render_depth())
    assert before.sum() > 50
    backend.dirt.level[:] = 0.0
    assert red(backend.render_depth()).sum() == 0


def test_colour_matches_the_marking_geometry():
    backend = MujocoBackend(SceneConfig(object_name="plane", marking="blobs"))
    _look_down(backend, 0.25)
    frame = backend.render_depth()
    pos, rot = backend.object_pose()
    _, hit = _plane_depth(frame, pos, rot[:, 2])
    local = (hit - pos) @ rot
    on = (frame.depth_m > 0) & (np.abs(local[..., 0]) < 0.14) & (np.abs(local[..., 1]) < 0.14)
    expected = backend.dirt.level_at(local[on]) > 0.5
    seen = frame.rgb[on][:, 1] < 60
    assert np.mean(expected == seen) > 0.98  # disagreement only on cell borders


def test_camera_frame_rate():
    backend = MujocoBackend(SceneConfig(object_name="plane", camera_width=16, camera_height=12, camera_rate_hz=30.0))
    frames = []
    for _ in range(1000):
        f = backend.camera_frame()
        if f is not None:
            frames.append(f.timestamp)
        backend.step()
    assert len(frames) == 30
    assert np.diff(frames).max() < 1 / 30 + 1e-3


def test_depth_noise_scales_with_depth_squared():
    sigma = 0.002
    clean = MujocoBackend(SceneConfig(object_name="plane"))
    noisy = MujocoBackend(SceneConfig(object_name="plane", depth_noise_m=sigma, seed=1))
    _look_down(clean)
    _look_down(noisy)
    a, b = clean.render_depth().depth_m, noisy.render_depth().depth_m
    both = (a > 0) & (b > 0)
    rel = (b[both] - a[both]) / a[both] ** 2
    assert abs(rel.mean()) < 0.1 * sigma
    assert rel.std() == pytest.approx(sigma, rel=0.1)
