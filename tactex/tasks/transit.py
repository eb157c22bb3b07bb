"""A transit to a pose near the part that keeps the tool clear of it.

A joint move between two postures sweeps the tool along a curve nobody planned: from the arm's home to
a start just above a part placed high (or tall), it can pass through the part. :func:`move_clear_of_part`
plans the move against the part's nominal shape before the arm moves. A tool that starts nearer the part
than :data:`TRANSIT_CLEARANCE_M` (a run stopped on it, or a part placed where the tool already is) first
backs out along its own axis, the way an approach came in. Then the direct joint move, if the tool keeps
:data:`TRANSIT_CLEARANCE_M` (or the goal's own clearance, if less) all along it, sampled in joint space as
the move follows it; else a way round: up to :data:`ABOVE_PART_M` over the part's top, across, and straight
down, each leg checked the same way and its waypoints solved before the first moves. With no clear way it
refuses. The tool is its pad (rim and an inner ring), its axis up to the flange, the F/T sensor's disc and
the camera's box (:func:`tool_points`); the arm's links are not checked. The part is the solid over its
footprint from its base (``base_m`` below its frame) to its height field, or the cup's cylinder taken as
solid (:func:`clearance_m`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tactex.errors import ConfigError, SimulationError
from tactex.geometry import exp_so3, log_so3
from tactex.pointcloud.shapes import CylinderWallSurface, HeightFieldSurface, Surface
from tactex.robots.loop import ControlLoop
from tactex.sim.tool import ToolGeometry

__all__ = ["ABOVE_PART_M", "MAX_BACK_OUT_M", "PATH_SAMPLES", "SAMPLE_STEP_M", "TRANSIT_CLEARANCE_M", "PartShape",
           "clearance_m", "line_clearance_m", "move_clear_of_part", "path_clearance_m", "tool_points"]

#: The least distance between the tool and the part a transit keeps [m] (or the goal's own, if less).
TRANSIT_CLEARANCE_M = 0.005

#: How high over the part's top a transit that goes round it crosses [m] (plus the pad's radius).
ABOVE_PART_M = 0.05

#: The furthest a tool that starts too near the part backs out along its axis to free itself [m].
MAX_BACK_OUT_M = 0.10

#: Postures sampled along a path for its clearance, at the least [-].
PATH_SAMPLES = 60

#: The furthest a point of the tool moves between two samples of a path [m].
SAMPLE_STEP_M = 0.002

#: The F/T sensor's disc and the camera's box half sizes in the tool frame [m] (as :func:`tactex.sim.tool.tool_xml`
#: draws them).
_SENSOR_RADIUS_M = 0.04
_CAMERA_HALF_M = (0.0125, 0.045, 0.0125)


@dataclass(frozen=True)
class PartShape:
    """The part's nominal shape where it stands: its surface, its frame's world position [m] and rotation, the
    solid under its frame's z = 0 [m] (``SimObject.base_thickness_m``), and where the user placed it
    (``--object-position`` [m], for messages; the frame's position when not given)."""

    surface: Surface
    position_m: np.ndarray
    rotation: np.ndarray
    base_m: float = 0.0
    placed_m: tuple[float, float, float] | None = None

    def clearance_m(self, points_world: np.ndarray) -> np.ndarray:
        return clearance_m(self.surface, self.position_m, self.rotation, points_world, self.base_m)

    def top_z_m(self) -> float:
        """The highest corner of the part's bounding box in the world [m]."""
        lo, hi = self.surface.bounds_m
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        return float((corners @ self.rotation.T + self.position_m)[:, 2].max())


def tool_points(p_tcp_world: np.ndarray, r_tcp_world: np.ndarray, tool: ToolGeometry) -> np.ndarray:
    """(K, 3) [m] points of the tool at a TCP pose (world frame): the pad's centre, 16 points of its rim and 8
    of a ring at half its radius, 4 points up its axis to the flange, 8 of the F/T sensor's rim at the flange,
    and the camera box's 8 corners."""
    p = np.asarray(p_tcp_world, dtype=float)
    r = np.asarray(r_tcp_world, dtype=float)

    def ring(radius: float, n: int, along_m: float) -> np.ndarray:  # in the tool's x-y plane, along_m up its axis
        a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
        return radius * (np.outer(np.cos(a), r[:, 0]) + np.outer(np.sin(a), r[:, 1])) - along_m * r[:, 2]

    length = tool.tcp_offset_m
    axis = np.outer(np.linspace(0.25, 1.0, 4) * length, -r[:, 2])  # the tool's z points out of the pad
    box = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * _CAMERA_HALF_M
    flange = p - length * r[:, 2]
    camera = flange + (np.asarray(tool.camera_offset_m, dtype=float) + box) @ r.T  # its centre from the flange
    return np.vstack([p, p + ring(tool.pad_radius_m, 16, 0.0), p + ring(0.5 * tool.pad_radius_m, 8, 0.0),
                      p + axis, p + ring(_SENSOR_RADIUS_M, 8, length - tool.sensor_height_m), camera])


def clearance_m(surface: Surface, obj_pos: np.ndarray, obj_rot: np.ndarray, points_world: np.ndarray,
                base_m: float = 0.0) -> np.ndarray:
    """(K,) [m] each point's distance from the part at ``obj_pos`` [m] turned by ``obj_rot``, the solid over its
    footprint from ``base_m`` under its frame's z = 0 up to its height field (over the footprint: its height
    over the surface; beside it: its distance from the footprint's edge, horizontal below the edge's height),
    or the cup's cylinder taken as solid (its side and its top); negative inside the part."""
    p = (np.asarray(points_world, dtype=float).reshape(-1, 3) - obj_pos) @ obj_rot
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    if isinstance(surface, HeightFieldSurface):
        if surface.radius_m is not None:  # the disc's nearest point (the rectangle holds it)
            rho = np.maximum(np.hypot(x, y), 1e-12)
            shrink = np.minimum(1.0, surface.radius_m / rho)
            xc, yc = x * shrink, y * shrink
        else:
            xc = np.clip(x, -surface.size_x_m / 2, surface.size_x_m / 2)
            yc = np.clip(y, -surface.size_y_m / 2, surface.size_y_m / 2)
        side = np.hypot(x - xc, y - yc)  # 0 over the footprint
        over = z - surface.height(xc, yc)  # above the surface (or its edge)
        under = -base_m - z  # below the base
        vertical = np.maximum(over, under)  # < 0 between base and surface
        return np.where(side > 0.0, np.hypot(side, np.maximum(vertical, 0.0)), vertical)
    if isinstance(surface, CylinderWallSurface):
        radial = np.hypot(x, y) - surface.radius_m
        vertical = np.maximum(z - surface.height_m, -base_m - z)
        inside = (radial <= 0.0) & (vertical <= 0.0)
        return np.where(inside, np.maximum(radial, vertical),
                        np.hypot(np.maximum(radial, 0.0), np.maximum(vertical, 0.0)))
    raise ConfigError(f"no transit clearance for a {type(surface).__name__}: a height field or a cup's wall")


def _sampled(tool_points_at: Callable[[float], np.ndarray], n: int = PATH_SAMPLES) -> np.ndarray:
    """(n', K, 3) [m] the tool's points at n' >= ``n`` evenly spaced fractions s in [0, 1] of a path
    (``tool_points_at(s)``), so fine that no point moves more than :data:`SAMPLE_STEP_M` between two samples
    (a thin part between two samples would be missed)."""
    while True:
        pts = np.stack([tool_points_at(s) for s in np.linspace(0.0, 1.0, n)])
        step = float(np.linalg.norm(np.diff(pts, axis=0), axis=2).max()) if n > 1 else 0.0
        if step <= SAMPLE_STEP_M * (1.0 + 1e-9):
            return pts
        n = math.ceil((n - 1) * step / SAMPLE_STEP_M) + 1  # a straight path needs no more; a curved one loops


def path_clearance_m(loop: ControlLoop, q_from: np.ndarray, q_to: np.ndarray, part: PartShape,
                     tool: ToolGeometry) -> np.ndarray:
    """(n,) [m] the tool's least clearance from the part at postures along the joint move from ``q_from`` to
    ``q_to`` [rad] (a straight line in joint space, as :meth:`ControlLoop.move_joints` goes from rest), both ends
    included, at least :data:`PATH_SAMPLES` of them."""
    if loop.tcp_pose(q_from) is None:
        raise ConfigError("this robot's backend has no kinematic model: the transit's clearance cannot be checked")
    pts = _sampled(lambda s: tool_points(*loop.tcp_pose(q_from + s * (q_to - q_from)), tool))
    return part.clearance_m(pts.reshape(-1, 3)).reshape(len(pts), -1).min(axis=1)


def line_clearance_m(p0: np.ndarray, r0: np.ndarray, p1: np.ndarray, r1: np.ndarray, part: PartShape,
                     tool: ToolGeometry) -> np.ndarray:
    """(n,) [m] the tool's least clearance from the part along the TCP's straight line from ``p0`` to ``p1``
    [m], its orientation along the geodesic from ``r0`` to ``r1`` (as :meth:`ControlLoop.move_cartesian` goes)."""
    w = log_so3(np.asarray(r0, dtype=float).T @ r1)
    pts = _sampled(lambda s: tool_points(p0 + s * (p1 - p0), r0 @ exp_so3(s * w), tool))
    return part.clearance_m(pts.reshape(-1, 3)).reshape(len(pts), -1).min(axis=1)


def _back_out(p_now: np.ndarray, r_now: np.ndarray, part: PartShape, tool: ToolGeometry) -> np.ndarray | None:
    """Where the TCP [m] is first :data:`TRANSIT_CLEARANCE_M` clear of the part backing out along the tool's
    axis (within :data:`MAX_BACK_OUT_M`), or None: that does not free it."""
    for d in np.arange(SAMPLE_STEP_M, MAX_BACK_OUT_M + 1e-9, SAMPLE_STEP_M):
        p = p_now - d * r_now[:, 2]
        if part.clearance_m(tool_points(p, r_now, tool)).min() >= TRANSIT_CLEARANCE_M:
            return p
    return None


def move_clear_of_part(loop: ControlLoop, p_goal_world: np.ndarray, r_goal_world: np.ndarray, part: PartShape,
                       tool: ToolGeometry, settle_s: float = 0.5) -> str:
    """Move the TCP to a pose near the part [m, rotation], clear of it (module docstring); returns ``"direct"``,
    or how it went (backed out first, round over the part) and why. Raises :class:`ConfigError` before the arm
    moves when there is no clear way (the arm stands under or against the part) or the way round is out of
    reach. The goal's posture is the direct move's (the IK solution from the current posture), however it went."""
    q_now, p_now, r_now = loop.state.q.copy(), loop.state.ee_position.copy(), loop.state.ee_rotation.copy()
    q_goal = loop.solve_pose(p_goal_world, r_goal_world)
    where = np.round(np.asarray(part.position_m if part.placed_m is None else part.placed_m, dtype=float), 3).tolist()
    legs: list[tuple[np.ndarray, np.ndarray]] = []  # Cartesian legs (TCP position, rotation) before the last move
    said = []
    start_clear = float(part.clearance_m(tool_points(p_now, r_now, tool)).min())
    if start_clear < TRANSIT_CLEARANCE_M:
        p_out = _back_out(p_now, r_now, part, tool)
        if p_out is None:
            raise ConfigError(
                f"the tool stands {1e3 * -start_clear:.0f} mm inside the part placed at {where} m, and backing out "
                f"{1e3 * MAX_BACK_OUT_M:.0f} mm along its axis does not free it: "
                "check --object-position, or move the arm clear (Franka's guiding mode)")
        legs.append((p_out, r_now))
        said.append(f"backed out {1e3 * np.linalg.norm(p_out - p_now):.0f} mm along the tool's axis first (it stood "
                    + (f"{1e3 * -start_clear:.0f} mm inside the part as placed)" if start_clear < 0.0 else
                       f"{1e3 * start_clear:.0f} mm from it)"))
    q_from = q_now
    plans: list[list[np.ndarray]] = []
    try:
        for p, r in legs:
            plans.append(loop.cartesian_path(p_now, r_now, q_from, p, r))
            q_from = plans[-1][-1]
    except SimulationError as exc:
        raise ConfigError(f"the tool cannot back out along its axis ({exc}): move the arm clear of the part") from exc
    path = path_clearance_m(loop, q_from, q_goal, part, tool)
    need = min(TRANSIT_CLEARANCE_M, path[-1]) - 1e-3
    if path.min() >= need:
        _run(loop, legs, plans, q_goal, None, settle_s)
        return "; ".join([*said, "then direct"]) if said else "direct"
    z_cross = max(part.top_z_m() + ABOVE_PART_M + tool.pad_radius_m, float(p_goal_world[2]))
    p_from, r_from = legs[-1] if legs else (p_now, r_now)
    round_legs = ([(np.array([p_from[0], p_from[1], z_cross]), r_from)] if p_from[2] < z_cross else []) + [
        (np.array([p_goal_world[0], p_goal_world[1], z_cross]), r_goal_world), (p_goal_world, r_goal_world)]
    ends = [(p_from, r_from), *round_legs]
    least = min(float(line_clearance_m(*a, *b, part, tool).min()) for a, b in zip(ends, round_legs, strict=False))
    if least < need:
        raise ConfigError(
            f"no clear way to the start: the direct move would pass through the part at {where} m, and the way over "
            f"it (up to z = {z_cross:.2f} m, across, down) would " + (
                f"bring the tool within {1e3 * least:.1f} mm of it" if least >= 0.0 else "pass through it too")
            + " (the arm stands under or against the part): place the part elsewhere")
    try:  # every leg's waypoints solved before the arm moves: a way round out of reach is refused, not begun
        for i, (p, r) in enumerate(round_legs):
            last = i == len(round_legs) - 1
            plans.append(loop.cartesian_path(*ends[i], q_from, p, r, q_goal=q_goal if last else None))
            q_from = plans[-1][-1]
    except SimulationError as exc:
        raise ConfigError(
            f"the move to the start would pass through the part at {where} m, and the way over its top, at z = "
            f"{z_cross:.2f} m, is out of the arm's reach ({exc}): place the part lower or nearer the robot") from exc
    _run(loop, [*legs, *round_legs], plans, None, q_goal, settle_s)
    passed = ("went through it" if path.min() < 0.0 else
              f"passed {1e3 * path.min():.1f} mm from it, under {1e3 * TRANSIT_CLEARANCE_M:.0f} mm")
    return "; ".join([*said, f"over the part at z = {z_cross:.2f} m (the direct move {passed})"])


def _run(loop: ControlLoop, legs: list[tuple[np.ndarray, np.ndarray]], plans: list[list[np.ndarray]],
         q_last: np.ndarray | None, q_goal: np.ndarray | None, settle_s: float) -> None:
    """Move along the planned Cartesian legs, then to ``q_last`` by a joint move when given; the last move
    settles ``settle_s`` [s], the others a tenth of a second."""
    for i, ((p, r), plan) in enumerate(zip(legs, plans, strict=True)):
        final = q_last is None and i == len(legs) - 1
        loop.move_cartesian(p, r, path=plan, q_goal=q_goal if final else None, settle_s=settle_s if final else 0.1)
    if q_last is not None:
        loop.move_joints(q_last, settle_s=settle_s)
