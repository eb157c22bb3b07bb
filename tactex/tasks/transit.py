"""A transit to a pose near the part that keeps the tool clear of it.

A joint move between two postures sweeps the tool along a curve nobody planned: from the arm's home to
a start just above a part placed high (or tall), it can pass through the part. :func:`move_clear_of_part`
checks the move's path first, sampled in joint space as the move follows it, and when the tool would come
nearer the part than :data:`TRANSIT_CLEARANCE_M` (or than it starts or ends), goes round: up to
:data:`ABOVE_PART_M` over the part's top, across, and straight down to the pose, each leg checked the
same way before the arm moves; with no clear way it refuses. The tool is its pad's
rim, its axis up to the flange and its camera (:func:`tool_points`); the arm's links are not checked. The
part is the solid under its height field, or the cup's cylinder taken as solid (:func:`clearance_m`).
"""

from __future__ import annotations

import math

import numpy as np

from tactex.errors import ConfigError, SimulationError
from tactex.geometry import exp_so3, log_so3
from tactex.pointcloud.shapes import CylinderWallSurface, HeightFieldSurface, Surface
from tactex.robots.loop import ControlLoop
from tactex.sim.tool import ToolGeometry

__all__ = ["ABOVE_PART_M", "PATH_SAMPLES", "SAMPLE_STEP_M", "TRANSIT_CLEARANCE_M", "clearance_m", "line_clearance_m",
           "move_clear_of_part", "path_clearance_m", "tool_points"]

#: The least distance between the tool and the part a transit keeps [m] (or its ends' own, if less).
TRANSIT_CLEARANCE_M = 0.005

#: How high over the part's top a transit that goes round it crosses [m].
ABOVE_PART_M = 0.05

#: Postures sampled along a path for its clearance, at the least [-].
PATH_SAMPLES = 60

#: The furthest a point of the tool moves between two samples of a path [m].
SAMPLE_STEP_M = 0.002


def tool_points(p_tcp_world: np.ndarray, r_tcp_world: np.ndarray, tool: ToolGeometry) -> np.ndarray:
    """(K, 3) [m] points of the tool at a TCP pose (world frame): the pad's centre and eight points of
    its rim, four points up its axis to the flange, and the camera."""
    p = np.asarray(p_tcp_world, dtype=float)
    r = np.asarray(r_tcp_world, dtype=float)
    angles = np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)
    rim = tool.pad_radius_m * (np.outer(np.cos(angles), r[:, 0]) + np.outer(np.sin(angles), r[:, 1]))
    length = tool.sensor_height_m + tool.body_length_m + tool.pad_thickness_m
    axis = np.outer(np.linspace(0.25, 1.0, 4) * length, -r[:, 2])  # the tool's z points out of the pad
    flange = p - length * r[:, 2]
    camera = flange + r @ np.asarray(tool.camera_offset_m, dtype=float)
    return np.vstack([p, p + rim, p + axis, camera])


def clearance_m(surface: Surface, obj_pos: np.ndarray, obj_rot: np.ndarray, points_world: np.ndarray) -> np.ndarray:
    """(K,) [m] each point's clearance from the part at ``obj_pos`` [m] turned by ``obj_rot``: its height
    over the height field where it is above the part's footprint, its distance from the cup's cylinder
    (its top and its side); +inf beside the footprint, or below the part's base (the table's side, not the
    part's); negative inside the part."""
    p = (np.asarray(points_world, dtype=float).reshape(-1, 3) - obj_pos) @ obj_rot
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    out = np.full(len(p), np.inf)
    above_base = z >= 0.0
    if isinstance(surface, HeightFieldSurface):
        over = surface.inside(x, y) & above_base
        out[over] = z[over] - surface.height(x[over], y[over])
    elif isinstance(surface, CylinderWallSurface):
        radial = np.hypot(x, y) - surface.radius_m
        over_top = z - surface.height_m
        side = above_base & (over_top <= 0.0)
        out[side] = radial[side]
        top = over_top > 0.0
        out[top] = np.where(radial[top] <= 0.0, over_top[top], np.hypot(radial[top], over_top[top]))
    else:
        raise ConfigError(f"no transit clearance for a {type(surface).__name__}: a height field or a cup's wall")
    return out


def _sampled(tool_points_at, n: int) -> np.ndarray:
    """(n', K, 3) [m] the tool's points at n' >= ``n`` evenly spaced fractions s in [0, 1] of a path
    (``tool_points_at(s)``), sampled finely enough that no point moves more than :data:`SAMPLE_STEP_M`
    between two samples (a thin part between two samples would be missed)."""
    for _ in range(3):
        pts = np.stack([tool_points_at(s) for s in np.linspace(0.0, 1.0, n)])
        step = float(np.linalg.norm(np.diff(pts, axis=0), axis=2).max()) if n > 1 else 0.0
        if step <= SAMPLE_STEP_M:
            break
        n = math.ceil(n * step / SAMPLE_STEP_M) + 1
    return pts


def path_clearance_m(loop: ControlLoop, q_from: np.ndarray, q_to: np.ndarray, surface: Surface,
                     obj_pos: np.ndarray, obj_rot: np.ndarray, tool: ToolGeometry) -> np.ndarray:
    """(n,) [m] the tool's least clearance from the part at postures along the joint move from ``q_from`` to
    ``q_to`` [rad] (a straight line in joint space, as :meth:`ControlLoop.move_joints` goes from rest), both
    ends included, at least :data:`PATH_SAMPLES` of them."""
    if loop.tcp_pose(q_from) is None:
        raise ConfigError("this robot's backend has no kinematic model: the transit's clearance cannot be checked")
    pts = _sampled(lambda s: tool_points(*loop.tcp_pose(q_from + s * (q_to - q_from)), tool), PATH_SAMPLES)
    return clearance_m(surface, obj_pos, obj_rot, pts.reshape(-1, 3)).reshape(len(pts), -1).min(axis=1)


