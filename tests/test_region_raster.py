"""The region raster (plane slicer over the dirty region), its path follower and the physical bound on the
time to clean."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.ergodic.relocation import RelocationCommand
from tactex.errors import ConfigError, ExplorationError, InputError, TactexError
from tactex.pointcloud import SurfaceCloud, load_ply, target_from_channel, voxel_down_sample
from tactex.pointcloud.markings import marked_cloud
from tactex.pointcloud.shapes import get_surface
from tactex.tasks.ideal_time import dirty_area_m2, ideal_time_s, point_areas_m2
from tactex.tasks.raster import RasterPath
from tactex.tasks.region_raster import (
    WAYPOINT_LINE,
    WAYPOINT_SLIDE,
    WAYPOINT_TOUCH_DOWN,
    dirty_islands,
    path_distance,
    plan_region_raster,
    spacing_from_overlap,
)
from tactex.tasks.region_raster_path import RegionRasterPath

from .conftest import tec_cloud_path

H = 0.003  # [m] the plates' grid spacing
PAD_R = 0.025  # [m] pad radius
SPACING = 0.03  # [m] line spacing
#: The path's straight pieces are sampled at this step for the coverage check [m].
REACH_TOL = 1e-9


def plate(size_x: float = 0.36, size_y: float = 0.24) -> SurfaceCloud:
    """A flat 3 mm grid on z = 0 (normals +z), centred at the origin, no dirt."""
    u, v = np.meshgrid(np.arange(-size_x / 2, size_x / 2 + 1e-9, H), np.arange(-size_y / 2, size_y / 2 + 1e-9, H))
    pts = np.c_[u.ravel(), v.ravel(), np.zeros(u.size)]
    return SurfaceCloud(pts, normals=np.tile([0.0, 0.0, 1.0], (len(pts), 1)), spacing=H)


def with_squares(cloud: SurfaceCloud, centres: list[tuple[float, float]], side: float) -> SurfaceCloud:
    """The cloud with dirt (mass 1) on axis-aligned squares of ``side`` [m] at ``centres`` (x, y) [m]."""
    dirt = np.zeros(len(cloud), dtype=bool)
    for cx, cy in centres:
        dirt |= (np.abs(cloud.points[:, 0] - cx) <= side / 2) & (np.abs(cloud.points[:, 1] - cy) <= side / 2)
    return cloud.with_target(dirt.astype(float))


def segments_of(plan) -> list[np.ndarray]:
    """Each line segment's waypoints (m, 3), in walking order."""
    return [plan.waypoints[plan.segment == j] for j in range(int(plan.segment.max()) + 1)]


def covered(plan, cloud: SurfaceCloud, radius: float = PAD_R) -> np.ndarray:
    """Per dirty point, whether the path in contact passes within ``radius`` [m] of it."""
    return path_distance(plan.waypoints, cloud.points[cloud.target > 0], plan.kind) <= radius + REACH_TOL


TWO_SQUARES = [(-0.1, 0.0), (0.1, 0.0)]


def test_two_separated_squares_are_two_islands_rastered_at_the_asked_spacing() -> None:
    cloud = with_squares(plate(), TWO_SQUARES, 0.06)
    spacing = 0.02
    plan = plan_region_raster(cloud, PAD_R, spacing, gap_m=0.03)
    assert len(dirty_islands(cloud, PAD_R)) == 2 and len(plan.islands) == 2 and len(plan.directions) == 2
    for isl, t in zip(plan.islands, plan.directions, strict=True):
        d = np.cross([0.0, 0.0, 1.0], t)
        near = np.flatnonzero(np.linalg.norm(plan.waypoints[:, None, :2] - cloud.points[isl][None, :, :2],
                                             axis=2).min(axis=1) < 0.01)
        lines = plan.kind[near] == WAYPOINT_LINE
        offsets = np.unique(np.round(plan.waypoints[near[lines]] @ d, 6))
        extent = cloud.points[isl] @ d
        gaps = np.diff(offsets)
        assert np.all(gaps <= spacing + 1e-9) and np.all(gaps > 0.8 * spacing)  # as many lines as needed, no more
        assert offsets[0] - extent.min() <= spacing / 2 + 1e-9 and extent.max() - offsets[-1] <= spacing / 2 + 1e-9
    assert covered(plan, cloud).all()


