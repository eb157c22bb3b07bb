"""Object registry: every object smoke-runs; height fields match the shared analytic surfaces."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from tactex.errors import ConfigError, InputError
from tactex.pointcloud.shapes import HeightFieldSurface
from tactex.robots import MujocoBackend
from tactex.sim import SceneConfig, SimObject, get_object, heightfield_from_image, heightfield_object, object_names
from tactex.sim.objects import OBJECTS, register_object
from tactex.sim.testing import SimpleImpedance

HFIELD_TOL_M = 5e-4  # linear interpolation of a 3 mm grid on these curvatures


@pytest.mark.parametrize("name", object_names())
def test_every_registered_object_smoke_runs(name):
    backend = MujocoBackend(SceneConfig(object_name=name, camera_width=32, camera_height=24))
    s0 = backend.reset(seed=0)
    hold = SimpleImpedance()
    for _ in range(1000):
        backend.apply_torque(hold.torque(backend.state(), s0.ee_position, s0.ee_rotation))
        s = backend.step()
    assert s.is_finite() and s.t == pytest.approx(1.0)
    frame = backend.render_depth()
    assert np.isfinite(frame.depth_m).all() and (frame.depth_m > 0).any()
    assert 0.0 <= backend.dirt_remaining() <= 1.0


def _ray_heights(backend, xy_obj):
    """Surface heights (object frame) under object-frame points xy by vertical ray casting."""
    m, d = backend.model, backend.data
    pos, rot = backend.object_pose()
    out = []
    gid = np.zeros(1, dtype=np.int32)
    for x, y in xy_obj:
        start = pos + rot @ np.array([x, y, 0.5])
        dist = mujoco.mj_ray(m, d, start, -rot[:, 2], np.array([1, 0, 0, 0, 0, 0], np.uint8), 1, -1, gid)
        assert gid[0] == backend.scene.ids["object_geom"]
        out.append(0.5 - dist)
    return np.array(out)


@pytest.mark.parametrize("name", ["sine_panel", "plate", "bowl", "bumps"])
def test_height_field_matches_surface_height(name):
    backend = MujocoBackend(SceneConfig(object_name=name, camera_width=8, camera_height=8))
    surf = backend.scene.sim_object.surface
    assert isinstance(surf, HeightFieldSurface)
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.45, 0.45, (60, 2)) * [surf.size_x_m, surf.size_y_m]
    xy = xy[surf.inside(xy[:, 0], xy[:, 1])]
    if surf.radius_m is not None:
        xy = xy[np.hypot(xy[:, 0], xy[:, 1]) < surf.radius_m - 0.01]
    np.testing.assert_allclose(_ray_heights(backend, xy), surf.height(xy[:, 0], xy[:, 1]), atol=HFIELD_TOL_M)


def test_cup_wall_radius():
    backend = MujocoBackend(SceneConfig(object_name="cup", camera_width=8, camera_height=8))
    surf = backend.scene.sim_object.surface
    pos, _ = backend.object_pose()
    gid = np.zeros(1, dtype=np.int32)
    for z in (0.02, 0.05, 0.09):
        start = pos + np.array([0.0, -0.3, z])
        dist = mujoco.mj_ray(backend.model, backend.data, start, np.array([0.0, 1.0, 0.0]),
                             np.array([1, 0, 0, 0, 0, 0], np.uint8), 1, -1, gid)
        assert 0.3 - dist == pytest.approx(surf.radius_m, abs=1e-9)


def test_objects_are_placed_where_the_registry_puts_them_unless_told():
    """The cup's marked wall sits well inside the arm's reach (0.42 m out), the others at 0.5 m; an
    explicit position wins, in the scene, in a task's config and on the command line."""
    from tactex.config import add_dataclass_arguments, dataclass_from_args
    from tactex.tasks.clean import CleanConfig

    assert SceneConfig(object_name="cup").object_position == (0.42, 0.0, 0.0)
    assert SceneConfig(object_name="plate").object_position == (0.5, 0.0, 0.0)
    pos, _ = MujocoBackend(SceneConfig(object_name="cup", camera_width=8, camera_height=8)).object_pose()
    np.testing.assert_allclose(pos, [0.42, 0.0, 0.0])
    assert CleanConfig(object_name="cup").scene().object_position == (0.42, 0.0, 0.0)
    assert CleanConfig(object_name="cup", object_position=(0.5, 0.1, 0.0)).scene().object_position == (0.5, 0.1, 0.0)
    import argparse

    parser = argparse.ArgumentParser()
    add_dataclass_arguments(parser, CleanConfig)
    cfg = dataclass_from_args(CleanConfig, parser.parse_args(["--object", "cup", "--object-position", "0.5", "0", "0"]))
    assert cfg.scene().object_position == (0.5, 0.0, 0.0)
    cfg = dataclass_from_args(CleanConfig, parser.parse_args(["--object", "cup"]))
    assert cfg.scene().object_position == (0.42, 0.0, 0.0)
    with pytest.raises(ConfigError, match="object_position must be 3 finite numbers"):
        SceneConfig(object_name="cup", object_position=(0.5, float("nan"), 0.0))
    with pytest.raises(ConfigError, match="position_m must be 3 finite numbers"):
        register_object(SimObject("far", get_object("plate").surface, position_m=(0.5, 0.0)))  # type: ignore[arg-type]
    assert "far" not in object_names()


