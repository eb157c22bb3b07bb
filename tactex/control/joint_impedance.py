"""Joint impedance with a minimum-jerk joint trajectory: how TEC moves between its pre-recorded
capture and hover poses (§V-A3: "a simple joint impedance controller")."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PchipInterpolator

from tactex.config import param
from tactex.control.controller import Controller
from tactex.control.linalg import solve
from tactex.control.state import RobotState
from tactex.errors import ConfigError, ControllerFault, InputError

__all__ = ["JointImpedanceController", "JointImpedanceParams", "JointTarget", "min_jerk", "start_speed_decay"]


def min_jerk(s: float) -> tuple[float, float]:
    """Minimum-jerk profile at normalised time s ∈ [0, 1]: (position fraction, d/ds)."""
    s = min(max(s, 0.0), 1.0)
    return 10 * s**3 - 15 * s**4 + 6 * s**5, 30 * s**2 - 60 * s**3 + 30 * s**4


def start_speed_decay(s: float) -> tuple[float, float]:
    """The quintic that carries a start speed into a move and brings it to rest, at normalised time
    s ∈ [0, 1]: (value, d/ds), with value 0 at both ends, slope 1 at s = 0 and 0 at s = 1, and zero
    curvature at both ends. ``v0 · T · value`` added to a rest-to-rest move of duration T starts it at
    speed v0 with no jump of acceleration and still ends it at rest on the goal."""
    s = min(max(s, 0.0), 1.0)
    return s - 6 * s**3 + 8 * s**4 - 3 * s**5, 1 - 18 * s**2 + 32 * s**3 - 15 * s**4


@dataclass(frozen=True)
class JointImpedanceParams:
    """Gains of the Franka example joint impedance controller (stiffness and damping as there).

    The damping is applied implicitly (see :class:`JointImpedanceController`): the explicit −D·q̇
    of the example is unstable at 1 kHz on any motion mode whose inertia is below D·dt/2, e.g.
    joints 1 and 3 turning against each other when joint 2 is near 0 (their axes then align and
    only the small link 2 moves). The real arm's reflected rotor inertia hides this; a model
    without it, or a lighter arm, does not.
    """

    stiffness: tuple[float, ...] = param((600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0), "joint stiffness [N·m/rad]")
    damping: tuple[float, ...] = param((50.0, 50.0, 50.0, 50.0, 30.0, 25.0, 15.0), "joint damping [N·m·s/rad]")
    dt: float = param(1e-3, "control period the damping is made stable for [s]")
    latency_horizon_ticks: float = param(
        3.0, "horizon h of the implicit impedance in control periods [-]: the torque is M (M + h·D + h²·K)⁻¹ "
        "(K·e + D·ė) (tactex.control.damping). 1 with K left out is the backward-Euler damping, stable at "
        "1 kHz without command delay; a real Franka applies each command one cycle later, and with two "
        "ticks of delay that form is unstable; 3 keeps every mode's dt·D/m ≤ 1/3; 0: stiffness explicit, "
        "damping backward Euler over one period")

    def __post_init__(self) -> None:
        k, d = np.asarray(self.stiffness, float), np.asarray(self.damping, float)
        ok = np.all(k >= 0) and np.all(d >= 0) and np.isfinite(k).all() and np.isfinite(d).all()
        if k.shape != d.shape or not ok:
            raise ConfigError(f"joint stiffness and damping must be ≥ 0 and of equal length, got {k} and {d}")
        if not (np.isfinite(self.latency_horizon_ticks) and self.latency_horizon_ticks >= 0):
            raise ConfigError("JointImpedanceParams.latency_horizon_ticks must be ≥ 0, "
                              f"got {self.latency_horizon_ticks!r}")
        if not (np.isfinite(self.dt) and 0 < self.dt <= 0.1):
            raise ConfigError(f"JointImpedanceParams.dt must be a control period in (0, 0.1] s, got {self.dt!r}")


@dataclass(frozen=True)
class JointTarget:
    """Move from ``q_start`` to ``q_goal`` [rad] between ``t_start`` and ``t_start + duration_s`` [s].

    With ``via`` (m, n) [rad] the path passes through those postures in order: a C¹ monotone cubic
    (PCHIP: no overshoot past a via point, where a C² spline swung far out after an uneven step)
    through start, via points and goal, parameterised by chord length in joint space, travelled
    with one minimum-jerk timing. Through IK waypoints of a Cartesian transit this is one smooth
    motion; a rest-to-rest move per waypoint would stop the arm at every waypoint and shake the tool
    at that rate (a force ripple on the wrist F/T).

    ``dq_start`` [rad/s]: the joint speed the move starts at (default rest), brought to rest within the
    move (:func:`start_speed_decay`). A move that starts from a moving arm (a lift-off while another
    controller slid the tool or turned the elbow in its null space) would otherwise command rest at its
    first tick: its damping brakes the whole speed at once, a torque step the robot's torque-rate
    check sees.
    """

    q_start: np.ndarray
    q_goal: np.ndarray
    t_start: float
    duration_s: float
    via: np.ndarray | None = None
    dq_start: np.ndarray | None = None

    def __post_init__(self) -> None:
        q0 = np.asarray(self.q_start, dtype=float)
        q1 = np.asarray(self.q_goal, dtype=float)
        if q0.ndim != 1 or q0.shape != q1.shape or not (np.isfinite(q0).all() and np.isfinite(q1).all()):
            raise InputError(
                f"JointTarget needs finite q_start and q_goal of one shape [rad], got {q0.tolist()} and {q1.tolist()}"
            )
        if not (np.isfinite(self.t_start) and np.isfinite(self.duration_s) and self.duration_s >= 0):
            raise InputError(f"JointTarget needs a finite t_start and duration_s ≥ 0 [s], got {self.t_start}, "
                             f"{self.duration_s}")
        object.__setattr__(self, "q_start", q0)
        object.__setattr__(self, "q_goal", q1)
        if self.dq_start is not None:
            v0 = np.asarray(self.dq_start, dtype=float)
            if v0.shape != q0.shape or not np.isfinite(v0).all():
                raise InputError(f"JointTarget.dq_start must be finite joint speeds [rad/s] of shape {q0.shape}, "
                                 f"got {np.asarray(self.dq_start).tolist()}")
            object.__setattr__(self, "dq_start", None if not v0.any() else v0)
        spline = None
        if self.via is not None:
            via = np.asarray(self.via, dtype=float).reshape(-1, q0.shape[0]) if np.size(self.via) else None
            if via is None or np.asarray(self.via).ndim != 2 or not np.isfinite(via).all():
                raise InputError(f"JointTarget.via must be finite (m, {q0.shape[0]}) joint positions [rad], "
                                 f"got shape {np.shape(self.via)}")
            object.__setattr__(self, "via", via)
            knots = np.vstack([q0, via, q1])
            step = np.linalg.norm(np.diff(knots, axis=0), axis=1)
            keep = np.concatenate([[True], step > 1e-9])  # repeated postures would give equal knots
            knots, u = knots[keep], np.concatenate([[0.0], np.cumsum(step[step > 1e-9])])
            if u[-1] > 0 and len(u) > 2:
                spline = PchipInterpolator(u / u[-1], knots, axis=0)
        object.__setattr__(self, "_spline", spline)

    def path_rate(self) -> float:
        """Largest |dq/du| of any joint along the path [rad per unit path parameter]: the joint speed
        at a path rate of 1/s (for the straight move, the largest joint difference)."""
        if self._spline is None:
            return float(np.max(np.abs(self.q_goal - self.q_start), initial=0.0))
        u = np.linspace(0.0, 1.0, 201)
        return float(np.max(np.abs(self._spline(u, 1))))

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Desired joint position [rad] and velocity [rad/s] at time t [s]."""
        if self.duration_s <= 0:
            return self.q_goal, np.zeros_like(self.q_goal)
        tau = (t - self.t_start) / self.duration_s
        s, ds = min_jerk(tau)
        if self._spline is not None:
            q, dq = self._spline(s), self._spline(s, 1) * (ds / self.duration_s)
        else:
            delta = self.q_goal - self.q_start
            q, dq = self.q_start + s * delta, ds * delta / self.duration_s
        if self.dq_start is not None:
            c, dc = start_speed_decay(tau)
            q, dq = q + (c * self.duration_s) * self.dq_start, dq + dc * self.dq_start
        return q, dq


