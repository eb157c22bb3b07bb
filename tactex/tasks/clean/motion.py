"""The clean's moves out of contact and onto the surface: where the camera looks from, the hover over a
touch-down and the joint moves there, the first touch-down the arm reaches soonest, the approach speed,
the pad kept above the table and the lift-off."""

from __future__ import annotations

import warnings

import numpy as np

from tactex.control.references import LineForceReference
from tactex.ergodic.command import ExplorationCommand
from tactex.errors import SimulationError
from tactex.perception.acquisition import AcquisitionConfig
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.pointcloud.shapes import CylinderWallSurface
from tactex.robots.loop import ControlLoop
from tactex.sim.scene import SceneConfig
from tactex.tasks.clean.config import CleanConfig
from tactex.tasks.runner import tool_rotation_for_normal
from tactex.tasks.vision import workspace_crop

#: Lift-off distance along the tool axis before vision and at the end [m].
RETRACT_M = 0.05
#: Longest single step of a lift-off [m]: each step is one linearised joint move (ControlLoop.retract), whose
#: error grows with the square of its length; on a curved wall a long step moves the tool along the wall,
#: dragging the pad, instead of out of it.
RETRACT_STEP_M = 0.025
#: Time over which the pressing force ramps to zero before a lift-off from contact [s]: the lift's joint
#: controller then takes over an arm that no longer presses. Handed over while pressing, the pad's and the
#: arm's compression springs back under the joint controller's blend, which on franky-sim's arm (the twin)
#: rang at its shoulder.
UNLOAD_S = 0.25
#: Height of the waypoints above the hover pose on the way from the capture pose, and above the
#: retracted tool on the way back to it [m].
CLEARANCE_M = 0.08
#: Largest joint difference [rad] between the waypoint and the hover for the waypoint to be used.
WAYPOINT_MAX_JOINT_RAD = 0.5
#: Largest turn [rad] of a joint of :data:`WRIST_BEND_JOINTS` in a joint move that starts low over the object (after a
#: lift-off); a farther one goes up to the capture posture first (:func:`_detour_via_capture`). In the bench's
#: cleans the moves that bent the wrist by 1.3-1.5 rad in a bowl swung the tool against its wall or near it, those
#: of about 0.6 rad passed clear of the cup and the bowl.
LOW_MOVE_MAX_JOINT_RAD = 1.0
#: Closest the pad's disc may come to the captured surface on a joint move's way from low over the object [m]: half
#: the hover height (CleanConfig.hover_height_m), so the move's own ends, a hover and a lift-off, are clear of it.
SWEEP_CLEARANCE_M = 0.015
#: Postures checked along a joint move's path (ends included) [-]: on a move of a radian or two, a few centimetres
#: of the tool's travel between two of them.
SWEEP_CHECK_SAMPLES = 32
#: The Franka's joints that swing the tool's tip about the wrist: the forearm's roll and the wrist's pitch (joints 5
#: and 6; indices into q).
WRIST_BEND_JOINTS = [4, 5]
#: A posture this close to the capture posture in every joint [rad] is at the capture pose (the joint move's
#: tracking error, a real arm's measurement noise): its moves start high above the object.
AT_CAPTURE_JOINT_RAD = 0.05
#: Settling after the joint move to the hover pose, before the approach [s].
HOVER_SETTLE_S = 0.1
#: How fast the commanded approach speed falls with the height above the captured surface [1/s]: it reaches
#: zero at CleanConfig.approach_slow_m over about 1 / APPROACH_GAIN_PER_S, time enough for the line's damping
#: (D_z = 50 N·s/m on a few kg of tool) to brake.
APPROACH_GAIN_PER_S = 10.0
#: ... and rises from rest no faster than this [m/s²]: a step of D_z·v in the push shakes the tool, whose
#: inertia the F/T reads as a force above the touch-down threshold.
APPROACH_ACCEL_M_S2 = 1.0
#: A touch-down low on a wall is raised so the pad's rim clears the support by this much [m]: the joint move
#: down to the hover undershoots it by a millimetre or two, and a rim on the table stops the tool with a jolt.
TOUCH_DOWN_CLEARANCE_M = 0.005
#: Height of the table top the simulated objects stand on [m] (tactex.sim.scene): the capture's crop cuts the
#: table above it and the pad is kept above it.
SUPPORT_Z_M = 0.0
#: tactex's first touch-down (:func:`_quickest_touch_down`): candidates on the dirt one per cell of this grid
#: [m] (at most START_CANDIDATES, the grid widened until so), each a joint-move plan from the capture posture
#: (two IK solves).
START_SPACING_M = 0.01
START_CANDIDATES = 64
#: Their IK stops once its steps are below this [rad]: the steps shrink geometrically to a fixed point, so the
#: planned duration is then far closer to the full search's than the 10 ms the choice compares.
START_SETTLED_STEP_RAD = 1e-5
#: ... and gives up after this many steps: a reachable hover settles well within them, while one at the edge
#: of the reach would chatter for the full search's 500 before it is refused.
START_IK_STEPS = 150


