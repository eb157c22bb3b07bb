"""The move to a pose near the part keeps the tool clear of it: the clearance of the tool's points from a
height field and a cup, and the route over a part that stands in the way (tactex.tasks.transit)."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.errors import ConfigError
from tactex.pointcloud.shapes import CylinderWallSurface
from tactex.robots import MujocoBackend
from tactex.robots.loop import ControlLoop
from tactex.sim import SceneConfig
from tactex.sim.part import object_or_part
from tactex.sim.tool import ToolGeometry
from tactex.tasks import transit
from tactex.tasks.runner import TOOL_DOWN
from tactex.tasks.transit import clearance_m, line_clearance_m, move_clear_of_part, path_clearance_m, tool_points
from tactex.tasks.wipe import WipeConfig, run_wipe
from tactex.tasks.wipe_policy import wipe_start_pose


def test_a_points_clearance_from_a_plate_over_beside_inside_and_under_it():
    plate = object_or_part("plate").surface
    pos, rot = np.array([0.5, 0.1, 0.2]), np.eye(3)
    h0 = float(plate.height(np.zeros(1), np.zeros(1))[0])
    points = np.array([[0.5, 0.1, 0.2 + h0 + 0.03],  # 3 cm over its centre
                       [0.5, 0.1, 0.2 + h0 - 0.002],  # inside, 2 mm under its surface
                       [0.5 + 0.2, 0.1, 0.21],  # beside its footprint (radius 0.13 m)
                       [0.5, 0.1, 0.15]])  # under its base: the table's side
    c = clearance_m(plate, pos, rot, points)
    np.testing.assert_allclose(c[:2], [0.03, -0.002], atol=1e-9)
    assert np.isinf(c[2:]).all()
    # turned a quarter about z, the footprint turns with it: a point over the turned centre is the same
    quarter = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(clearance_m(plate, pos, quarter, points[:1]), [0.03], atol=1e-9)


def test_a_points_clearance_from_a_cup_side_top_and_inside():
    cup = CylinderWallSurface(name="cup", radius_m=0.04, height_m=0.1)
    pos, rot = np.array([0.5, 0.0, 0.0]), np.eye(3)
    c = clearance_m(cup, pos, rot, np.array([[0.5, -0.06, 0.05],  # 2 cm off its side
                                             [0.5, -0.03, 0.05],  # inside its cylinder
                                             [0.5, 0.0, 0.13],  # 3 cm over its top's centre
                                             [0.5, -0.07, 0.14]]))  # off the top's edge: 3 cm out, 4 cm up
    np.testing.assert_allclose(c, [0.02, -0.01, 0.03, 0.05], atol=1e-9)


def test_the_tools_points_are_its_pad_rim_its_axis_and_its_camera():
    tool = ToolGeometry()
    p = np.array([0.5, 0.0, 0.3])
    pts = tool_points(p, TOOL_DOWN, tool)
    np.testing.assert_allclose(pts[0], p)
    rim = pts[1:9] - p
    np.testing.assert_allclose(np.linalg.norm(rim, axis=1), tool.pad_radius_m)
    np.testing.assert_allclose(rim @ TOOL_DOWN[:, 2], 0.0, atol=1e-12)  # in the pad's plane
    length = tool.sensor_height_m + tool.body_length_m + tool.pad_thickness_m
    flange = p + np.array([0.0, 0.0, length])  # up the axis: the tool points down
    np.testing.assert_allclose(pts[12], flange)


def test_a_straight_line_through_a_plate_is_seen_however_thin_it_is():
    # a line crossing the plate's 4 mm floor between two far poses: sampled finely enough to meet it
    plate = object_or_part("plate").surface
    tool = ToolGeometry()
    pos = np.array([0.5, 0.0, 0.0])
    through = line_clearance_m(np.array([0.5, 0.0, 0.5]), TOOL_DOWN, np.array([0.5, 0.0, -0.3]), TOOL_DOWN, plate,
                               pos, np.eye(3), tool)
    over = line_clearance_m(np.array([0.3, 0.0, 0.1]), TOOL_DOWN, np.array([0.7, 0.0, 0.1]), TOOL_DOWN, plate,
                            pos, np.eye(3), tool)
    assert through < 0.0 and over == pytest.approx(0.1 - 0.02, abs=2e-3)  # the plate's rim is 2 cm high


def _loop_with_part_at(position, hold_s: float = 0.05, name: str = "plate") -> tuple[ControlLoop, object]:
    """A loop on a scene with the object ``name`` at ``position`` [m], held ``hold_s`` [s] at the arm's home."""
    cfg = SceneConfig(object_name=name, object_position=tuple(position), camera_width=8, camera_height=8)
    loop = ControlLoop(MujocoBackend(cfg))
    if hold_s:
        loop.hold(hold_s)
    return loop, cfg


