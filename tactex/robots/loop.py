"""The 1 kHz loop over a backend: one safety layer, swappable controllers, joint moves between them.

The loop belongs to the robot stage, not to the tasks: a robot check holds the arm with it before
any task exists, and every task drives the robot through it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from tactex.control import joint_kernels
from tactex.control.controller import Controller
from tactex.control.joint_impedance import JointImpedanceController, JointTarget
from tactex.control.load_error import LoadErrorEstimator
from tactex.control.safety import SafetyLayer, SafetyLimits
from tactex.control.state import RobotState
from tactex.errors import InputError, SimulationError
from tactex.geometry import exp_so3, log_so3
from tactex.robots.backend import RobotBackend

__all__ = ["ControlLoop"]

#: Largest joint step [rad] from the last IK waypoint to a given end posture that move_cartesian
#: joins into its smooth path; a larger one is a separate joint move.
FINAL_LEG_RAD = 0.1

#: Damping [m] of the retract's least-squares step (keeps it bounded near singular postures).
RETRACT_DAMPING = 0.01


class ControlLoop:
    """Runs controllers on a backend tick by tick behind one :class:`SafetyLayer`.

    The safety layer (torque, torque-rate and joint limits, NaN guard, force trip) persists when
    the task switches controllers, so torque-rate limits hold across phase changes.

    Args:
        backend: the robot (simulated or real).
        limits: safety limits (Franka defaults).
        on_tick: called after every tick with (state, reference, controller) — logging, dirt, vision.
    """

    def __init__(self, backend: RobotBackend, limits: SafetyLimits | None = None,
                 on_tick: Callable[[RobotState, Any, Controller], None] | None = None,
                 max_joint_speed: float = 0.8) -> None:
        if not (np.isfinite(max_joint_speed) and max_joint_speed > 0):
            raise InputError(f"max_joint_speed must be a positive speed [rad/s], got {max_joint_speed!r}")
        self.backend = backend
        self.max_joint_speed = float(max_joint_speed)  # [rad/s] the joint moves' default peak speed
        # the task-space controllers' compiled kernels are built (or loaded) now, before the first tick:
        # a task builds its controllers between moves, while a real robot's torque control runs
        joint_kernels.kernels()
        self.joint = JointImpedanceController()
        self.safety = SafetyLayer(self.joint, limits)
        self.state = backend.state()
        self.safety.reset(self.state)
        self.on_tick = on_tick
        self._started: list[Controller] = [self.joint]  # controllers already reset once in this loop
        self._q_commanded: np.ndarray | None = None  # where the joint controller was last told to be [rad]

    @property
    def t(self) -> float:
        return float(self.state.t)

    def use(self, controller: Controller) -> None:
        """Switch the active controller; the safety layer stays. A controller is reset on the current
        state the first time this loop uses it and resumed afterwards (:meth:`Controller.resume`:
        its energy tanks keep what they hold, so switching back and forth creates no energy)."""
        if self.safety.inner is not controller:
            self.safety.inner = controller
            self._q_commanded = None
            if any(c is controller for c in self._started):
                controller.resume(self.state)
            else:
                self._started.append(controller)
                controller.reset(self.state)

    def tick(self, reference: Any, after_send: Callable[[RobotState], None] | None = None) -> RobotState:
        """One control cycle: the torque for the current state, sent, then the next state.

        ``after_send(state)`` runs once the torque computed from ``state`` is sent and before the next
        state is read: on a real robot that is time the robot spends executing the command, so
        bookkeeping placed there stays out of the cycle's critical path (state read → command sent).
        It must not command the robot."""
        if getattr(self.backend, "torque_paused", False):
            # a real robot holds itself while torque control is paused: the state held is from before the pause,
            # and a command computed on it would never be sent. Torque control starts again on a fresh state.
            self._next_state()
        state = self.state
        tau = self.safety.torque(state, reference)
        self.backend.apply_torque(tau)
        if after_send is not None:
            after_send(state)
        self._next_state()
        if self.on_tick is not None:
            self.on_tick(self.state, reference, self.safety.inner)
        return self.state

    def _next_state(self) -> None:
        self.state = self.backend.step()
        restart = getattr(self.backend, "torque_restart", None)
        if restart is not None:  # torque control (re)started: the robot's last command is where ours continue
            self.backend.torque_restart = None
            self.safety.reseed(restart)

    def move_joints(self, q_goal: np.ndarray, duration_s: float | None = None, settle_s: float = 0.2,
                    max_joint_speed: float | None = None,
                    load_check: LoadErrorEstimator | None = None) -> RobotState:
        """Minimum-jerk joint move with joint impedance (TEC's capture/hover transitions).

        ``duration_s`` defaults to what keeps every joint under ``max_joint_speed`` [rad/s] (default: the
        loop's; the min-jerk peak speed is 1.875 × the mean speed), at least 0.5 s. ``load_check``
        collects the commands of the settle, the arm held still in free space
        (:mod:`tactex.control.load_error`).
        """
        self.use(self.joint)
        q_goal = np.asarray(q_goal, dtype=float)
        if duration_s is None:
            duration_s = self.joint_move_duration(q_goal, max_joint_speed)
        return self._run_joint_target(JointTarget(self._q_from(), q_goal, self.t, float(duration_s),
                                                  dq_start=self._dq_from()), settle_s, load_check)

    def _q_from(self) -> np.ndarray:
        """Where a new joint move starts: the last commanded posture while the joint controller runs on
        from an earlier move, else the measured one. At the end of a move q lags q_d by the tracking
        error, held by the joint spring; a move starting from the measured q would drop that spring
        torque in one tick. After a pause of torque control (a real robot's, :meth:`pause`) the robot's own hold
        has already taken that torque over, and its rate check starts from its own command: the move starts
        from the measured posture, so its first command holds no spring torque the robot would see as a jump."""
        if self._continues_joint_move():
            return self._q_commanded.copy()
        return self.state.q.copy()

    def _dq_from(self) -> np.ndarray | None:
        """The speed a new joint move starts at [rad/s]: rest (None) where it continues the joint controller's
        earlier move, which ended at rest, else the measured speed. A lift-off takes over an arm another
        controller moves (the tool sliding, the elbow turning in the null space); a move that started at
        rest would brake all of that speed in its first ticks, a step of torque the size of the damping
        times the speed. After a pause the robot has held the arm itself, so the measured speed is its rest."""
        return None if self._continues_joint_move() else self.state.dq.copy()

    def _continues_joint_move(self) -> bool:
        """Whether a new joint move continues the joint controller's last one (running, not paused since)."""
        paused = bool(getattr(self.backend, "torque_paused", False))
        return self.safety.inner is self.joint and self._q_commanded is not None and not paused

    def _run_joint_target(self, target: JointTarget, settle_s: float,
                          load_check: LoadErrorEstimator | None = None) -> RobotState:
        """Track ``target`` with joint impedance until it ends, then ``settle_s`` [s] more; the settle's
        commands go to ``load_check``."""
        self.use(self.joint)
        t_move_end = target.t_start + target.duration_s
        t_end = t_move_end + settle_s
        self._q_commanded = target.q_goal
        while self.t - self.joint.lag_s < t_end - 1e-9:  # on the target's clock, which a stall holds back
            state = self.state
            self.tick(target)
            if load_check is not None and state.t - self.joint.lag_s >= t_move_end:
                load_check.add(state, self.safety.last_command)
        return self.state

    def joint_move_duration(self, q_goal: np.ndarray, max_joint_speed: float | None = None,
                            q_from: np.ndarray | None = None, min_duration_s: float = 0.5) -> float:
        """Duration [s] of :meth:`move_joints` from ``q_from`` (default: the current q) to
        ``q_goal`` (no settling): every joint under ``max_joint_speed`` [rad/s] (the min-jerk peak
        speed is 1.875 × the mean speed; default: the loop's), at least ``min_duration_s``."""
        max_joint_speed = self.max_joint_speed if max_joint_speed is None else max_joint_speed
        start = self.state.q if q_from is None else np.asarray(q_from, dtype=float)
        peak = 1.875 * float(np.max(np.abs(np.asarray(q_goal, dtype=float) - start))) / max_joint_speed
        return max(min_duration_s, peak)

    def solve_pose(self, position_world: np.ndarray, rotation_world: np.ndarray,
                   q_seed: np.ndarray | None = None, q_posture: np.ndarray | None = None, *,
                   settled_step_rad: float | None = None, max_iter: int | None = None) -> np.ndarray:
        """Joint angles (7,) [rad] of a TCP pose, searched from ``q_seed`` (default: the current q),
        preferring postures near ``q_posture`` (default: the backend's home). A quicker search for screening
        many poses: ``settled_step_rad`` [rad] stops it once its steps are this small, ``max_iter`` gives up
        after that many steps (None: the backend's full search; :func:`~tactex.sim.ik.solve_site_ik`)."""
        seed = self.state.q if q_seed is None else q_seed
        # only what was given: the backends' own defaults are the full search (and their home posture)
        given = {"settled_step_rad": settled_step_rad, "max_iter": max_iter}
        extra = {k: v for k, v in given.items() if v is not None}
        return self.backend.solve_ik(position_world, rotation_world, seed, q_posture,  # type: ignore[attr-defined]
                                     **extra)

    def tcp_pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The TCP's position (3,) [m] and orientation (3, 3) at joint positions ``q`` (7,) [rad] on the backend's
        kinematic model (the robot does not move), or None from a backend without one."""
        fk = getattr(self.backend, "tcp_pose", None)
        return None if fk is None else fk(q)

    def link_capsules(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The arm's links at joint positions ``q`` (7,) [rad] as capsules on the backend's kinematic model: their
        axes' ends (K, 2, 3) [m] and radii (K,) [m]; None from a backend without one."""
        fk = getattr(self.backend, "link_capsules", None)
        return None if fk is None else fk(q)

    def move_to_pose(self, position_world: np.ndarray, rotation_world: np.ndarray, duration_s: float | None = None,
                     settle_s: float = 0.2, q_seed: np.ndarray | None = None) -> RobotState:
        """Joint move to the IK solution of a TCP pose, searched from ``q_seed`` (default: the
        current q). Seeding from a known posture keeps the arm on one IK branch: a far jump of
        branch would sweep the arm through the scene."""
        return self.move_joints(self.solve_pose(position_world, rotation_world, q_seed), duration_s, settle_s)

    def cartesian_path(self, p0: np.ndarray, r0: np.ndarray, q0: np.ndarray, position_world: np.ndarray,
                       rotation_world: np.ndarray, *, step_m: float = 0.02, step_rad: float = 0.15,
                       q_goal: np.ndarray | None = None, max_skipped: int = 2) -> list[np.ndarray]:
        """The joint waypoints (7,) [rad] of :meth:`move_cartesian` from the TCP pose ``p0`` [m], ``r0`` at
        posture ``q0`` [rad] to ``position_world``, ``rotation_world``, without moving the arm (a route of
        several legs is planned whole before its first leg moves). Raises SimulationError as the move would."""
        p0, r0 = np.asarray(p0, dtype=float), np.asarray(r0, dtype=float)
        goal_p = np.asarray(position_world, dtype=float)
        w = log_so3(r0.T @ np.asarray(rotation_world, dtype=float))
        n = max(1, math.ceil(max(float(np.linalg.norm(goal_p - p0)) / step_m, float(np.linalg.norm(w)) / step_rad)))
        q = np.asarray(q0, dtype=float)
        path: list[np.ndarray] = []
        skipped = 0
        for k in range(1, n + 1):
            f = k / n
            if skipped > max_skipped:
                raise SimulationError(
                    f"move_cartesian: the IK missed {skipped} waypoints in a row before waypoint {k} of {n}; "
                    "the straight line leaves the arm's reach")
            if k == n and q_goal is not None:
                path.append(np.asarray(q_goal, dtype=float))
                break
            try:  # the posture pull towards the last waypoint keeps the IK on its branch
                q = self.solve_pose(p0 + f * (goal_p - p0), r0 @ exp_so3(f * w), q_seed=q, q_posture=q)
            except SimulationError:
                if k == n:
                    raise
                skipped += 1
                continue  # a waypoint the IK misses is skipped; the next one is a short step further
            skipped = 0
            path.append(q)
        return path

    def move_cartesian(self, position_world: np.ndarray, rotation_world: np.ndarray, *, step_m: float = 0.02,
                       step_rad: float = 0.15, settle_s: float = 0.2, max_joint_speed: float | None = None,
                       q_goal: np.ndarray | None = None, max_skipped: int = 2,
                       path: list[np.ndarray] | None = None) -> RobotState:
        """Move the TCP along the straight line to ``position_world`` [m] (the orientation along the
        geodesic to ``rotation_world``), as one joint move through IK waypoints at most ``step_m`` [m]
        and ``step_rad`` [rad] apart, each solved from the one before (one IK branch). ``q_goal``: the
        posture of the end pose when it is known (a pre-recorded capture posture); it then ends the
        path instead of an IK solution. ``path``: the waypoints planned already (:meth:`cartesian_path`,
        from where the arm is now). A waypoint the IK misses is skipped, at most ``max_skipped`` in a row
        (SimulationError beyond, before the arm moves).

        For transits near an object: a single joint move between two far postures (from a cleaning
        pose inside a bowl to the capture pose above it) can dip the tool back into the object on the
        way, however high both ends are. The waypoints are joined by a smooth joint path with one
        minimum-jerk timing (:class:`JointTarget` ``via``), not a stop at each of them."""
        if path is None:
            start = self.state
            path = self.cartesian_path(start.ee_position, start.ee_rotation, start.q, position_world, rotation_world,
                                       step_m=step_m, step_rad=step_rad, q_goal=q_goal, max_skipped=max_skipped)
        path = [np.asarray(q, dtype=float) for q in path]
        self.use(self.joint)
        last_leg = None
        if q_goal is not None and len(path) > 1 and float(np.max(np.abs(path[-1] - path[-2]))) > FINAL_LEG_RAD:
            # the recorded end posture is on another branch than the IK path (a wrist turned by π): a spline
            # through both swings far past them; join it with its own joint move, as a stop
            last_leg = path.pop()
        target = JointTarget(self._q_from(), path[-1], self.t, 0.0, via=np.array(path[:-1]) if len(path) > 1 else None,
                             dq_start=self._dq_from())
        max_joint_speed = self.max_joint_speed if max_joint_speed is None else max_joint_speed
        duration_s = max(0.1, 1.875 * target.path_rate() / max_joint_speed)
        if last_leg is None:
            return self._run_joint_target(replace(target, duration_s=duration_s), settle_s)
        self._run_joint_target(replace(target, duration_s=duration_s), 0.0)
        # a joint move of its own, as long as any other (a tenth of a second to turn a wrist saturates the torque
        # rate: it starts while the arm still moves along the path)
        return self.move_joints(last_leg, self.joint_move_duration(last_leg, max_joint_speed), settle_s)

    def retract(self, distance_m: float, duration_s: float = 0.4,
                direction_world: np.ndarray | None = None) -> RobotState:
        """Lift the TCP about ``distance_m`` [m] straight back along the tool axis (−tool z), or
        along the unit ``direction_world`` when given, keeping its orientation, as a joint move of at
        least ``duration_s`` [s] (longer when a joint would otherwise exceed the planner's speed).

        The joint goal is one damped least-squares step through the current Jacobian, not a full
        IK solve: IK prefers postures near home, and its answer for a pose a few cm away can
        swing the elbow, so that the joint interpolation drags the tool across the object (a
        bowl's wall, pressed hard while lifting off). The linear step moves no joint more than the
        lift needs; its error is second order in the distance, harmless for a lift-off of a few cm
        but not a positioning move.
        """
        state = self.state
        jac = state.jacobian
        if direction_world is None:
            direction = -state.ee_rotation[:, 2]
        else:
            direction = np.asarray(direction_world, dtype=float)
            norm = float(np.linalg.norm(direction)) if direction.shape == (3,) else float("nan")
            if not (np.isfinite(norm) and norm > 0.0):
                raise InputError(f"direction_world must be a finite, non-zero 3-vector, got {direction_world!r}")
            direction = direction / norm
        twist = np.concatenate([distance_m * direction, np.zeros(3)])
        dq = jac.T @ np.linalg.solve(jac @ jac.T + RETRACT_DAMPING**2 * np.eye(6), twist)
        # Near a singular posture the step grows: keep it inside the joint limits (short of the safety
        # layer's repulsion band) and slow enough for every joint.
        # A joint already inside the band may stay where it is, not be pushed out by the lift.
        lim = self.safety.limits
        low = np.minimum(np.asarray(lim.q_min) + lim.joint_limit_margin, state.q)
        high = np.maximum(np.asarray(lim.q_max) - lim.joint_limit_margin, state.q)
        q_goal = np.clip(state.q + dq, low, high)
        return self.move_joints(q_goal, self.joint_move_duration(q_goal, min_duration_s=duration_s), settle_s=0.0)

    def pause(self) -> None:
        """Before wall-clock work longer than a control cycle between two ticks (planning, a model
        build): a real robot's torque control ends and the robot holds its posture itself until the
        next tick starts it again (:meth:`LibfrankaBackend.pause`), where it would otherwise wait for
        a command that does not come and drop the link; a simulated robot waits anyway. ``pause`` is
        the backend protocol's optional hook: a backend without it is one that waits."""
        pause = getattr(self.backend, "pause", None)
        if pause is not None:
            pause()

    def hold(self, duration_s: float) -> RobotState:
        """Hold still: at the posture the joint controller was last sent to when it is running, else at
        the current one."""
        q = self._q_from()
        return self._run_joint_target(JointTarget(q, q, self.t, 0.0), duration_s)