def _lag_m(tcp_m: np.ndarray, cmd: ExplorationCommand) -> float:
    """How far the tool at ``tcp_m`` (3,) [m] is from the commanded point along the surface (its offset
    along the normal left out) [m]."""
    d = np.asarray(tcp_m, dtype=float) - cmd.point
    d = d - float(d @ cmd.normal) * cmd.normal
    return float(np.sqrt(d @ d))



def _capture_pose(scene: SceneConfig, cfg: CleanConfig) -> tuple[np.ndarray, np.ndarray]:
    """Where the robot looks from: above a height field, beside a cylinder wall (camera ⟂ surface)."""
    pos, rot = scene.object_pose()
    surface = scene.sim_object.surface
    if isinstance(surface, CylinderWallSurface):
        out = rot @ np.array([0.0, -1.0, 0.0])  # the side the cup's marking faces
        centre = pos + rot @ np.array([0.0, 0.0, surface.height_m / 2])
        up = rot @ np.array([0.0, 0.0, 1.0])
        el = np.radians(cfg.side_capture_elevation_deg)
        view = np.cos(el) * out + np.sin(el) * up  # from the wall's mid-height towards the camera
        return (centre + out * surface.radius_m + view * cfg.side_capture_distance_m,
                tool_rotation_for_normal(view))
    top = pos + rot @ np.array([0.0, 0.0, float(surface.bounds_m[1, 2])])
    return top + np.array([0.0, 0.0, cfg.capture_distance_m]), tool_rotation_for_normal(np.array([0.0, 0.0, 1.0]))


def _hover_plan(loop: ControlLoop, point_m: np.ndarray, normal: np.ndarray, q_seed: np.ndarray,
                hover_height_m: float, q_from: np.ndarray | None = None, q_hover: np.ndarray | None = None,
                settled_step_rad: float | None = None, max_iter: int | None = None,
                ) -> tuple[np.ndarray | None, np.ndarray, float]:
    """The joint moves from ``q_from`` (default: the current posture) to the hover ``hover_height_m`` [m] above
    ``point_m`` along ``normal``: ``(q_above, q_hover, move_s)``, ``q_above`` the waypoint :data:`CLEARANCE_M`
    straight above the hover (None when it is not a short step from it) and ``move_s`` [s] the moves'
    duration. IK is searched from ``q_seed`` (``q_hover``: the hover's posture when already solved;
    ``settled_step_rad``: :meth:`ControlLoop.solve_pose`'s, ``max_iter`` its for the hover). Raises
    SimulationError when the hover is out of the arm's reach."""
    rot = tool_rotation_for_normal(normal)
    hover = np.asarray(point_m, dtype=float) + hover_height_m * np.asarray(normal, dtype=float)
    if q_hover is None:
        q_hover = loop.solve_pose(hover, rot, q_seed=q_seed, settled_step_rad=settled_step_rad, max_iter=max_iter)
    # Through a waypoint straight above the hover pose: a joint move from the high capture pose down to a
    # hover inside a bowl can swing the tool through the rim on the way. The waypoint is solved from the hover
    # (same IK branch) and dropped when it is not a short step from it.
    try:
        # never cut short by max_iter: a waypoint given up on would make the plan the (quicker) direct move
        q_above: np.ndarray | None = loop.solve_pose(hover + np.array([0.0, 0.0, CLEARANCE_M]), rot, q_seed=q_hover,
                                                     settled_step_rad=settled_step_rad)
    except SimulationError:
        q_above = None
    if q_above is not None and float(np.max(np.abs(q_above - q_hover))) > WAYPOINT_MAX_JOINT_RAD:
        q_above = None
    if q_above is None:
        return None, q_hover, loop.joint_move_duration(q_hover, q_from=q_from)
    return q_above, q_hover, (loop.joint_move_duration(q_above, q_from=q_from)
                              + loop.joint_move_duration(q_hover, q_from=q_above))