def test_a_sliver_shorter_than_the_shortest_segment_is_left_out_and_counted() -> None:
    """A strip of dirt 1.2 cm long across the lines (a rim seen from outside) would be a segment shorter than the
    pad radius: dropped, like Noether's segments under min_segment_size, its points counted in ``uncovered``."""
    cloud = with_squares(plate(), [(-0.08, 0.0)], 0.06)
    sliver = (np.abs(cloud.points[:, 0] - 0.12) <= 0.006) & (np.abs(cloud.points[:, 1]) <= 0.003)
    cloud = cloud.with_target(np.maximum(cloud.target, sliver))
    plan = plan_region_raster(cloud, PAD_R, SPACING, gap_m=0.03, overrun_m=0.0)
    assert len(plan.islands) == 1 and plan.uncovered == int(sliver.sum())
    assert covered(plan, cloud)[~sliver[cloud.target > 0]].all()
    kept = plan_region_raster(cloud, PAD_R, SPACING, gap_m=0.03, overrun_m=0.0, min_segment_m=0.0)
    assert len(kept.islands) == 2 and kept.uncovered == 0 and covered(kept, cloud).all()
    # a cloud that is all slivers is rastered all the same
    alone = plate().with_target(sliver.astype(float))
    assert plan_region_raster(alone, PAD_R, SPACING, gap_m=0.03, overrun_m=0.0).uncovered == 0


def test_every_dirty_point_is_within_the_pad_radius_and_a_dropped_lane_shows() -> None:
    cloud = with_squares(plate(), [(0.0, 0.0)], 0.1)
    plan = plan_region_raster(cloud, PAD_R, SPACING, gap_m=0.05)
    assert covered(plan, cloud).all()
    # the check is sharp: without one inner segment some dirty point is out of the pad's reach
    longest = int(np.argmax([len(s) for s in segments_of(plan)]))
    inner = segments_of(plan)[longest]
    keep = plan.segment != longest
    dropped = plan._replace(waypoints=plan.waypoints[keep], kind=plan.kind[keep], segment=plan.segment[keep])
    assert len(inner) > 2 and not covered(dropped, cloud).all()


def test_a_rotated_rectangle_is_rastered_along_its_length_in_snake_order() -> None:
    base = plate()
    a = np.radians(30.0)
    axis = np.array([np.cos(a), np.sin(a), 0.0])
    across = np.array([-np.sin(a), np.cos(a), 0.0])
    p = base.points
    # 24 cm long, a little under two spacings wide: two lines along it, eight across
    dirt = (np.abs(p @ axis) <= 0.12) & (np.abs(p @ across) <= 0.95 * SPACING)
    cloud = base.with_target(dirt.astype(float))
    # the lines stop over the last dirt: the path is then the area's (with the default overrun of a pad radius
    # at each end of each line, 2 × 5 cm longer)
    plan = plan_region_raster(cloud, PAD_R, SPACING, gap_m=0.05, overrun_m=0.0)
    assert len(plan.directions) == 1 and abs(float(plan.directions[0] @ axis)) > np.cos(np.radians(1.0))
    principal_only = plan_region_raster(cloud, PAD_R, SPACING, gap_m=0.05, angle_step_deg=90.0, overrun_m=0.0)
    assert plan.surface_length_m <= principal_only.surface_length_m + 1e-12
    assert plan.turns == 1 and covered(plan, cloud).all()
    # snake order: each line walked the other way from the one before
    heading = [float((s[-1] - s[0]) @ plan.directions[0]) for s in segments_of(plan)]
    assert len(heading) == 2 and heading[0] * heading[1] < 0
    # the path is close to the area bound at this spacing (area / spacing)
    assert plan.surface_length_m <= 1.15 * dirty_area_m2(cloud) / SPACING


