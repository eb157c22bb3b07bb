"""The move to a pose near the part keeps the tool clear of it: the clearance of the tool's points from a
height field and a cup, and the route over a part that stands in the way (tactex.tasks.transit)."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.errors import ConfigError
from tactex.geometry import exp_so3
from tactex.pointcloud.shapes import CylinderWallSurface
from tactex.robots import MujocoBackend
from tactex.robots.loop import ControlLoop
from tactex.sim import SceneConfig
from tactex.sim.objects import get_object
from tactex.sim.part import object_or_part
from tactex.sim.tool import ToolGeometry
from tactex.tasks import transit
from tactex.tasks.runner import TOOL_DOWN
from tactex.tasks.transit import (
    PartShape,
    clearance_m,
    move_clear_of_part,
    path_clearance_m,
    tool_points,
)
from tactex.tasks.wipe import WipeConfig, run_wipe
from tactex.tasks.wipe_policy import wipe_start_pose


def test_a_points_clearance_from_a_plate_over_beside_inside_and_under_it():
    plate = object_or_part("plate").surface  # a disc of radius 0.13 m
    pos, rot = np.array([0.5, 0.1, 0.2]), np.eye(3)
    h0 = float(plate.height(np.zeros(1), np.zeros(1))[0])
    h_rim = float(plate.height(np.array([0.13]), np.zeros(1))[0])
    points = np.array([[0.5, 0.1, 0.2 + h0 + 0.03],  # 3 cm over its centre
                       [0.5, 0.1, 0.2 + h0 - 0.002],  # inside, 2 mm under its surface
                       [0.5 + 0.2, 0.1, 0.2 + 0.5 * h_rim],  # beside its rim, below the rim's height: 7 cm out
                       [0.5 + 0.16, 0.1, 0.2 + h_rim + 0.04],  # 3 cm out and 4 cm over the rim
                       [0.5, 0.1, 0.2 - 0.004],  # in its 1 cm base
                       [0.5, 0.1, 0.2 - 0.03]])  # 2 cm under its base
    c = clearance_m(plate, pos, rot, points, base_m=0.01)
    np.testing.assert_allclose(c, [0.03, -0.002, 0.07, 0.05, -0.006, 0.02], atol=1e-6)  # the base: 6 mm to its bottom
    # a part turned about an axis: a point given in its own frame is judged the same
    turn = exp_so3(np.array([0.3, -0.2, 1.1]))
    local = np.array([[0.08, -0.05, 0.015], [0.2, 0.0, 0.01], [0.0, 0.1, -0.02]])
    np.testing.assert_allclose(clearance_m(plate, pos, turn, pos + local @ turn.T, base_m=0.01),
                               clearance_m(plate, np.zeros(3), np.eye(3), local, base_m=0.01), atol=1e-12)


def test_a_points_clearance_from_a_cup_side_top_and_inside():
    cup = CylinderWallSurface(name="cup", radius_m=0.04, height_m=0.1)
    pos, rot = np.array([0.5, 0.0, 0.0]), np.eye(3)
    c = clearance_m(cup, pos, rot, np.array([[0.5, -0.06, 0.05],  # 2 cm off its side
                                             [0.5, -0.03, 0.05],  # inside its cylinder, 1 cm from the side
                                             [0.5, 0.0, 0.13],  # 3 cm over its top's centre
                                             [0.5, -0.07, 0.14]]))  # off the top's edge: 3 cm out, 4 cm up
    np.testing.assert_allclose(c, [0.02, -0.01, 0.03, 0.05], atol=1e-9)


def test_the_tools_points_cover_its_surfaces_closer_than_the_clearance():
    tool = ToolGeometry()
    p = np.array([0.5, 0.0, 0.3])
    pts = tool_points(p, TOOL_DOWN, tool)
    np.testing.assert_allclose(pts[0], p)  # the pad's centre first
    up = (pts - p) @ -TOOL_DOWN[:, 2]  # along the tool's axis, up from the pad's face
    radial = np.linalg.norm((pts - p) - np.outer((pts - p) @ TOOL_DOWN[:, 2], TOOL_DOWN[:, 2]), axis=1)
    face = up < 1e-9
    assert radial[face].max() == pytest.approx(tool.pad_radius_m)  # the pad's face, to its rim
    assert up.max() == pytest.approx(tool.tcp_offset_m)  # the flange's side of the sensor
    assert radial[np.isclose(up, tool.tcp_offset_m)].max() == pytest.approx(0.04)  # the sensor's disc
    # the camera's box around its offset from the flange (in the tool frame; x along the world's x here)
    box_centre = p + TOOL_DOWN @ (np.array([0.0, 0.0, -tool.tcp_offset_m]) + np.asarray(tool.camera_offset_m))
    box = pts[np.all(np.abs(pts - box_centre) <= np.array([0.0125, 0.045, 0.0125]) + 1e-9, axis=1)]
    assert np.ptp(box, axis=0) == pytest.approx([0.025, 0.09, 0.025])
    # no point of the pad's face is farther than the clearance from the nearest of the others: a part cannot
    # reach into it between them unseen by more than that
    from scipy.spatial import cKDTree

    d, _ = cKDTree(pts[face]).query(pts[face], k=2)
    assert d[:, 1].max() <= transit.TRANSIT_CLEARANCE_M + 1e-9
    # a cup's rim 3 mm into the middle of the camera box's underside is seen
    cup = CylinderWallSurface(name="cup", radius_m=0.04, height_m=0.1)
    bottom = box_centre[2] - 0.0125
    seen = clearance_m(cup, np.array([box_centre[0] + 0.04, box_centre[1], bottom + 0.003 - 0.1]), np.eye(3), pts)
    assert seen.min() < 0.0


def test_a_move_through_a_plate_is_seen_however_thin_it_is():
    # a joint move straight down through the plate's 4 mm floor, from two postures 40 cm apart (the fewest samples
    # a planned route's waypoint pair starts from): sampled finely enough to meet it; and one across, over it
    loop, cfg = _loop_with_part_at(get_object("plate").position_m)
    p0, r0 = loop.state.ee_position.copy(), loop.state.ee_rotation.copy()
    part = PartShape(object_or_part("plate").surface, p0 - np.array([0.0, 0.0, 0.006]), np.eye(3))  # declared only
    tool = cfg.tool
    high, low = (loop.solve_pose(p0 + np.array([0.0, 0.0, dz]), r0) for dz in (0.2, -0.2))
    assert path_clearance_m(loop, high, low, part, tool, min_samples=2).min() < 0.0
    left, right = (loop.solve_pose(p0 + np.array([dx, 0.0, 0.1]), r0) for dx in (-0.1, 0.1))
    assert path_clearance_m(loop, left, right, part, tool, min_samples=2).min() > 0.05


def test_the_arms_links_are_checked_as_capsules():
    """A part declared where the arm's elbow stands, away from the tool: the tool's points alone keep
    clear of it, the links' capsules do not; each capsule is points along its axis no farther apart than the
    clearance, each with the capsule's radius."""
    loop, cfg = _loop_with_part_at(get_object("plate").position_m)
    q = loop.state.q.copy()
    ends, radii = loop.link_capsules(q)
    assert ends.shape == (len(radii), 2, 3) and np.all((radii >= 0.03) & (radii <= 0.08))
    elbow = ends[int(np.argmax(ends[:, :, 2].max(axis=1) * (ends[:, :, 0].min(axis=1) < -0.1)))].mean(axis=0)
    plate = object_or_part("plate").surface
    part = PartShape(plate, elbow - np.array([0.0, 0.0, float(plate.height(np.zeros(1), np.zeros(1))[0])]),
                     np.eye(3))  # its surface's centre at the elbow's axis: declared only
    assert part.clearance_m(tool_points(*loop.tcp_pose(q), cfg.tool)).min() > 0.1
    assert path_clearance_m(loop, q, q, part, cfg.tool, min_samples=2).min() < -0.03  # the elbow's capsule in it
    pts, r = transit.link_points(ends, radii)
    assert len(pts) == len(r) and set(np.round(r, 6)) == set(np.round(radii, 6))
    for (a, b), radius in zip(ends, radii, strict=True):  # every axis covered from end to end, densely
        on = np.isclose(r, radius) & (np.linalg.norm(np.cross(pts - a, b - a), axis=1)
                                      <= 1e-9 + 1e-6 * np.linalg.norm(b - a))
        d = np.sort((pts[on] - a) @ (b - a) / max(float(np.linalg.norm(b - a)), 1e-12))
        assert d[0] <= 1e-9 and d[-1] >= np.linalg.norm(b - a) - 1e-9
        assert np.diff(d).max(initial=0.0) <= transit.TRANSIT_CLEARANCE_M + 1e-9


