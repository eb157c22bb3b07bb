"""Dirt: Preston's law removal under the pad, only where the tool touched, faster with more force."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.errors import ConfigError, InputError
from tactex.pointcloud.shapes import SURFACES, HeightFieldSurface
from tactex.robots import MujocoBackend
from tactex.sim import DirtField, PrestonParams, SceneConfig
from tactex.sim.testing import SimpleImpedance

DOWN = np.diag([1.0, -1.0, -1.0])


def _field(coefficient=1e-3, threshold=2.0, radius=0.02):
    return DirtField(SURFACES["plane"], "full", 0.002, PrestonParams(coefficient, threshold, radius))


def test_wipe_follows_prestons_law_inside_the_footprint_only():
    field = _field()
    centre = np.array([0.03, -0.02, 0.0])
    n = field.wipe(centre, normal_force_n=10.0, slip_speed_m_s=0.05, dt_s=0.01)
    removed = field.initial - field.level
    inside = np.linalg.norm(field.points - centre, axis=1) <= 0.02
    assert n == inside.sum() > 0
    expected = 1e-3 * 10.0 / (np.pi * 0.02**2) * 0.05 * 0.01
    np.testing.assert_allclose(removed[inside], expected, rtol=1e-12)
    assert np.all(removed[~inside] == 0.0)


@pytest.mark.parametrize("name", ["sine_panel", "bowl", "cup"])
def test_footprint_is_the_pad_ball_on_curved_surfaces(name):
    # the window search (separable on height fields, per coordinate on the cup) removes dirt from
    # exactly the cells within the pad radius of the contact point, in 3-D
    surface = SURFACES[name]
    field = DirtField(surface, "full", 0.002, PrestonParams(1e-3, 2.0, 0.02))
    # on a height field, where it is steepest: there the 3-D ball differs most from a vertical cylinder
    pts = field.points[field.initial > 0]
    if isinstance(surface, HeightFieldSurface):
        pts = pts[np.abs(pts[:, :2]).max(axis=1) < 0.06]  # the whole footprint on the surface
        gx, gy = surface.gradient(pts[:, 0], pts[:, 1])
        centre = pts[np.argmax(np.hypot(gx, gy))]
    else:
        centre = pts[len(pts) // 2]
    centre = centre + 0.0007  # off the cell centres
    n = field.wipe(centre, normal_force_n=10.0, slip_speed_m_s=0.05, dt_s=0.01)
    inside = (np.linalg.norm(field.points - centre, axis=1) <= 0.02) & (field.initial > 0)
    removed = field.initial - field.level
    assert n > 100
    assert np.all(removed[inside] > 0) and np.all(removed[~inside] == 0.0)


def test_removal_is_linear_in_force_and_speed_and_has_a_threshold():
    removed = {}
    for f, v in ((5.0, 0.05), (10.0, 0.05), (10.0, 0.1), (1.5, 0.05), (10.0, 0.0)):
        field = _field()
        field.wipe(np.zeros(3), f, v, 0.01)
        removed[(f, v)] = field.total_initial - field.level.sum()
    assert removed[(10.0, 0.05)] == pytest.approx(2 * removed[(5.0, 0.05)], rel=1e-9)
    assert removed[(10.0, 0.1)] == pytest.approx(2 * removed[(10.0, 0.05)], rel=1e-9)
    assert removed[(1.5, 0.05)] == 0.0  # below the 2 N threshold
    assert removed[(10.0, 0.0)] == 0.0  # no sliding, no wear


def test_levels_saturate_at_zero_and_reset():
    field = _field(coefficient=10.0)
    field.wipe(np.zeros(3), 15.0, 0.1, 0.1)
    assert field.level.min() == 0.0
    assert 0.0 < field.remaining_fraction() < 1.0
    field.reset()
    assert field.remaining_fraction() == 1.0


def test_marking_and_colours():
    field = DirtField(SURFACES["plane"], "X", 0.002)
    assert 0 < field.total_initial < field.level.size
    centre_cell = field.level_at(np.array([[0.0, 0.0, 0.0]]))  # the X crosses the centre
    corner_cell = field.level_at(np.array([[0.14, -0.14, 0.0]]))
    assert centre_cell[0] == 1.0 and corner_cell[0] == 0.0
    rgb = field.colors(np.array([[0.0, 0.0, 0.0], [0.14, -0.14, 0.0]]))
    np.testing.assert_allclose(rgb[0], [1.0, 0.0, 0.0])
    assert rgb[1, 1] > 0.5


def test_disc_domains_have_no_dirt_outside():
    field = DirtField(SURFACES["plate"], "full", 0.004)
    outside = np.hypot(field.points[:, 0], field.points[:, 1]) > 0.13 + 1e-9
    assert outside.any() and np.all(field.initial[outside] == 0.0)


def test_cylinder_cells_lie_on_the_wall():
    cup = SURFACES["cup"]
    field = DirtField(cup, "X", 0.003)
    np.testing.assert_allclose(np.hypot(field.points[:, 0], field.points[:, 1]), cup.radius_m)
    np.testing.assert_allclose(cup.uv(field.points), field.uv, atol=1e-9)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"coefficient": -1.0}, "Preston coefficient"),
        ({"force_threshold_n": float("nan")}, "threshold"),
        ({"pad_radius_m": 0.0}, "pad radius"),
    ],
)
def test_preston_params_are_validated(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        PrestonParams(**kwargs)


def test_dirt_field_inputs_are_validated():
    with pytest.raises(ConfigError, match="resolution"):
        DirtField(SURFACES["plane"], "X", 1.0)
    with pytest.raises(ConfigError, match="marking"):
        DirtField(SURFACES["plane"], "nope", 0.002)
    with pytest.raises(InputError, match="surface type"):
        DirtField(object(), "X", 0.002)  # type: ignore[arg-type]


def _wipe_line(force_n, coefficient=2e-4, seconds=1.6, sample_ticks=5):
    """Press with force_n on the plane and slide 8 cm along +x; returns backend and contact path."""
    backend = MujocoBackend(SceneConfig(object_name="plane", marking="full", preston_coefficient=coefficient,
                                        contact_sample_ticks=sample_ticks))
    pos, rot = backend.object_pose()
    start = pos + np.array([-0.04, 0.0, 0.003])
    backend.reset(seed=0, q0=backend.solve_ik(start, DOWN))
    ctrl = SimpleImpedance(free_axes=(2,))
    ff = np.array([0.0, 0.0, -force_n, 0.0, 0.0, 0.0])
    path = []
    steps = int(seconds / backend.dt)
    for i in range(steps):
        s = backend.state()
        target = start + np.array([0.08 * min(1.0, max(0.0, (i - 300) / (steps - 500))), 0.0, 0.0])
        backend.apply_torque(ctrl.torque(s, target, DOWN, ff))
        backend.step()
        force, point = backend.pad_contact()
        if point is not None and force > backend.config.dirt_force_threshold_n:
            path.append((point - pos) @ rot)
    return backend, np.array(path)


@pytest.mark.slow
def test_dirt_disappears_only_along_the_touched_path_and_faster_with_force():
    removed = {}
    for force in (5.0, 15.0):
        backend, path = _wipe_line(force)
        field = backend.dirt
        touched = field.level < field.initial
        assert touched.sum() > 100
        dist = np.min(np.linalg.norm(field.points[:, None, :2] - path[None, ::10, :2], axis=2), axis=1)
        radius = backend.config.tool_pad_radius_m
        assert dist[touched].max() <= radius + 0.003  # nothing cleaned away from the pad's path
        assert np.all(~touched[dist > radius + 0.003])
        # and everything well under the pad while it slid was cleaned
        x = field.points[:, 0]
        under = (dist < radius - 0.005) & (x > path[:, 0].min() + 0.01) & (x < path[:, 0].max() - 0.01)
        assert under.sum() > 100 and np.all(touched[under])
        removed[force] = field.total_initial - field.level.sum()
    assert removed[15.0] == pytest.approx(3.0 * removed[5.0], rel=0.25)


@pytest.mark.slow
def test_sampling_contacts_every_few_ticks_removes_the_same_dirt():
    removed = []
    for ticks in (1, 5):
        backend, _ = _wipe_line(15.0, sample_ticks=ticks)
        removed.append(backend.dirt.total_initial - backend.dirt.level.sum())
    assert removed[1] == pytest.approx(removed[0], rel=0.03)
