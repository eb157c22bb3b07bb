"""A transit to a pose near the part that keeps the tool clear of it.

A joint move between two postures sweeps the tool along a curve nobody planned: from the arm's home to
a start just above a part placed high (or tall), it can pass through the part. :func:`move_clear_of_part`
plans the move against the part's nominal shape before the arm moves. A tool that starts nearer the part
than :data:`TRANSIT_CLEARANCE_M` (a run stopped on it, an approach that gave up past the surface, a part
declared where the tool already is) first moves straight away from it (up over a height field, out from a
cup's axis), which brings no point of it nearer. Then the direct joint move, if the tool keeps
:data:`TRANSIT_CLEARANCE_M` (or the goal's own clearance, if less) all along it, sampled in joint space as
the move follows it; else a way round: up to :data:`ABOVE_PART_M` over the part's top, across, and straight
down into the direct move's posture (the descent planned up from it), every waypoint solved and every joint
move between them checked before the first moves. With no clear way it refuses. The tool is points on its
surfaces no farther apart than the clearance (:func:`tool_points`), the arm's links the kinematic model's
capsules (:func:`link_points`: an approximation of the Panda's shape, not its exact hull). The
part is the solid over its footprint from its base (``base_m`` below its frame) to its height field, its
clearance measured vertically over the footprint (on a slope the true distance is shorter), or the cup's
cylinder taken as solid (:func:`clearance_m`).
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tactex.errors import ConfigError, SimulationError
from tactex.pointcloud.shapes import CylinderWallSurface, HeightFieldSurface, Surface
from tactex.robots.loop import ControlLoop
from tactex.sim.tool import ToolGeometry

__all__ = ["ABOVE_PART_M", "MAX_BACK_OUT_M", "PATH_SAMPLES", "SAMPLE_STEP_M", "TRANSIT_CLEARANCE_M", "PartShape",
           "clearance_m", "link_points", "move_clear_of_part", "path_clearance_m", "polyline_clearance_m",
           "tool_points"]

#: The least distance between the tool and the part a transit keeps [m] (or the goal's own, if less).
TRANSIT_CLEARANCE_M = 0.005

#: How high over the part's top a transit that goes round it crosses [m] (plus the pad's radius).
ABOVE_PART_M = 0.05

#: The furthest a tool that starts too near the part moves away from it to free itself [m].
MAX_BACK_OUT_M = 0.30

#: Postures sampled along a path for its clearance, at the least [-].
PATH_SAMPLES = 60

#: The furthest a point of the tool moves between two samples of a path [m].
SAMPLE_STEP_M = 0.002

#: The F/T sensor's disc and the tool body's radii, and the camera's box half sizes in the tool frame [m] (as
#: :func:`tactex.sim.tool.tool_xml` draws them).
_SENSOR_RADIUS_M = 0.04
_BODY_RADIUS_M = 0.02
_CAMERA_HALF_M = (0.0125, 0.045, 0.0125)

#: A planned Cartesian leg: where the TCP ends [m] and its rotation, the joint waypoints [rad] to it, and the
#: posture it must end in (None: its own last waypoint).
_Leg = tuple[np.ndarray, np.ndarray, list[np.ndarray], np.ndarray | None]


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


def _disc(radius: float, z: float, spacing: float) -> np.ndarray:
    """Points of a disc in a plane z = const of the tool frame, no two neighbours farther than ``spacing``."""
    out = [np.array([[0.0, 0.0, z]])]
    for rk in np.linspace(0.0, radius, math.ceil(radius / spacing) + 1)[1:]:
        a = np.linspace(0.0, 2.0 * np.pi, math.ceil(2.0 * np.pi * rk / spacing), endpoint=False)
        out.append(np.column_stack([rk * np.cos(a), rk * np.sin(a), np.full(a.size, z)]))
    return np.vstack(out)


def _cylinder_side(radius: float, z0: float, z1: float, spacing: float) -> np.ndarray:
    a = np.linspace(0.0, 2.0 * np.pi, math.ceil(2.0 * np.pi * radius / spacing), endpoint=False)
    zs = np.linspace(z0, z1, math.ceil(abs(z1 - z0) / spacing) + 1)
    return np.array([[radius * math.cos(t), radius * math.sin(t), z] for z in zs for t in a])


def _box_surface(centre: np.ndarray, half: tuple[float, float, float], spacing: float) -> np.ndarray:
    grids = [np.linspace(-h, h, math.ceil(2.0 * h / spacing) + 1) for h in half]
    pts = np.array([[x, y, z] for x in grids[0] for y in grids[1] for z in grids[2]])
    on_face = np.any(np.isclose(np.abs(pts), half), axis=1)
    return centre + pts[on_face]


@functools.lru_cache(maxsize=8)
def _tool_frame_points(tool: ToolGeometry) -> np.ndarray:
    """(K, 3) [m] points on the tool's surfaces in the tool frame at the TCP (z out of the pad), no two
    neighbours farther apart than :data:`TRANSIT_CLEARANCE_M` (nothing reaches into the tool between them by
    more than the clearance unseen): the pad, the body's cylinder, the F/T sensor's disc and the camera's box
    (as :func:`tactex.sim.tool.tool_xml` draws them). The pad's centre comes first."""
    s = TRANSIT_CLEARANCE_M
    pt, bl, length = tool.pad_thickness_m, tool.body_length_m, tool.tcp_offset_m
    return np.vstack([
        _disc(tool.pad_radius_m, 0.0, s), _cylinder_side(tool.pad_radius_m, 0.0, -pt, s),
        _disc(tool.pad_radius_m, -pt, s), _cylinder_side(_BODY_RADIUS_M, -pt, -(pt + bl), s),
        _disc(_SENSOR_RADIUS_M, -(pt + bl), s), _cylinder_side(_SENSOR_RADIUS_M, -(pt + bl), -length, s),
        _disc(_SENSOR_RADIUS_M, -length, s),
        _box_surface(np.array([0.0, 0.0, -length]) + np.asarray(tool.camera_offset_m), _CAMERA_HALF_M, s)])