def _loop_with_part_at(position, hold_s: float = 0.05, name: str = "plate") -> tuple[ControlLoop, SceneConfig]:
    """A loop on a scene with the object ``name`` at ``position`` [m], held ``hold_s`` [s] at the arm's home."""
    cfg = SceneConfig(object_name=name, object_position=tuple(position), camera_width=8, camera_height=8)
    loop = ControlLoop(MujocoBackend(cfg))
    if hold_s:
        loop.hold(hold_s)
    return loop, cfg


def _start(cfg: SceneConfig):
    """The wipe's start [m, rotation] on the scene's object, and the object's shape."""
    pos, rot = cfg.object_pose()
    obj = cfg.sim_object
    return (*wipe_start_pose(WipeConfig(), obj.surface, pos, rot),
            PartShape(obj.surface, pos, rot, obj.base_thickness_m, cfg.object_position))


@pytest.mark.parametrize("name", ["sine_panel", "plate", "bowl", "plane", "tilted_plane", "door", "hull"])
def test_every_built_in_object_where_it_stands_is_reached_directly(name):
    # the move every default wipe made before the check: the same joint move, to the same posture
    loop, cfg = _loop_with_part_at(get_object(name).position_m, name=name)
    p, r, part = _start(cfg)
    q_direct = loop.solve_pose(p, r)
    assert move_clear_of_part(loop, p, r, part, cfg.tool) == "direct"
    np.testing.assert_allclose(loop.state.q, q_direct, atol=0.02)
    assert np.linalg.norm(loop.state.ee_position - p) < 3e-3