def test_the_lines_overrun_the_dirt_by_up_to_the_pad_radius_within_the_region() -> None:
    cloud = with_squares(plate(), [(0.0, 0.0)], 0.09)
    trimmed = plan_region_raster(cloud, PAD_R, SPACING, gap_m=0.05, overrun_m=0.0)
    default = plan_region_raster(cloud, PAD_R, SPACING, gap_m=0.05)
    assert default.surface_length_m == plan_region_raster(cloud, PAD_R, SPACING, 0.05, overrun_m=PAD_R).surface_length_m
    for overrun in (0.01, PAD_R, 2 * PAD_R):
        plan = plan_region_raster(cloud, PAD_R, SPACING, gap_m=0.05, overrun_m=overrun)
        longer = [len(b) - len(a) for a, b in zip(segments_of(trimmed), segments_of(plan), strict=True)]
        extent = [np.linalg.norm(s[-1] - s[0]) for s in segments_of(plan)]
        base = [np.linalg.norm(s[-1] - s[0]) for s in segments_of(trimmed)]
        # on, up to the region's edge a pad radius past the dirt (line points a spacing apart)
        assert np.allclose(np.subtract(extent, base), 2 * min(overrun, PAD_R), atol=H) and min(longer) > 0
        assert covered(plan, cloud).all()


def test_snake_order_on_many_lines() -> None:
    cloud = with_squares(plate(), [(0.0, 0.0)], 0.15)
    plan = plan_region_raster(cloud, PAD_R, SPACING, gap_m=0.05)
    t = plan.directions[0]
    heading = np.sign([float((s[-1] - s[0]) @ t) for s in segments_of(plan)])
    assert len(heading) >= 5 and np.all(heading[1:] == -heading[:-1])
    assert plan.turns == len(heading) - 1 and plan.lift_offs == 0
    assert np.all(plan.kind[1:][plan.segment[1:] == -1] == WAYPOINT_SLIDE)


def test_a_long_gap_is_a_lift_off_and_a_short_one_a_slide() -> None:
    cloud = with_squares(plate(), TWO_SQUARES, 0.06)
    far = plan_region_raster(cloud, PAD_R, SPACING, gap_m=0.03)
    assert far.lift_offs == 1 and far.air_length_m > 0.1 and np.count_nonzero(far.lift_off) == 2  # with the first
    near = plan_region_raster(cloud, PAD_R, SPACING, gap_m=0.5)
    assert near.lift_offs == 0 and near.air_length_m == 0.0
    assert near.surface_length_m > far.surface_length_m + 0.1  # the slide between the squares


def test_the_follower_walks_the_plan_and_flies_its_lift_offs() -> None:
    cloud = with_squares(plate(), TWO_SQUARES, 0.06)
    step = 0.002
    path = RegionRasterPath(cloud, PAD_R, SPACING, gap_m=0.03, max_step_m=step, start_m=np.array([-0.2, 0.0, 0.0]))
    cmd = path.reset(np.array([-0.2, 0.0, 0.0]))
    assert np.allclose(cmd.point, path.plan.waypoints[0]) and np.allclose(cmd.normal, [0.0, 0.0, 1.0])
    flights, last = [], cmd.point
    for _ in range(5000):
        if path.done:
            break
        cmd = path.step(None)
        if isinstance(cmd, RelocationCommand):
            flights.append(cmd)
        else:
            assert np.linalg.norm(cmd.point - last) <= step + 1e-12
        last = cmd.point
    assert path.done and len(flights) == path.plan.lift_offs == len(path.relocations) == 1
    assert flights[0].point[0] > 0 > flights[0].lift_off[0]  # from the left square to the right one
    # (the path length counts each step's displacement, a little less than the waypoints' polyline at its corners)
    assert path.path_length_m == pytest.approx(path.plan.surface_length_m, rel=0.01)
    assert path.air_path_length == pytest.approx(path.plan.air_length_m, rel=1e-9)
    assert np.allclose(last, path.plan.waypoints[-1])