def tool_points(p_tcp_world: np.ndarray, r_tcp_world: np.ndarray, tool: ToolGeometry) -> np.ndarray:
    """(K, 3) [m] points on the tool's surfaces at a TCP pose (world frame), the pad's centre first
    (:func:`_tool_frame_points`)."""
    return np.asarray(p_tcp_world, dtype=float) + _tool_frame_points(tool) @ np.asarray(r_tcp_world, dtype=float).T


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


def link_points(ends_m: np.ndarray, radii_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points (L, 3) [m] along the axes of capsules (ends (K, 2, 3) [m]) no farther apart than
    :data:`TRANSIT_CLEARANCE_M`, and each one's capsule radius (L,) [m]: a point's clearance less its radius is
    its ball's, and the balls along an axis this dense make up the capsule to under a tenth of a millimetre."""
    ends = np.asarray(ends_m, dtype=float)
    # rounded first: a capsule keeps its count of points at every posture (its length moves by round-off only)
    n = np.maximum(np.ceil(np.round(np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1) / TRANSIT_CLEARANCE_M, 6)), 1)
    n = n.astype(int) + 1
    s = [np.linspace(0.0, 1.0, k)[:, None] for k in n]
    pts = np.concatenate([a + si * (b - a) for (a, b), si in zip(ends, s, strict=True)])
    return pts, np.repeat(np.asarray(radii_m, dtype=float), n)


def _robot_points(loop: ControlLoop, q: np.ndarray, tool: ToolGeometry) -> tuple[np.ndarray, np.ndarray]:
    """The points (P, 3) [m] of the tool (:func:`tool_points`) and of the arm's links (:func:`link_points`, when
    the backend models them) at posture ``q`` [rad], and how far each one's surface lies out from it (P,) [m]: 0
    on the tool's surfaces, the capsule's radius on a link's axis."""
    pts = tool_points(*loop.tcp_pose(q), tool)
    links = loop.link_capsules(q)
    if links is None:
        return pts, np.zeros(len(pts))
    axis, radii = link_points(*links)
    return np.vstack([pts, axis]), np.concatenate([np.zeros(len(pts)), radii])


def _sampled(tool_points_at: Callable[[float], np.ndarray], n: int = PATH_SAMPLES) -> np.ndarray:
    """(n', K, 3) [m] the robot's points at n' >= ``n`` evenly spaced fractions s in [0, 1] of a path
    (``tool_points_at(s)``), so fine that no point moves more than :data:`SAMPLE_STEP_M` between two samples
    (a thin part between two samples would be missed)."""
    while True:
        pts = np.stack([tool_points_at(s) for s in np.linspace(0.0, 1.0, n)])
        step = float(np.linalg.norm(np.diff(pts, axis=0), axis=2).max()) if n > 1 else 0.0
        if step <= SAMPLE_STEP_M * (1.0 + 1e-9):
            return pts
        n = math.ceil((n - 1) * step / SAMPLE_STEP_M) + 1  # a straight path needs no more; a curved one loops