def _detour_via_capture(loop: ControlLoop, q_first: np.ndarray, q_capture: np.ndarray, surface=None,
                        pad_radius_m: float = 0.0) -> float | None:
    """The extra time [s] of a joint move to ``q_first`` (7,) [rad] that goes up to the capture posture ``q_capture``
    first, or None for the direct move: a move that starts low over the object (away from the capture posture,
    after a lift-off) goes up first when it turns the forearm's roll or the wrist's pitch (:data:`WRIST_BEND_JOINTS`)
    by more than :data:`LOW_MOVE_MAX_JOINT_RAD`, which swings the tool's tip, a tool length from the wrist, through
    the object (down a bowl's far wall), or when its path brings the pad within :data:`SWEEP_CLEARANCE_M` of the
    captured surface (``surface``: a KD-tree of its points [m], or None; :func:`passes_near`); from high above the
    object it clears it."""
    q_now = loop.state.q
    if float(np.max(np.abs(q_now - q_capture))) <= AT_CAPTURE_JOINT_RAD:
        return None
    if (float(np.max(np.abs(q_first - q_now)[WRIST_BEND_JOINTS])) <= LOW_MOVE_MAX_JOINT_RAD
            and (surface is None or not passes_near(loop, q_now, q_first, surface, pad_radius_m))):
        return None
    return (loop.joint_move_duration(q_capture) + loop.joint_move_duration(q_first, q_from=q_capture)
            - loop.joint_move_duration(q_first))


def passes_near(loop: ControlLoop, q_from: np.ndarray, q_to: np.ndarray, surface, pad_radius_m: float,
                clearance_m: float = SWEEP_CLEARANCE_M) -> bool:
    """Whether the joint move ``q_from`` → ``q_to`` (7,) [rad] brings the pad, a disc of ``pad_radius_m`` [m] at the
    TCP ⟂ the tool axis, within ``clearance_m`` [m] of the captured surface (``surface``: a KD-tree of its points
    [m]) on its way: the posture sampled along the move's straight line in joint space (a minimum-jerk move keeps to
    it), the ends left out (a lift-off's and a hover's own heights are above the clearance). False from a backend
    without a kinematic model."""
    q_from, q_to = np.asarray(q_from, dtype=float), np.asarray(q_to, dtype=float)
    ring = np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)
    disc = np.vstack([[0.0, 0.0], pad_radius_m * np.column_stack([np.cos(ring), np.sin(ring)])])  # (9, 2) [m]
    for s in np.linspace(0.0, 1.0, SWEEP_CHECK_SAMPLES)[1:-1]:
        pose = loop.tcp_pose(q_from + s * (q_to - q_from))
        if pose is None:
            return False
        position, rotation = pose
        pad = position + disc @ rotation[:, :2].T
        if float(surface.query(pad)[0].min()) < clearance_m:
            return True
    return False


