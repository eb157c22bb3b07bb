"""Ray-cast wrist camera: depth geometry, pose, colour from dirt, frame rate, noise."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.robots import MujocoBackend
from tactex.sim import SceneConfig
from tactex.sim.objects import rotation_from_rpy_deg

DEPTH_TOL_M = 1e-3
NEWTON_TOL_M = 1e-5  # the ray caster's default step tolerance [m]
DOWN = np.diag([1.0, -1.0, -1.0])


def _look_down(backend, height=0.15, dx=0.0, dy=0.0):
    """Reset with the TCP pointing down at (dx, dy, height) [m] from the object's origin."""
    pos, _ = backend.object_pose()
    q = backend.solve_ik(pos + np.array([dx, dy, height]), DOWN)
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


@pytest.mark.parametrize("method", ["analytic", "mujoco"])
@pytest.mark.parametrize("name", ["plane", "tilted_plane"])
def test_depth_of_a_known_plane_is_exact(name, method):
    backend = MujocoBackend(SceneConfig(object_name=name, camera_raycast=method))
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


@pytest.mark.parametrize("latency", [0.0, 0.02, 1 / 30])
def test_camera_frame_rate_and_latency(latency):
    cfg = SceneConfig(object_name="plane", camera_width=16, camera_height=12, camera_rate_hz=30.0,
                      camera_latency_s=latency)
    backend = MujocoBackend(cfg)
    frames = []
    for _ in range(1040):
        f = backend.camera_frame()
        if f is not None and f.timestamp < 1.0 - 1e-9:
            frames.append((backend.time, f.timestamp))
        backend.step()
    delivered, exposed = np.array(frames).T
    assert len(frames) == 30  # exposures in the first second at 30 Hz
    assert np.diff(exposed).max() < 1 / 30 + 1e-3 and exposed[0] == 0.0
    np.testing.assert_allclose(delivered - exposed, latency, atol=1.01e-3)


def test_delayed_frames_equal_immediate_ones():
    # a delayed frame is the one exposed earlier: identical to an immediate capture at that time
    cfgs = [SceneConfig(object_name="bowl", camera_width=40, camera_height=30, depth_noise_m=0.001,
                        camera_latency_s=lat) for lat in (0.0, 1 / 30)]
    runs = []
    for cfg in cfgs:
        backend = MujocoBackend(cfg)
        out = []
        for i in range(200):
            backend.apply_torque(np.full(7, 0.3 * np.sin(i / 50)))
            f = backend.camera_frame()
            if f is not None:
                out.append(f)
            backend.step()
        runs.append(out)
    for a, b in zip(runs[0], runs[1], strict=False):
        assert a.timestamp == b.timestamp
        np.testing.assert_array_equal(a.depth_m, b.depth_m)
        np.testing.assert_array_equal(a.rgb, b.rgb)


def test_camera_latency_is_validated():
    from tactex.errors import ConfigError

    with pytest.raises(ConfigError, match="camera_latency_s"):
        SceneConfig(camera_latency_s=0.5)


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


@pytest.mark.parametrize("name", ["plane", "tilted_plane", "sine_panel", "plate", "bowl", "cup", "bumps"])
def test_analytic_and_mujoco_ray_casting_agree(name):
    backend = MujocoBackend(SceneConfig(object_name=name, camera_width=80, camera_height=60))
    pos, _ = backend.object_pose()
    view = pos + np.array([0.0, -0.05, 0.2]) if name != "cup" else pos + np.array([0.0, -0.25, 0.06])
    rot = DOWN if name != "cup" else np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    backend.reset(seed=0, q0=backend.solve_ik(view, rot))
    backend.camera.method = "analytic"
    a = backend.render_depth()
    backend.camera.method = "mujoco"
    m = backend.render_depth()
    both = (a.depth_m > 0) & (m.depth_m > 0)
    assert both.mean() > 0.9 * max((a.depth_m > 0).mean(), (m.depth_m > 0).mean())
    err = np.abs(a.depth_m[both] - m.depth_m[both])
    # identical up to the height-field interpolation (bilinear vs triangles), which matters only on
    # the silhouette of a steep rim (under 2 % of the pixels)
    assert np.quantile(err, 0.98) < DEPTH_TOL_M
    assert np.median(err) < 1e-4
    assert np.mean(np.all(a.rgb == m.rgb, axis=-1)[both]) > 0.97