def test_the_cups_default_start_goes_over_its_rim_and_ends_in_the_direct_moves_posture():
    # the direct joint move from home to the start beside the cup's wall passes its top edge within a millimetre
    loop, cfg = _loop_with_part_at(get_object("cup").position_m, name="cup")
    p, r, part = _start(cfg)
    q_direct = loop.solve_pose(p, r)
    assert path_clearance_m(loop, loop.state.q.copy(), q_direct, part, cfg.tool).min() < 0.005
    seen: list[float] = []  # the tool's clearance at every tick of the move made
    loop.on_tick = lambda state, reference, controller: seen.append(
        part.clearance_m(tool_points(state.ee_position, state.ee_rotation, cfg.tool)).min())
    route = move_clear_of_part(loop, p, r, part, cfg.tool)
    assert route.startswith("over the part at z = "), route
    np.testing.assert_allclose(loop.state.q, q_direct, atol=0.02)
    assert min(seen) >= transit.TRANSIT_CLEARANCE_M  # the descent too, into the direct move's posture


def test_a_part_in_the_way_is_gone_round_and_never_touched():
    # the plate raised to 0.5 m, above the height of the tool at the arm's home: the joint move to the start
    # sweeps the pad through it
    loop, cfg = _loop_with_part_at((0.5, 0.0, 0.5))
    p, r, part = _start(cfg)
    q0 = loop.state.q.copy()
    q_direct = loop.solve_pose(p, r)
    assert path_clearance_m(loop, q0, q_direct, part, cfg.tool).min() < 0.0
    forces, seen = [], []
    loop.on_tick = lambda state, reference, controller: (
        forces.append(float(np.linalg.norm(state.wrench_tool[:3]))),
        seen.append(part.clearance_m(tool_points(state.ee_position, state.ee_rotation, cfg.tool)).min()))
    route = move_clear_of_part(loop, p, r, part, cfg.tool)
    z_cross = part.top_z_m() + transit.ABOVE_PART_M + cfg.tool.pad_radius_m
    assert route == f"over the part at z = {z_cross:.2f} m (the direct move went through it)", route
    assert np.linalg.norm(loop.state.ee_position - p) < 3e-3
    np.testing.assert_allclose(loop.state.q, q_direct, atol=0.02)
    assert max(forces) < 1.0  # no contact on the way: the pad's weight and the moves' inertia only
    assert min(seen) >= transit.TRANSIT_CLEARANCE_M