def _quickest_touch_down(loop: ControlLoop, cloud: SurfaceCloud, targets: np.ndarray, q_capture: np.ndarray,
                         cap_pos: np.ndarray, hover_height_m: float) -> tuple[np.ndarray, float] | None:
    """tactex's first touch-down [m] and the planned moves' duration to its hover [s]: of the dirty points
    ``targets`` (indices into ``cloud``), one per cell of a grid (:data:`START_SPACING_M`, coarser until at most
    :data:`START_CANDIDATES` are left), the one whose hover the arm reaches soonest from the capture posture
    ``q_capture`` (the moves :func:`_hover_plan` plans), and of those equally quick (to 10 ms) the nearest to
    the camera at ``cap_pos`` [m]. None when the cloud has no normals or no candidate's hover is within reach.

    It is wall-clock work while the robot holds at the capture pose, so it is kept cheap: each candidate's hover
    posture is solved once (the IK stops when its steps settle, :data:`START_SETTLED_STEP_RAD`, and gives up
    after :data:`START_IK_STEPS`), and the direct joint move to it, a lower bound on the planned moves (the
    min-jerk duration is subadditive), orders the candidates; the waypoint above the hover is solved only while
    that bound can still beat the best plan."""
    if cloud.normals is None or targets.size == 0:
        return None
    pts = cloud.points[targets]
    spacing = START_SPACING_M
    while True:
        _, first = np.unique(np.floor(pts / spacing).astype(np.int64), axis=0, return_index=True)
        if first.size <= START_CANDIDATES:
            break
        spacing *= 1.5
    bounded: list[tuple[tuple[float, float], int, np.ndarray]] = []
    for j in np.sort(first):
        normal = cloud.normals[targets[j]]
        hover = pts[j] + hover_height_m * normal
        try:
            q_hover = loop.solve_pose(hover, tool_rotation_for_normal(normal), q_seed=q_capture,
                                      settled_step_rad=START_SETTLED_STEP_RAD, max_iter=START_IK_STEPS)
        except SimulationError:
            continue
        bound_s = loop.joint_move_duration(q_hover, q_from=q_capture)
        bounded.append(((round(bound_s, 2), float(np.linalg.norm(pts[j] - cap_pos))), int(j), q_hover))
    bounded.sort(key=lambda c: (c[0], c[1]))
    best: tuple[float, float] | None = None
    chosen: tuple[np.ndarray, float] | None = None
    for bound_key, j, q_hover in bounded:
        if best is not None and bound_key > best:
            break  # this and every later candidate takes at least as long as the best plan
        move_s = _hover_plan(loop, pts[j], cloud.normals[targets[j]], q_capture, hover_height_m, q_from=q_capture,
                             q_hover=q_hover, settled_step_rad=START_SETTLED_STEP_RAD)[2]
        key = (round(move_s, 2), bound_key[1])
        if best is None or key < best:
            best, chosen = key, (pts[j].copy(), move_s)
    return chosen


def _approach_speed(tcp_m: np.ndarray, cmd: ExplorationCommand, cfg: CleanConfig) -> float:
    """The approach speed [m/s] commanded with the tool at ``tcp_m`` (3,) [m] over ``cmd``'s point: falling
    in proportion to the height above the captured surface (:data:`APPROACH_GAIN_PER_S`) from
    ``cfg.approach_speed_m_s`` to zero at ``cfg.approach_slow_m``, below which the force loop's own slow
    approach touches down."""
    height_m = float((np.asarray(tcp_m, dtype=float) - cmd.point) @ cmd.normal)
    return float(np.clip(APPROACH_GAIN_PER_S * (height_m - cfg.approach_slow_m), 0.0, cfg.approach_speed_m_s))