#: A step of the robot's clock longer than this many control periods between two commands is a stall [-].
STALL_TICKS = 1.5

#: A target that moves less than this over a stall has nothing to hold back [rad] (the encoders' resolution).
PROGRESS_MIN_RAD = 1e-6

#: Bisections of the arm's progress along the target over a stall: the gap over 2^30, far under a period [-].
PROGRESS_BISECTIONS = 30


class JointImpedanceController(Controller):
    """τ = M (M + h·D + h²·K)⁻¹ (K (q_d − q) + D (dq_d − dq)) + C(q, dq)·dq on a :class:`JointTarget`
    (gravity by the robot), h = ``latency_horizon_ticks``·dt.

    The impedance applied implicitly over h (:func:`tactex.control.damping.latency_shaped_torque`):
    the same as K, D on modes whose inertia is large against h·D and h²·K, and never more than a
    loop with one or two ticks of command delay can apply without ringing on light ones (joints 1
    and 3 turning against each other when joint 2 is near 0, the wrist); still passive.
    """

    name = "joint_impedance"

    def __init__(self, params: JointImpedanceParams | None = None) -> None:
        self.params = params or JointImpedanceParams()
        self._k = np.asarray(self.params.stiffness, dtype=float)
        self._d = np.asarray(self.params.damping, dtype=float)
        self._d_mat = np.diag(self._d)
        h = float(self.params.dt) * max(float(self.params.latency_horizon_ticks), 1.0)
        self._dt_d_mat = h * self._d_mat  # h·D, added to M every tick
        self._h_mat = self._dt_d_mat + np.diag(h * h * self._k)
        self._target: JointTarget | None = None
        self._t_prev = 0.0
        self.lag_s = 0.0  # how far the target's clock runs behind the robot's [s]
        self._q_prev: np.ndarray | None = None  # the joint positions of the last command's state [rad]

    def reset(self, state: RobotState) -> None:
        self._target = None

    def damping_matrix(self, mass_matrix: np.ndarray) -> np.ndarray:
        """The effective damping M (M + h·D)⁻¹ D [N·m·s/rad] for the joint-space inertia ``mass_matrix`` [kg·m²]."""
        m = np.asarray(mass_matrix, dtype=float)
        return m @ solve(m + self._dt_d_mat, self._d_mat)

    def _progress_s(self, reference: JointTarget, q: np.ndarray, gap_s: float) -> float:
        """How far along ``reference`` [s of its clock] the arm went from the last command's state to ``q`` over
        a gap of ``gap_s`` [s]: the time s in [one period, the gap] after the last command's target time at which
        the target's own displacement, along the way it goes over the gap, equals the arm's (bisected: a move's
        target goes on along its way); the whole gap where the target does not move over it (nothing to hold
        back). A frozen arm gives one period, an arm that ran on along the move the time it took."""
        dt = self.params.dt
        if self._q_prev is None or self._q_prev.shape != q.shape:
            return dt
        t0 = self._t_prev - self.lag_s
        q0 = reference.at(t0)[0]
        span = reference.at(t0 + gap_s)[0] - q0
        norm = float(np.linalg.norm(span))
        if not norm > PROGRESS_MIN_RAD:
            return gap_s
        u = span / norm
        went = float((q - self._q_prev) @ u)
        lo, hi = dt, gap_s
        if not float((reference.at(t0 + lo)[0] - q0) @ u) < went:  # not even a period's way (or NaN): held back
            return lo
        if went >= norm:
            return hi
        for _ in range(PROGRESS_BISECTIONS):
            mid = 0.5 * (lo + hi)
            if float((reference.at(t0 + mid)[0] - q0) @ u) < went:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)

    def torque(self, state: RobotState, reference: JointTarget) -> np.ndarray:
        if not isinstance(reference, JointTarget):
            raise ControllerFault(f"{self.name} needs a JointTarget, got {type(reference).__name__}")
        if reference.q_goal.shape != state.q.shape or self._k.shape != state.q.shape:
            raise ControllerFault(f"joint target has shape {reference.q_goal.shape}, gains {self._k.shape}, "
                                  f"the robot {state.q.shape}")
        t = state.t
        if reference is not self._target:
            self._target, self.lag_s = reference, 0.0
        elif t - self._t_prev > STALL_TICKS * self.params.dt:
            # the loop answered late (a stall of the machine, lost cycles): the target's clock advances by as much
            # of the gap as the arm itself went along the move meanwhile (at least one period), so the command
            # goes on from where the arm is instead of stepping. A robot (and the twin) runs on under the last
            # command through lost cycles: holding the target back by the whole gap would step the command
            # backwards by the arm's progress; an emulator that repeats a frozen state while its clock runs on
            # (franka-sim) has the whole gap held back.
            gap = t - self._t_prev
            self.lag_s += gap - self._progress_s(reference, state.q, gap)
        self._t_prev = t
        self._q_prev = state.q.copy()
        q_d, dq_d = reference.at(t - self.lag_s)
        m = state.mass_matrix
        if self.params.latency_horizon_ticks <= 0:  # stiffness explicit, damping over one period
            accel = solve(m + self._dt_d_mat, self._d * (dq_d - state.dq))
            return self._k * (q_d - state.q) + m @ accel + state.coriolis
        accel = solve(m + self._h_mat, self._k * (q_d - state.q) + self._d * (dq_d - state.dq))
        return m @ accel + state.coriolis