def test_update_target_replans_over_only_what_is_left() -> None:
    cloud = with_squares(plate(), TWO_SQUARES, 0.06)
    path = RegionRasterPath(cloud, PAD_R, SPACING, gap_m=0.03, max_step_m=0.002, start_m=np.array([-0.2, 0.0, 0.0]))
    path.reset()
    for _ in range(20):
        path.step(None)
    here = path.step(None).point
    left = with_squares(cloud, [TWO_SQUARES[1]], 0.06)  # the right square only
    path.update_target(left.target)
    plan = path.plan
    assert len(plan.islands) == 1 and np.all(left.target[plan.islands[0]] > 0)
    assert np.allclose(plan.waypoints[0], here) and plan.kind[1] == WAYPOINT_TOUCH_DOWN  # it flies there
    assert np.all(plan.waypoints[plan.segment >= 0, 0] > 0.03)  # no line over the left square
    assert covered(plan, left).all()
    cmd = path.step(None)
    assert isinstance(cmd, RelocationCommand) and cmd.point[0] > 0
    path.update_target(np.zeros(len(cloud)))
    assert path.done and np.allclose(path.step(None).point, path._x)


@pytest.mark.parametrize(
    ("kwargs", "error", "words"),
    [
        ({"line_spacing_m": 0.0}, ConfigError, "line_spacing_m"),
        ({"line_spacing_m": 0.06}, ConfigError, "2 × pad radius"),
        ({"pad_radius_m": -0.01}, ConfigError, "pad_radius_m"),
        ({"gap_m": -1.0}, ConfigError, "gap_m"),
        ({"pad_radius_m": None}, ConfigError, "pad_radius_m must be a number"),
        ({"angle_step_deg": 0.0}, ConfigError, "angle_step_deg"),
        ({"angle_step_deg": 120.0}, ConfigError, "angle_step_deg"),
        ({"clearance_m": np.nan}, ConfigError, "clearance_m"),
        ({"link_factor": 0.0}, ConfigError, "link_factor"),
        ({"overrun_m": -0.01}, ConfigError, "overrun_m"),
        ({"min_segment_m": -0.01}, ConfigError, "min_segment_m"),
        ({"start_m": [np.nan, 0, 0]}, InputError, "start_m"),
        ({"start_m": [0.0, 0.0]}, InputError, "start_m"),
        ({"from_start": True}, InputError, "from_start needs start_m"),
        ({"empty": True}, ExplorationError, "no dirt"),
        ({"no_normals": True}, InputError, "normals"),
    ],
)
def test_bad_input_is_refused_with_a_one_line_message(kwargs, error, words) -> None:
    cloud = with_squares(plate(0.12, 0.12), [(0.0, 0.0)], 0.03)
    if kwargs.pop("empty", False):
        cloud = cloud.with_target(np.zeros(len(cloud)))
    if kwargs.pop("no_normals", False):
        cloud = SurfaceCloud(cloud.points, target=cloud.target, spacing=H)
    args = {"pad_radius_m": PAD_R, "line_spacing_m": SPACING, "gap_m": 0.03, **kwargs}
    with pytest.raises(error, match=words) as info:
        plan_region_raster(cloud, **args)
    assert isinstance(info.value, TactexError) and "\n" not in str(info.value)