def _pad_over_support(point_m: np.ndarray, normal: np.ndarray, support_z_m: float, pad_radius_m: float,
                      clearance_m: float = 0.0) -> np.ndarray:
    """The commanded line's point ``point_m`` (3,) [m], raised along world z where needed so that the pad, a disc
    of ``pad_radius_m`` [m] centred there and ⟂ ``normal`` (3,), stays above the support plane z = ``support_z_m``
    [m], by ``clearance_m`` [m] on a wall (less as the disc tilts towards level, where its rim does not dip): at
    the foot of a wall the line through the lowest captured ring would press the pad's rim into the table, which
    would then hold the tool off the wall while the line drags it sideways."""
    n = np.asarray(normal, dtype=float)
    n_z2 = float(n[2] * n[2]) / max(float(n @ n), 1e-12)
    tilt = float(np.sqrt(max(1.0 - n_z2, 0.0)))  # how far the disc's rim dips below its centre, per radius
    low = support_z_m + (pad_radius_m + clearance_m) * tilt
    if point_m[2] >= low:
        return point_m
    out = np.array(point_m, dtype=float)
    out[2] = low
    return out


def _touchable(indices: np.ndarray, touch_down_ok: np.ndarray | None) -> np.ndarray:
    """The cloud points ``indices`` a touch-down may be at (``touch_down_ok`` (N,) bool; None: all), or all of
    them when none is (the dirt left lies only beside a keep-out zone)."""
    if touch_down_ok is not None and touch_down_ok[indices].any():
        return indices[touch_down_ok[indices]]
    return indices


def _straight_away(loop: ControlLoop, hold_s: float, along_tool_axis: bool) -> None:
    """By :data:`CLEARANCE_M` straight up, or back along the tool axis (``along_tool_axis``), along a line of IK
    waypoints (:meth:`ControlLoop.move_cartesian`, one smooth joint path); a single linearised step from a bent
    posture moves sideways too. ``hold_s`` [s]: a hold before the line's IK (on a real robot the IK pauses torque
    control and the robot holds the arm meanwhile; one still moving would be elsewhere when the next command comes,
    a step of the joint spring's torque). Where the line leaves the arm's reach, one linearised step instead."""
    if hold_s > 0.0:
        loop.hold(hold_s)
    direction = -loop.state.ee_rotation[:, 2] if along_tool_axis else np.array([0.0, 0.0, 1.0])
    try:
        loop.move_cartesian(loop.state.ee_position + CLEARANCE_M * direction, loop.state.ee_rotation, settle_s=0.0)
    except SimulationError:
        loop.retract(CLEARANCE_M, duration_s=0.4, direction_world=direction)


def rise(loop: ControlLoop, hold_s: float = 0.0) -> None:
    """Straight up by :data:`CLEARANCE_M` (:func:`_straight_away`; ``hold_s`` [s] a hold before it)."""
    _straight_away(loop, hold_s, along_tool_axis=False)


def back_off(loop: ControlLoop, hold_s: float = 0.0) -> None:
    """Straight back along the tool axis (away from the surface the tool last pressed) by :data:`CLEARANCE_M`
    (:func:`_straight_away`; ``hold_s`` [s] a hold before it)."""
    _straight_away(loop, hold_s, along_tool_axis=True)


def rise_to_capture(loop: ControlLoop, cap_pos_m: np.ndarray, cap_rot: np.ndarray, q_capture: np.ndarray,
                    hold_s: float = 0.0) -> None:
    """From low over the object (after a lift-off) towards the capture pose ``cap_pos_m`` (3,) [m], ``cap_rot``
    (3, 3), posture ``q_capture`` (7,) [rad]: :func:`rise`, then along the straight line to the capture pose through
    IK waypoints. A single joint move from inside a bowl can swing the tool through its wall on the way. Without a
    straight way the caller's joint move to ``q_capture`` still reaches the camera."""
    rise(loop, hold_s)
    if hold_s > 0.0:
        loop.hold(hold_s)
    try:
        loop.move_cartesian(cap_pos_m, cap_rot, settle_s=0.0, q_goal=q_capture)
    except SimulationError as exc:
        warnings.warn(f"clean: no straight way back to the camera ({exc}); moving in joint space", RuntimeWarning,
                      stacklevel=3)


