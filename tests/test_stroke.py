"""Straight strokes through small islands of dirt and slides in contact between islands (issue 21), and
the raster's lanes on a bent surface."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.spatial import cKDTree

from tactex.errors import ConfigError, InputError
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.tasks import raster
from tactex.tasks.clean import CleanConfig
from tactex.tasks.raster import WaypointPath, boustrophedon
from tactex.tasks.stroke import MAX_LINE_GAP_M, MAX_PASSES, STROKE_OVERRUN_RADII, plan_stroke, surface_line
from tactex.tasks.wear_model import WearModel

K_P, R, STEP = 5e-3, 0.025, 0.003


def _plane(target: np.ndarray | None = None, spacing: float = 0.003, half: float = 0.09) -> SurfaceCloud:
    g = np.arange(-half, half + 1e-9, spacing)
    x, y = np.meshgrid(g, g)
    pts = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    t = np.zeros(len(pts)) if target is None else target(pts)
    return SurfaceCloud(points=pts, normals=np.tile([0.0, 0.0, 1.0], (len(pts), 1)), target=t, spacing=spacing)


def _spot(centre: tuple[float, float], radius: float = 0.005):
    return lambda p: (np.linalg.norm(p[:, :2] - np.asarray(centre), axis=1) <= radius).astype(float)


def _wipe_along(wear: WearModel, waypoints: np.ndarray, force_n: float = 10.0) -> None:
    for a, b in itertools.pairwise(waypoints):
        wear.wipe(0.5 * (a + b), force_n * float(np.linalg.norm(b - a)))


def test_surface_line_stays_on_the_cloud_and_measures_its_gap() -> None:
    cloud = _plane()
    tree = cKDTree(cloud.points)
    line, gap = surface_line(cloud, tree, np.array([-0.06, 0.0, 0.0]), np.array([0.06, 0.03, 0.0]), STEP)
    assert gap <= cloud.spacing  # on a plane the chord is the surface: a sample is at most a voxel from a point
    assert np.all(np.linalg.norm(np.diff(line, axis=0), axis=1) > 0)  # no repeated waypoints
    assert np.allclose(line[0], [-0.06, 0.0, 0.0]) and np.allclose(line[-1], [0.06, 0.03, 0.0])
    # across a hollow (two plates 4 cm apart in height) the chord leaves the surface
    low = cloud.points[cloud.points[:, 0] < 0]
    high = cloud.points[cloud.points[:, 0] >= 0] + [0.0, 0.0, 0.04]
    step_cloud = SurfaceCloud(points=np.vstack([low, high]), normals=np.tile([0.0, 0.0, 1.0], (len(cloud), 1)),
                              target=np.zeros(len(cloud)), spacing=cloud.spacing)
    _, gap = surface_line(step_cloud, cKDTree(step_cloud.points), low[0], high[-1], STEP)
    assert gap > MAX_LINE_GAP_M


def test_a_small_island_gets_a_stroke_through_its_centre_that_cleans_it() -> None:
    cloud = _plane(_spot((0.02, 0.01)))
    tree = cKDTree(cloud.points)
    wear = WearModel(cloud, K_P, R, margin=1.5)
    stroke = plan_stroke(cloud, tree, wear, np.array([0.02, 0.01, 0.0]), np.array([-0.05, 0.01, 0.0]), R, STEP)
    assert stroke is not None and not stroke.transfer_only and not stroke.transfer
    assert stroke.path.tree is tree  # planned in contact: the path reads the given tree, builds none
    assert set(stroke.island) == set(np.flatnonzero(cloud.target > 0))
    # along the direction from where the robot comes (x here), half a pad radius plus the spot's radius each side
    assert stroke.a[0] < stroke.b[0] and np.allclose([stroke.a[1], stroke.b[1]], 0.01, atol=cloud.spacing)
    assert np.linalg.norm(stroke.b - stroke.a) == pytest.approx(2 * (STROKE_OVERRUN_RADII * R + 0.005),
                                                                abs=2 * cloud.spacing)
    # back and forth until the model calls it clean: one pass keeps every spot point under the pad for 1.37 pad
    # radii or more, k_p·F/(π r²)·1.37 r < the margin 1.5; a second pass does it
    wiped = 0  # waypoints walked so far
    while True:
        _wipe_along(wear, stroke.path.waypoints[wiped:])
        wiped = len(stroke.path.waypoints) - 1
        if stroke.clean(wear) or not stroke.next_pass(STEP):
            break
        assert not stroke.wiped(wear)  # after the first pass: not yet
    assert stroke.clean(wear) and stroke.wiped(wear) and stroke.passes == 2
    assert not wear.island_left(np.array([0.02, 0.01, 0.0]), 2 * R)


def test_passes_are_bounded_and_reverse() -> None:
    cloud = _plane(_spot((0.0, 0.0)))
    wear = WearModel(cloud, K_P, R)
    stroke = plan_stroke(cloud, cKDTree(cloud.points), wear, np.zeros(3), np.array([-0.05, 0.0, 0.0]), R, STEP)
    a, b = stroke.a.copy(), stroke.b.copy()
    assert stroke.next_pass(STEP)
    assert np.allclose(stroke.a, b) and np.allclose(stroke.b, a)
    assert np.allclose(stroke.path.waypoints[-1], a)  # the second pass ends where the first began
    while stroke.next_pass(STEP):
        pass
    assert stroke.passes == MAX_PASSES


def test_a_large_island_is_left_to_the_explorer_or_reached_by_a_slide() -> None:
    cloud = _plane(lambda p: (np.abs(p[:, 1] - 0.03) <= 0.01).astype(float))  # a 2 cm wide stripe
    tree = cKDTree(cloud.points)
    wear = WearModel(cloud, K_P, R)
    island = np.array([0.0, 0.02, 0.0])
    assert plan_stroke(cloud, tree, wear, island, np.zeros(3), R, STEP) is None
    slide = plan_stroke(cloud, tree, wear, island, np.zeros(3), R, STEP, transfer_from_m=np.array([0.0, -0.05, 0.0]))
    assert slide is not None and slide.transfer_only and slide.transfer
    assert np.allclose(slide.path.waypoints[0], [0.0, -0.05, 0.0], atol=cloud.spacing)
    assert np.allclose(slide.path.waypoints[-1], island, atol=cloud.spacing)
    assert slide.clean(wear)  # nothing of its own to wipe: the explorer takes over where it ends
    assert not slide.wiped(wear)  # ... but only once it has slid there


def test_no_slide_across_a_hollow() -> None:
    cloud = _plane(_spot((0.06, 0.0)))
    pts = cloud.points.copy()
    pts[:, 2] = np.where(np.abs(pts[:, 0]) < 0.03, -0.03, 0.0)  # a 3 cm deep trench across the path
    cloud = SurfaceCloud(points=pts, normals=cloud.normals, target=cloud.target, spacing=cloud.spacing)
    wear = WearModel(cloud, K_P, R)
    here = np.array([-0.06, 0.0, 0.0])
    assert plan_stroke(cloud, cKDTree(pts), wear, np.array([0.06, 0.0, 0.0]), here, R, STEP,
                       transfer_from_m=here) is None
    assert plan_stroke(cloud, cKDTree(pts), wear, np.array([0.06, 0.0, 0.0]), here, R, STEP) is not None


def _half_cylinder(radius: float = 0.04, height: float = 0.10, spacing: float = 0.003) -> SurfaceCloud:
    n_arc = int(np.pi * radius / spacing)
    ang = np.linspace(-np.pi, 0.0, n_arc)
    z = np.arange(0.0, height + 1e-9, spacing)
    a, zz = np.meshgrid(ang, z)
    pts = np.column_stack([radius * np.cos(a.ravel()), radius * np.sin(a.ravel()), zz.ravel()])
    normals = np.column_stack([np.cos(a.ravel()), np.sin(a.ravel()), np.zeros(a.size)])
    return SurfaceCloud(points=pts, normals=normals, target=np.ones(len(pts)), spacing=spacing)


def _farthest_from_path(cloud: SurfaceCloud, path: np.ndarray) -> float:
    dense = np.vstack([a + np.linspace(0, 1, 20)[:, None] * (b - a) for a, b in itertools.pairwise(path)])
    return float(cKDTree(dense).query(cloud.points)[0].max())


def test_raster_lanes_hold_their_spacing_on_a_half_cylinder(monkeypatch) -> None:
    """On a cup's half cylinder, lanes spaced across its principal plane are farther apart on the surface
    towards the sides; run along the arc, spaced along the straight axis, every point is within half a
    lane spacing of the path."""
    cloud = _half_cylinder()
    spacing = 0.03
    assert _farthest_from_path(cloud, boustrophedon(cloud, spacing, 0.003)) <= 0.5 * spacing + cloud.spacing
    # lanes across the principal plane (the order before) leave strips on the sides
    monkeypatch.setattr(raster, "BEND_SWAP_RATIO", np.inf)
    assert _farthest_from_path(cloud, boustrophedon(cloud, spacing, 0.003)) > 0.5 * spacing + 2 * cloud.spacing


def test_lag_hold_and_boost_options_are_checked() -> None:
    with pytest.raises(ConfigError, match="--touch-down-boost-s"):
        CleanConfig(touch_down_boost_s=0.0)
    for name in ("max_lag_m", "hold_force_ratio", "touch_down_boost"):
        option = "--" + name.replace("_", "-")
        with pytest.raises(ConfigError, match=option):
            CleanConfig(**{name: -1.0})
        with pytest.raises(ConfigError, match=option):
            CleanConfig(**{name: float("nan")})
    # a pulse above the set point itself, and a hold at or below the set point (every contact would wait)
    with pytest.raises(ConfigError, match="--touch-down-boost"):
        CleanConfig(touch_down_boost=1.5)
    for ratio in (0.5, 1.0):
        with pytest.raises(ConfigError, match="--hold-force-ratio"):
            CleanConfig(hold_force_ratio=ratio)
    assert CleanConfig(hold_force_ratio=0.0, touch_down_boost=0.0).hold_force_ratio == 0.0  # both off


def test_a_waypoint_path_refuses_a_tree_of_another_cloud() -> None:
    cloud = _plane(_spot((0.02, 0.01)))
    with pytest.raises(InputError, match="KD-tree holds"):
        WaypointPath(cloud, cloud.points[:3], STEP, tree=cKDTree(cloud.points[:10]))