def path_clearance_m(loop: ControlLoop, q_from: np.ndarray, q_to: np.ndarray, part: PartShape,
                     tool: ToolGeometry, min_samples: int = PATH_SAMPLES) -> np.ndarray:
    """(n,) [m] the robot's least clearance from the part (its tool's and its links', :func:`_robot_points`) at
    postures along the joint move from ``q_from`` to ``q_to`` [rad] (a straight line in joint space, as
    :meth:`ControlLoop.move_joints` goes from rest), both ends included, at least ``min_samples`` of them."""
    if loop.tcp_pose(q_from) is None:
        raise ConfigError("this robot's backend has no kinematic model: the transit's clearance cannot be checked")
    out = _robot_points(loop, q_from, tool)[1]
    pts = _sampled(lambda s: _robot_points(loop, q_from + s * (q_to - q_from), tool)[0], min_samples)
    return (part.clearance_m(pts.reshape(-1, 3)).reshape(len(pts), -1) - out).min(axis=1)


def polyline_clearance_m(loop: ControlLoop, postures: list[np.ndarray], part: PartShape, tool: ToolGeometry) -> float:
    """[m] the robot's least clearance from the part along joint moves through ``postures`` [rad] in turn (the
    waypoints a planned route moves through)."""
    return min((float(path_clearance_m(loop, a, b, part, tool, min_samples=2).min())
                for a, b in itertools.pairwise(postures)), default=math.inf)


def _away(part: PartShape, p_world: np.ndarray) -> np.ndarray:
    """The unit direction [world] in which every point's clearance grows: up the part's z over a height field,
    out from the cup's axis beside it."""
    if isinstance(part.surface, CylinderWallSurface):
        local = (np.asarray(p_world, dtype=float) - part.position_m) @ part.rotation
        radial = np.array([local[0], local[1], 0.0])
        if np.linalg.norm(radial) > 1e-9:
            return part.rotation @ (radial / np.linalg.norm(radial))
    return part.rotation[:, 2].copy()


def _back_out(p_now: np.ndarray, r_now: np.ndarray, part: PartShape, tool: ToolGeometry) -> np.ndarray | None:
    """Where the TCP [m] is first :data:`TRANSIT_CLEARANCE_M` clear of the part moving away from it
    (:func:`_away`, the tool's orientation kept; within :data:`MAX_BACK_OUT_M`), or None."""
    away = _away(part, p_now)
    for d in np.arange(SAMPLE_STEP_M, MAX_BACK_OUT_M + 1e-9, SAMPLE_STEP_M):
        p = p_now + d * away
        if part.clearance_m(tool_points(p, r_now, tool)).min() >= TRANSIT_CLEARANCE_M:
            return p
    return None


def _passed(least_m: float) -> str:
    return ("went through it" if least_m < -1e-3 else "touched it" if least_m < 0.0 else
            f"passed {1e3 * least_m:.1f} mm from it, under {1e3 * TRANSIT_CLEARANCE_M:.0f} mm")


def _route_over(loop: ControlLoop, part: PartShape, tool: ToolGeometry, q_from: np.ndarray, p_from: np.ndarray,
                r_from: np.ndarray, q_goal: np.ndarray, p_goal: np.ndarray,
                r_goal: np.ndarray) -> tuple[list[_Leg], float]:
    """The legs over the part from the TCP at ``p_from`` [m], ``r_from`` (posture ``q_from`` [rad]) to the goal
    pose in posture ``q_goal``: up to the crossing height, across, down; and that height [m]. Raises
    SimulationError where the IK cannot follow them."""
    z_cross = max(part.top_z_m() + ABOVE_PART_M + tool.pad_radius_m, float(p_goal[2]))
    p_above = np.array([p_goal[0], p_goal[1], z_cross])
    route: list[_Leg] = []
    q = q_from
    if p_from[2] < z_cross:
        p_up = np.array([p_from[0], p_from[1], z_cross])
        route.append((p_up, r_from, loop.cartesian_path(p_from, r_from, q, p_up, r_from), None))
        p_from, q = p_up, route[-1][2][-1]
    if np.linalg.norm(p_above - p_goal) > 1e-6:
        # the descent planned up from the goal's posture, on its branch: the across leg ends where it begins
        down = loop.cartesian_path(p_goal, r_goal, q_goal, p_above, r_goal)
        route.append((p_above, r_goal, loop.cartesian_path(p_from, r_from, q, p_above, r_goal, q_goal=down[-1]),
                      down[-1]))
        route.append((p_goal, r_goal, [*reversed(down[:-1]), q_goal], q_goal))
    else:
        route.append((p_goal, r_goal, loop.cartesian_path(p_from, r_from, q, p_goal, r_goal, q_goal=q_goal), q_goal))
    return route, z_cross