def line_clearance_m(p0: np.ndarray, r0: np.ndarray, p1: np.ndarray, r1: np.ndarray, surface: Surface,
                     obj_pos: np.ndarray, obj_rot: np.ndarray, tool: ToolGeometry) -> float:
    """[m] the tool's least clearance from the part along the TCP's straight line from ``p0`` to ``p1`` [m],
    its orientation along the geodesic from ``r0`` to ``r1`` (as :meth:`ControlLoop.move_cartesian` goes)."""
    w = log_so3(np.asarray(r0, dtype=float).T @ r1)
    pts = _sampled(lambda s: tool_points(p0 + s * (p1 - p0), r0 @ exp_so3(s * w), tool), PATH_SAMPLES)
    return float(clearance_m(surface, obj_pos, obj_rot, pts.reshape(-1, 3)).min())


def _top_world_z(surface: Surface, obj_pos: np.ndarray, obj_rot: np.ndarray) -> float:
    """The highest corner of the part's bounding box in the world [m]."""
    lo, hi = surface.bounds_m
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    return float((corners @ obj_rot.T + obj_pos)[:, 2].max())


def move_clear_of_part(loop: ControlLoop, p_goal_world: np.ndarray, r_goal_world: np.ndarray, surface: Surface,
                       obj_pos: np.ndarray, obj_rot: np.ndarray, tool: ToolGeometry, settle_s: float = 0.5) -> str:
    """Move the TCP to a pose near the part [m, rotation], clear of it; ``"direct"`` when the joint move
    to its IK solution keeps :data:`TRANSIT_CLEARANCE_M` (or its ends' own clearance, if less) all along,
    else how it went round (up, across at :data:`ABOVE_PART_M` over the part's top, down), and why.
    A move that starts in contact (a run stopped on the part) may start that deep, and goes direct unless
    it goes deeper. Raises :class:`ConfigError` before the arm moves when the tool is already deeper in the
    part than its pad's travel (the part's position is wrong), or the way round is out of the arm's reach."""
    q_from = loop.state.q.copy()
    q_goal = loop.solve_pose(p_goal_world, r_goal_world)
    path = path_clearance_m(loop, q_from, q_goal, surface, obj_pos, obj_rot, tool)
    where = np.round(np.asarray(obj_pos, dtype=float), 3).tolist()
    if path[0] < -(tool.max_compression_m + TRANSIT_CLEARANCE_M):  # deeper than a pad pressed on it can be
        raise ConfigError(
            f"the tool is inside the part where it stands now ({1e3 * -path[0]:.0f} mm deep): the part at {where} m "
            "overlaps the arm; check --object-position (the part's origin, its base, in the robot's base frame)")
    if path.min() >= min(TRANSIT_CLEARANCE_M, path[0], path[-1]) - 1e-3:
        loop.move_joints(q_goal, settle_s=settle_s)
        return "direct"
    z_cross = max(_top_world_z(surface, obj_pos, obj_rot) + ABOVE_PART_M + tool.pad_radius_m,
                  float(p_goal_world[2]))
    p_now, r_now = loop.state.ee_position.copy(), loop.state.ee_rotation.copy()
    legs = ([(np.array([p_now[0], p_now[1], z_cross]), r_now)] if p_now[2] < z_cross else []) + [
        (np.array([p_goal_world[0], p_goal_world[1], z_cross]), r_goal_world), (p_goal_world, r_goal_world)]
    ends = [(p_now, r_now), *legs]
    least = min(line_clearance_m(*a, *b, surface, obj_pos, obj_rot, tool) for a, b in zip(ends, legs, strict=False))
    if least < min(TRANSIT_CLEARANCE_M, path[0], path[-1]) - 1e-3:
        raise ConfigError(
            f"no clear way to the start: the direct move would pass through the part at {where} m, and the way over "
            f"it (up to z = {z_cross:.2f} m, across, down) would " + (
                f"bring the tool within {1e3 * least:.0f} mm of it" if least >= 0.0 else "pass through it too")
            + " (the arm stands under or against the part): place the part elsewhere")
    q = q_from
    try:  # each leg's end solved before the arm moves: a way round out of reach is refused, not begun
        for p, r in legs:
            q = loop.solve_pose(p, r, q_seed=q)
    except SimulationError as exc:
        raise ConfigError(
            f"the move to the start would pass through the part at {where} m (the tool within "
            f"{1e3 * max(path.min(), 0.0):.0f} mm of it), and the way over its top, at z = {z_cross:.2f} m, is out of "
            f"the arm's reach ({exc}): place the part lower or nearer the robot") from exc
    for i, (p, r) in enumerate(legs):
        loop.move_cartesian(p, r, settle_s=settle_s if i == len(legs) - 1 else 0.1)
    return (f"over the part at z = {z_cross:.2f} m (the direct move passed within {1e3 * path.min():.0f} mm of "
            "it)" if path.min() >= 0.0 else f"over the part at z = {z_cross:.2f} m (the direct move went through it)")