def test_bad_input_to_the_follower_and_the_helpers() -> None:
    cloud = with_squares(plate(0.12, 0.12), [(0.0, 0.0)], 0.03)
    path = RegionRasterPath(cloud, PAD_R, SPACING, 0.03, max_step_m=0.002)
    with pytest.raises(InputError, match="one per cloud point"):
        path.update_target(np.ones(3))
    with pytest.raises(InputError, match="≥ 0"):
        path.update_target(-np.ones(len(cloud)))
    with pytest.raises(ConfigError, match="step"):
        RegionRasterPath(cloud, PAD_R, SPACING, 0.03, max_step_m=0.0)
    with pytest.raises(ConfigError, match="overlap"):
        spacing_from_overlap(0.05, 1.0)
    with pytest.raises(ConfigError, match="width"):
        spacing_from_overlap(-0.05, 0.2)
    assert spacing_from_overlap(0.05, 0.4) == pytest.approx(0.03)
    with pytest.raises(ConfigError, match="speed_m_s"):
        ideal_time_s(0.01, 0.05, 0.0)
    with pytest.raises(ConfigError, match="transit_s"):
        ideal_time_s(0.01, 0.05, 0.05, -1.0)
    with pytest.raises(InputError, match="point_area_m2"):
        dirty_area_m2(cloud, np.ones(2))


def test_ideal_time_is_the_area_swept_once_plus_the_transit() -> None:
    assert ideal_time_s(0.01, 0.05, 0.05, 1.5) == pytest.approx(0.01 / (0.05 * 0.05) + 1.5)
    cloud = with_squares(plate(), [(0.0, 0.0)], 0.09)
    n = cloud.n_target  # grid points of 3 mm, each standing for h² of surface
    assert dirty_area_m2(cloud) == pytest.approx(n * H * H, rel=0.06)
    assert dirty_area_m2(cloud, np.full(len(cloud), H * H)) == pytest.approx(n * H * H)
    assert dirty_area_m2(cloud.with_target(np.zeros(len(cloud)))) == 0.0
    inner = np.median(point_areas_m2(cloud))
    assert inner == pytest.approx(H * H, rel=0.06)


@pytest.mark.parametrize(("name", "marking"), [("plate", "X"), ("bowl", "X"), ("cup", "X"), ("cup", "full")])
def test_the_marking_is_covered_on_flat_and_curved_surfaces(name: str, marking: str) -> None:
    # the whole cup wall is a half cylinder: lines along its axis, spaced across the bend, drop strips at its
    # sides, and a direction that does is no candidate
    cloud = marked_cloud(get_surface(name), marking, H)
    plan = plan_region_raster(cloud, PAD_R, SPACING, gap_m=0.1)
    assert covered(plan, cloud).all() and plan.uncovered == 0


def test_the_x_of_the_tec_cup_scan_is_covered() -> None:
    from tactex.perception.normals import knn_normals

    cup = target_from_channel(voxel_down_sample(load_ply(tec_cloud_path("cup_X")), H), "red", 1.0)
    cup = cup.with_normals(knn_normals(cup.points, 16).normals)
    pad_r = 0.01  # a pad about the size of the paper's agent on the cup (7.5 mm), so the X takes several lines
    plan = plan_region_raster(cup, pad_r, 0.015, gap_m=0.03)
    assert covered(plan, cup, pad_r).all()
    assert len(segments_of(plan)) >= 4


def test_the_region_raster_is_far_shorter_than_the_whole_raster_on_the_plate_with_the_x() -> None:
    cloud = marked_cloud(get_surface("plate"), "X", H)
    step = 0.002
    whole = RasterPath(cloud, lane_spacing_m=SPACING, max_step_m=step)
    whole_m = float(np.linalg.norm(np.diff(whole.waypoints, axis=0), axis=1).sum())
    region = plan_region_raster(cloud, PAD_R, SPACING, gap_m=0.1)
    trimmed = plan_region_raster(cloud, PAD_R, SPACING, gap_m=0.1, overrun_m=0.0)
    bound_m = dirty_area_m2(cloud) / SPACING
    print(f"\nplate X, lines {SPACING * 1e3:.0f} mm apart: region raster {region.surface_length_m:.3f} m "
          f"(+{region.air_length_m:.3f} m in the air, {region.lift_offs} lift-offs; lines stopping over the dirt "
          f"{trimmed.surface_length_m:.3f} m), whole raster {whole_m:.3f} m, area / spacing {bound_m:.3f} m")
    assert region.surface_length_m + region.air_length_m < 0.5 * whole_m
    assert trimmed.surface_length_m < region.surface_length_m