def clear_of_the_object(loop: ControlLoop, q_first: np.ndarray, cap_pos_m: np.ndarray, cap_rot: np.ndarray,
                        q_capture: np.ndarray, surface, pad_radius_m: float, hold_s: float = 0.0) -> str:
    """Before a joint move to ``q_first`` (7,) [rad] that :func:`_detour_via_capture` finds unsafe from low over the
    object: :func:`rise`; when the move from up there still brings the pad near the captured surface
    (:func:`passes_near`; ``surface`` a KD-tree of its points [m], ``pad_radius_m`` [m]), :func:`back_off` along the
    tool axis (up is along a cup's wall, out is away from it); when it still does, on to the capture posture
    (:func:`rise_to_capture`'s line, then the joint move to ``q_capture``). The way it went: ``"up"``, ``"out"`` or
    ``"capture"``. Going up or out first is a fraction of the trip to the capture posture and its way back."""
    for way, away in (("up", rise), ("out", back_off)):
        away(loop, hold_s)
        if not passes_near(loop, loop.state.q, q_first, surface, pad_radius_m) \
                and float(np.max(np.abs(q_first - loop.state.q)[WRIST_BEND_JOINTS])) <= LOW_MOVE_MAX_JOINT_RAD:
            return way
    if hold_s > 0.0:
        loop.hold(hold_s)
    try:
        loop.move_cartesian(cap_pos_m, cap_rot, settle_s=0.0, q_goal=q_capture)
    except SimulationError as exc:
        warnings.warn(f"clean: no straight way up to the camera ({exc}); moving in joint space", RuntimeWarning,
                      stacklevel=3)
    loop.move_joints(q_capture, settle_s=0.0)
    return "capture"


def _lift_off(loop: ControlLoop, distance_m: float, duration_s: float = 0.4,
              pressing: LineForceReference | None = None) -> None:
    """Back along the tool axis by ``distance_m`` [m] in steps of at most :data:`RETRACT_STEP_M`, each
    re-linearised where the last ended, taking ``duration_s`` [s] at least. From contact (``pressing``: the
    reference the pressing controller was last given), the force first ramps to zero along its line over
    :data:`UNLOAD_S`."""
    if pressing is not None and pressing.force_n > 0.0:
        t0 = loop.t
        while (left := 1.0 - (loop.t - t0) / UNLOAD_S) > 0.0:
            loop.tick(LineForceReference(pressing.point_world, pressing.normal_world, pressing.force_n * left))
    n = max(int(np.ceil(distance_m / RETRACT_STEP_M - 1e-9)), 1)
    for _ in range(n):
        loop.retract(distance_m / n, duration_s=duration_s / n)

def _acquisition(scene: SceneConfig) -> AcquisitionConfig:
    pos, _ = scene.object_pose()
    surface = scene.sim_object.surface
    half = float(np.max(np.abs(surface.bounds_m[:, :2]))) + 0.01
    if isinstance(surface, CylinderWallSurface):
        # the wall only: a view from above the wall also sees the cup's top, which is not the surface to clean
        # (2 mm below it, as the table is cut 2 mm above the table top)
        lo, hi = workspace_crop(pos, half, table_z_m=SUPPORT_Z_M, height_m=surface.height_m - 0.002)
    else:
        lo, hi = workspace_crop(pos, half, table_z_m=SUPPORT_Z_M)
    return AcquisitionConfig(crop_min_m=lo, crop_max_m=hi, voxel_size_m=0.0, sor_mean_k=20, sor_std_mul=2.0)



def _cloud_capture_pose(cloud: SurfaceCloud, cfg: CleanConfig) -> tuple[np.ndarray, np.ndarray]:
    """Above a user's cloud: its top, ``capture_distance_m`` higher, looking down."""
    lo, hi = cloud.points.min(axis=0), cloud.points.max(axis=0)
    top = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, hi[2]])
    return top + np.array([0.0, 0.0, cfg.capture_distance_m]), tool_rotation_for_normal(np.array([0.0, 0.0, 1.0]))