def test_a_tool_in_or_on_the_part_backs_out_along_its_axis_first():
    # the hull declared where its top is over the pad at the arm's home (the scene's own part stands elsewhere,
    # as a misplaced part would): 12 mm (a pad pressed on it by a stopped run), then 30 mm deep
    hull = get_object("hull")
    for depth in (0.012, 0.03):
        loop, cfg = _loop_with_part_at(get_object("plate").position_m, hold_s=0.0)
        p0, r0 = loop.state.ee_position.copy(), loop.state.ee_rotation.copy()
        pos = np.array([p0[0], p0[1], p0[2] - 0.08 + depth])  # the hull's top is 8 cm over its frame
        part = PartShape(hull.surface, pos, np.eye(3), hull.base_thickness_m)
        p, r = wipe_start_pose(WipeConfig(), hull.surface, pos, np.eye(3))
        assert part.clearance_m(tool_points(p0, r0, cfg.tool)).min() == pytest.approx(-depth, abs=1e-3)
        rise: list[float] = []
        loop.on_tick = lambda state, reference, controller, p0=p0, rise=rise: rise.append(state.ee_position[2] - p0[2])
        route = move_clear_of_part(loop, p, r, part, cfg.tool)
        backed = float(route.split(" mm")[0].removeprefix("backed out "))
        assert depth + 0.005 <= backed * 1e-3 <= depth + 0.008, route
        assert f"the tool stood {1e3 * depth:.0f} mm inside the part as placed" in route, route
        assert max(rise) > depth  # up, along the tool's axis (it points down)
        assert np.linalg.norm(loop.state.ee_position - p) < 3e-3


def test_no_clear_way_or_a_way_out_of_reach_is_refused_before_the_arm_moves(monkeypatch):
    # the arm's home under the plate's rim: the way over it would pass through it too; 2 cm lower, the F/T sensor
    # touches the plate's base: moving away (up) would pass through it
    for z, message in ((0.62, r"no clear way to the start: the direct move went through it \(the part at "
                              r"\[0\.4, 0\.0, 0\.62\] m\).*pass through it too"),
                       (0.6, r"the tool stands touching the part placed at \[0\.4, 0\.0, 0\.6\] m, and moving it away "
                             r"from the part would bring it nearer first \(the arm stands under")):
        loop, cfg = _loop_with_part_at((0.4, 0.0, z), hold_s=0.0)
        p, r, part = _start(cfg)
        q0 = loop.state.q.copy()
        with pytest.raises(ConfigError, match=message):
            move_clear_of_part(loop, p, r, part, cfg.tool)
        np.testing.assert_allclose(loop.state.q, q0)
    # a way round out of the arm's reach: refused with what to do, before any leg moves
    monkeypatch.setattr(transit, "ABOVE_PART_M", 1.5)
    loop, cfg = _loop_with_part_at((0.5, 0.0, 0.5))
    p, r, part = _start(cfg)
    q0 = loop.state.q.copy()
    with pytest.raises(ConfigError, match=r"out of the arm.s reach.*place the part lower or nearer the robot"):
        move_clear_of_part(loop, p, r, part, cfg.tool)
    np.testing.assert_allclose(loop.state.q, q0)


def test_a_wipe_of_a_raised_part_goes_over_it_and_says_so(capsys):
    result = run_wipe(WipeConfig(object_position=(0.5, 0.0, 0.5), duration_s=1.0), progress=True)
    m = result.metrics
    assert m["start_transit"].startswith("over the part"), m["start_transit"]
    assert "to the start: over the part" in capsys.readouterr().err
    assert m["max_force_norm_n"] < 2 * WipeConfig().force_n and m["safety_counts"].get("force_limit", 0) == 0
    assert run_wipe(WipeConfig(duration_s=0.2), progress=False).metrics["start_transit"] == "direct"