def move_clear_of_part(loop: ControlLoop, p_goal_world: np.ndarray, r_goal_world: np.ndarray, part: PartShape,
                       tool: ToolGeometry, settle_s: float = 0.5) -> str:
    """Move the TCP to a pose near the part [m, rotation], clear of it (module docstring); returns ``"direct"``,
    or how it went (backed out first, round over the part) and why. Raises :class:`ConfigError` before the arm
    moves when there is no clear way (the arm stands under or against the part) or the way is out of reach. The
    goal's posture is the direct move's (the IK solution from the current posture), however it went."""
    q_now, p_now, r_now = loop.state.q.copy(), loop.state.ee_position.copy(), loop.state.ee_rotation.copy()
    q_goal = loop.solve_pose(p_goal_world, r_goal_world)
    where = np.round(np.asarray(part.position_m if part.placed_m is None else part.placed_m, dtype=float), 3).tolist()
    moves: list[_Leg] = []  # moving away from the part first
    said: list[str] = []
    q_from, p_from = q_now, p_now
    start_clear = float(part.clearance_m(tool_points(p_now, r_now, tool)).min())
    try:  # planned whole before the arm moves
        if start_clear < TRANSIT_CLEARANCE_M:
            p_out = _back_out(p_now, r_now, part, tool)
            stands = (f"{1e3 * -start_clear:.0f} mm inside the part" if start_clear < -1e-3 else
                      "touching the part" if start_clear < 0.0 else f"{1e3 * start_clear:.0f} mm from the part")
            out = [] if p_out is None else loop.cartesian_path(p_now, r_now, q_now, p_out, r_now)
            # the way out (tool and links) nearer than the tool stands: a link as near refuses it too (the arm
            # stands against the part), on the safe side
            deeper = p_out is not None and polyline_clearance_m(loop, [q_now, *out], part, tool) < start_clear - 1e-3
            if p_out is None or deeper:
                why = ("moving it away from the part would bring it nearer first (the arm stands under or against "
                       "the part)" if deeper else f"moving it {1e3 * MAX_BACK_OUT_M:.0f} mm away does not free it")
                raise ConfigError(f"the tool stands {stands} placed at {where} m, and {why}: check --object-position, "
                                  "or move the arm clear (Franka's guiding mode)")
            moves.append((p_out, r_now, out, None))
            said.append(f"backed out {1e3 * np.linalg.norm(p_out - p_now):.0f} mm first (the tool stood {stands} as "
                        "placed)")
            q_from, p_from = out[-1], p_out
        direct = path_clearance_m(loop, q_from, q_goal, part, tool)
        need = min(TRANSIT_CLEARANCE_M, direct[-1]) - 1e-3
        route, z_cross = (([], 0.0) if direct.min() >= need else
                          _route_over(loop, part, tool, q_from, p_from, r_now, q_goal, p_goal_world, r_goal_world))
    except SimulationError as exc:
        raise ConfigError(
            f"the move to the start near the part at {where} m needs a way out of the arm's reach ({exc}): place "
            "the part lower or nearer the robot") from exc
    if not route:  # the direct move; an error while the arm moves is the move's own, not the plan's
        _run(loop, moves, settle_s, q_goal)
        return "; ".join([*said, "then direct"]) if said else "direct"
    least = polyline_clearance_m(loop, [q_from, *(q for m in route for q in m[2])], part, tool)
    if least < need:
        raise ConfigError(
            f"no clear way to the start: the direct move {_passed(direct.min())} (the part at {where} m), and the way "
            f"over it (up to z = {z_cross:.2f} m, across, down) would " + (
                f"bring the tool or the arm within {1e3 * least:.1f} mm of it" if least >= 0.0 else
                "pass through it too")
            + " (the arm stands under or against the part): place the part elsewhere")
    _run(loop, moves + route, settle_s)
    return "; ".join([*said, f"over the part at z = {z_cross:.2f} m (the direct move {_passed(direct.min())})"])


def _run(loop: ControlLoop, moves: list[_Leg], settle_s: float, q_last: np.ndarray | None = None) -> None:
    """Move along the planned Cartesian legs (TCP position, rotation, waypoints, the posture each ends in), then to
    ``q_last`` by a joint move when given; the last move settles ``settle_s`` [s], the others a tenth of a second."""
    for i, (p, r, path, q_end) in enumerate(moves):
        final = q_last is None and i == len(moves) - 1
        loop.move_cartesian(p, r, path=path, q_goal=q_end, settle_s=settle_s if final else 0.1)
    if q_last is not None:
        loop.move_joints(q_last, settle_s=settle_s)