def _start(cfg):
    pos, rot = cfg.object_pose()
    return (*wipe_start_pose(WipeConfig(), cfg.sim_object.surface, pos, rot), cfg.sim_object.surface, pos, rot)


def test_an_unobstructed_move_to_the_start_is_the_direct_joint_move():
    loop, cfg = _loop_with_part_at(SceneConfig(object_name="plate").object_pose()[0])
    p, r, surface, pos, rot = _start(cfg)
    q_direct = loop.solve_pose(p, r)
    assert move_clear_of_part(loop, p, r, surface, pos, rot, cfg.tool) == "direct"
    np.testing.assert_allclose(loop.state.q, q_direct, atol=0.02)
    assert np.linalg.norm(loop.state.ee_position - p) < 3e-3


def test_a_part_in_the_way_is_gone_round_and_never_touched():
    # the plate raised to 0.5 m, above the height of the tool at the arm's home: the joint move to the start
    # sweeps the pad through it
    loop, cfg = _loop_with_part_at((0.5, 0.0, 0.5))
    p, r, surface, pos, rot = _start(cfg)
    q0 = loop.state.q.copy()
    assert path_clearance_m(loop, q0, loop.solve_pose(p, r), surface, pos, rot, cfg.tool).min() < 0.0
    forces = []
    loop.on_tick = lambda state, reference, controller: forces.append(float(np.linalg.norm(state.wrench_tool[:3])))
    route = move_clear_of_part(loop, p, r, surface, pos, rot, cfg.tool)
    top = pos[2] + surface.bounds_m[1, 2]
    z_cross = top + transit.ABOVE_PART_M + cfg.tool.pad_radius_m
    assert route == f"over the part at z = {z_cross:.2f} m (the direct move went through it)", route
    assert np.linalg.norm(loop.state.ee_position - p) < 3e-3
    assert max(forces) < 1.0  # no contact on the way: the pad's weight and the moves' inertia only


def test_a_tool_inside_the_part_or_no_clear_way_is_refused_before_the_arm_moves(monkeypatch):
    # the hull's top 5 cm over the pad at the arm's home (0.307, 0, 0.430) m (before the physics pushes the two
    # apart: deeper than a pad pressed on a part can be); then the arm under the plate's rim
    for name, position, message in (("hull", (0.307, 0.0, 0.40), "the tool is inside the part where it stands now"),
                                    ("plate", (0.4, 0.0, 0.6), "no clear way to the start.*pass through it too")):
        loop, cfg = _loop_with_part_at(position, hold_s=0.0, name=name)
        p, r, surface, pos, rot = _start(cfg)
        q0 = loop.state.q.copy()
        with pytest.raises(ConfigError, match=message):
            move_clear_of_part(loop, p, r, surface, pos, rot, cfg.tool)
        np.testing.assert_allclose(loop.state.q, q0)
    # a pad pressed on the part (a run stopped there, compressed up to its travel) is not inside it: it goes
    loop, cfg = _loop_with_part_at((0.307, 0.0, 0.4303 - 0.08 + 0.012), hold_s=0.0, name="hull")  # 12 mm into it
    p, r, surface, pos, rot = _start(cfg)
    q0 = loop.state.q.copy()
    assert path_clearance_m(loop, q0, q0, surface, pos, rot, cfg.tool)[0] == pytest.approx(-0.012, abs=1e-3)
    assert move_clear_of_part(loop, p, r, surface, pos, rot, cfg.tool) == "direct"
    # a way round out of the arm's reach: refused with what to do, before any leg moves
    monkeypatch.setattr(transit, "ABOVE_PART_M", 1.5)
    loop, cfg = _loop_with_part_at((0.5, 0.0, 0.5))
    p, r, surface, pos, rot = _start(cfg)
    q0 = loop.state.q.copy()
    with pytest.raises(ConfigError, match=r"out of the arm.s reach.*place the part lower or nearer the robot"):
        move_clear_of_part(loop, p, r, surface, pos, rot, cfg.tool)
    np.testing.assert_allclose(loop.state.q, q0)


def test_a_wipe_of_a_raised_part_goes_over_it_and_says_so(capsys):
    result = run_wipe(WipeConfig(object_position=(0.5, 0.0, 0.5), duration_s=1.0), progress=True)
    m = result.metrics
    assert m["start_transit"].startswith("over the part"), m["start_transit"]
    assert "went to the start over the part" in capsys.readouterr().err
    assert m["max_force_norm_n"] < 2 * WipeConfig().force_n and m["safety_counts"].get("force_limit", 0) == 0
    assert run_wipe(WipeConfig(duration_s=0.2), progress=False).metrics["start_transit"] == "direct"