@pytest.mark.parametrize("roll_deg", [70.0, 100.0])
def test_height_field_seen_edge_on_and_through_its_side_walls(roll_deg):
    # a panel rolled towards the camera: rays enter its box through the sides (at 100° also through
    # the solid's side walls), not only through the top face
    backend = MujocoBackend(SceneConfig(object_name="sine_panel", camera_width=80, camera_height=60))
    pos, _ = backend.object_pose()
    backend.reset(seed=0, q0=backend.solve_ik(pos + np.array([0.0, 0.0, 0.25]), DOWN))
    backend.move_object("object", pos + np.array([0.0, 0.0, 0.05]), rotation_from_rpy_deg((roll_deg, 0.0, 0.0)))
    cam = backend.camera
    world_T_cam, obj_pos, obj_rot = cam.snapshot(backend.data, backend.scene.ids["object_body"])
    origin = (world_T_cam[:3, 3] - obj_pos) @ obj_rot
    _, wall = cam.caster.hit_hfield(origin, cam._directions(obj_rot.T @ world_T_cam[:3, :3], 0, 60))
    assert wall.any() == (roll_deg > 90.0)
    a = backend.render_depth()
    cam.method = "mujoco"
    m = backend.render_depth()
    both = (a.depth_m > 0) & (m.depth_m > 0)
    assert both.mean() > 0.8 and np.array_equal(a.depth_m > 0, m.depth_m > 0)
    err = np.abs(a.depth_m[both] - m.depth_m[both])
    assert np.quantile(err, 0.98) < DEPTH_TOL_M and np.median(err) < 1e-4


def test_frames_cast_in_several_chunks_equal_one_chunk(monkeypatch):
    import tactex.sim.camera as camera_module

    def frame():
        backend = MujocoBackend(SceneConfig(object_name="bumps", camera_width=80, camera_height=60))
        _look_down(backend, 0.2)
        return backend.render_depth()

    whole = frame()
    monkeypatch.setattr(camera_module, "CHUNK_RAYS", 700)  # 8 chunks of 7 or 8 rows
    chunked = frame()
    assert (whole.depth_m > 0).mean() > 0.9
    np.testing.assert_allclose(chunked.depth_m, whole.depth_m, atol=NEWTON_TOL_M)
    assert np.mean(np.all(chunked.rgb == whole.rgb, axis=-1)) > 0.999


@pytest.mark.parametrize("name", ["bowl", "plate"])
def test_height_field_depths_converge_also_on_rims(name):
    # Newton runs per ray until its step is below the tolerance: steep rims too are converged (two
    # fixed iterations left some rim pixels millimetres off); the same with wide cell indices
    backend = MujocoBackend(SceneConfig(object_name=name, camera_width=80, camera_height=60))
    _look_down(backend, 0.15, dx=0.03, dy=-0.06)
    caster = backend.camera.caster
    depth = backend.render_depth().depth_m
    caster.iterations, caster.tolerance = 40, np.float32(0.0)  # iterate to round-off
    converged = backend.render_depth().depth_m
    caster.iterations, caster.tolerance = 8, np.float32(NEWTON_TOL_M)
    caster._wide = True  # float64 cell indices (grids of more than 2²⁴ cells)
    wide = backend.render_depth().depth_m
    assert (depth > 0).mean() > 0.9
    assert np.abs(depth - converged).max() < 1e-6
    np.testing.assert_array_equal(wide, depth)


@pytest.mark.parametrize("name", ["bowl", "bumps"])
def test_height_field_march_on_the_unbracketed_rays_only_changes_nothing(name):
    # the bracketing march samples only the rays it has not bracketed yet once they are few: never
    # gathering them (0), the default, and gathering them after every sample that brackets any (1)
    # give the same bits
    backend = MujocoBackend(SceneConfig(object_name=name, camera_width=80, camera_height=60))
    _look_down(backend, 0.15, dx=0.03, dy=-0.06)
    caster = backend.camera.caster
    frames = []
    for below in (0.0, caster.march_gather_below, 1.0):
        caster.march_gather_below = below
        frames.append(backend.render_depth())
    assert (frames[0].depth_m > 0).mean() > 0.9
    for f in frames[1:]:
        np.testing.assert_array_equal(f.depth_m, frames[0].depth_m)
        np.testing.assert_array_equal(f.rgb, frames[0].rgb)