def test_heightfield_from_image_orientation():
    img = np.zeros((20, 30))
    img[:5, 20:] = 1.0  # top-right of the image: +y, +x corner
    obj = heightfield_from_image("img", img, 0.3, 0.2, 0.02)
    h = obj.surface.height
    assert h(np.array([0.14]), np.array([0.095]))[0] == pytest.approx(0.02)
    assert h(np.array([-0.14]), np.array([-0.095]))[0] == pytest.approx(0.0)
    with pytest.raises(InputError, match="2-D"):
        heightfield_from_image("bad", np.zeros(5), 0.3, 0.2, 0.02)
    with pytest.raises(ConfigError, match="max_height_m"):
        heightfield_from_image("bad", img, 0.3, 0.2, -1.0)


def test_registry_add_and_errors():
    obj = heightfield_object("ramp_test", lambda x, y: 0.05 * (np.asarray(x) + 0.1), 0.2, 0.2)
    try:
        register_object(obj)
        assert "ramp_test" in object_names()
        backend = MujocoBackend(SceneConfig(object_name="ramp_test", camera_width=8, camera_height=8))
        xy = np.array([[-0.05, 0.0], [0.05, 0.03]])
        np.testing.assert_allclose(_ray_heights(backend, xy), 0.05 * (xy[:, 0] + 0.1), atol=1e-6)
        with pytest.raises(ConfigError, match="already registered"):
            register_object(obj)
    finally:
        OBJECTS.pop("ramp_test", None)
    with pytest.raises(ConfigError, match=r"unknown object 'nope'.*plate"):
        get_object("nope")
    with pytest.raises(InputError, match="SimObject"):
        register_object("plate")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="size_x_m"):
        heightfield_object("big", lambda x, y: 0 * x, 50.0, 0.2)
    with pytest.raises(InputError, match="vectorised"):
        heightfield_object("scalar", lambda x, y: 0.0, 0.2, 0.2)


def test_scene_config_validation():
    with pytest.raises(ConfigError, match="unknown object"):
        SceneConfig(object_name="nope")
    with pytest.raises(ConfigError, match="marking"):
        SceneConfig(marking="Q")
    with pytest.raises(ConfigError, match="camera preset"):
        SceneConfig(camera_preset="kinect")
    with pytest.raises(ConfigError, match="tool_pad_shape"):
        SceneConfig(tool_pad_shape="cube")
    with pytest.raises(ConfigError, match="tool_stiffness_n_per_m"):
        SceneConfig(tool_stiffness_n_per_m=-5.0)
    with pytest.raises(ConfigError, match="tool_friction"):
        SceneConfig(tool_friction=float("nan"))
    with pytest.raises(ConfigError, match="camera size"):
        SceneConfig(camera_width=2)
    with pytest.raises(ConfigError, match="contact_sample_ticks"):
        SceneConfig(contact_sample_ticks=0)
    with pytest.raises(ConfigError, match="camera_raycast"):
        SceneConfig(camera_raycast="gl")
    with pytest.raises(ConfigError, match="ft_bias"):
        SceneConfig(ft_bias=(0.0, 1.0))  # type: ignore[arg-type]


def test_sim_object_rejects_unknown_surface_type():
    class Odd:
        pass

    with pytest.raises(ConfigError, match="no simulator geometry"):
        register_object(SimObject("odd", Odd()))  # type: ignore[arg-type]
