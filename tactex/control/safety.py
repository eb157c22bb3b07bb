"""The safety layer every controller runs behind: limits, NaN guard, force guard, joint limits.

:class:`SafetyLayer` wraps any :class:`Controller` and is itself one. Per tick:

1. non-finite state → hold (last safe command, decaying) and raise a ``nan_state`` event; a
   non-finite F/T wrench alone is replaced by the last finite one (``nan_wrench``, reported when the
   dropout starts) so control goes on through a glitch. After ``wrench_loss_ticks`` non-finite
   readings in a row the sensor counts as lost (``wrench_lost``): a stale reading can neither trip
   the force limit nor close a force loop, so the layer backs off as in 2. for ``retreat_time``,
   then holds the arm with damping alone until the sensor has been back for ``retreat_time``;
2. contact force above ``max_contact_force`` for ``force_trip_ticks`` ticks → compliant retreat
   (damping plus a small pull back along −tool z) for ``retreat_time``, then the inner controller
   resumes from the current state (``force_limit`` / ``retreat_end`` events; :meth:`Controller.resume`
   restarts its integrators but keeps its tanks' energy: a retreat must not refill a dry tank);
3. the inner controller's torque; an exception or a non-finite torque → hold (``controller_fault`` /
   ``nan_torque``). When the inner controller changes (``layer.inner = other``) or resumes after a
   retreat, its torque is blended in from the last command over ``handover_blend_s``: two controllers
   seldom agree on the torque at the switch, and the step would otherwise hit the rate limit;
4. joint-limit repulsion inside ``joint_limit_margin`` of a limit (``joint_limit``);
5. saturation a margin below the Franka torque limits and torque-rate limit (``torque_limit`` /
   ``torque_rate_limit``, reported when saturation starts, counted every tick). The robot's own
   check fires at its limits (``controller_torque_discontinuity`` at 1000 N·m/s); clipping exactly
   there lets round-off decide (a command clipped to exactly 1 N·m per 1 ms tick can be judged a
   hair above 1000 N·m/s, and the robot aborts), so the layer clips at ``(1 − limit_margin)`` of
   each limit, as libfranka's own limiter stays ``kLimitEps`` below them (``franka/rate_limiting.h``).

Events are small frozen dataclasses in :attr:`SafetyLayer.events`; nothing non-finite ever leaves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from tactex.config import param
from tactex.control import joint_kernels
from tactex.control.controller import Controller
from tactex.control.joint_impedance import min_jerk
from tactex.control.state import RobotState
from tactex.errors import ConfigError, TactexError

__all__ = [
    "FORCE_PEAK_RATIO",
    "FRANKA_Q_MAX",
    "FRANKA_Q_MIN",
    "FRANKA_TAU_MAX",
    "FRANKA_TAU_RATE_MAX",
    "LIMIT_MARGIN",
    "MAX_FORCE_SET_POINT_N",
    "SafetyEvent",
    "SafetyLayer",
    "SafetyLimits",
    "check_force_set_point",
]

#: The robot's joint torque limits [N·m] and torque-rate limit [N·m/s] (libfranka's kMaxTorqueRate):
#: where its own checks fire (tau_J_range_violation, controller_torque_discontinuity).
FRANKA_TAU_MAX = (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0)
FRANKA_TAU_RATE_MAX = 1000.0
#: The share of each limit no command uses [-]: 1 % (10 N·m/s of the rate, 0.87 N·m of a shoulder
#: joint's torque) is far above round-off and costs the controllers nothing they use.
LIMIT_MARGIN = 0.01
FRANKA_Q_MIN = (-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973)
FRANKA_Q_MAX = (2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973)


@dataclass(frozen=True, slots=True)
class SafetyEvent:
    """One trip of the safety layer: time [s], kind, and a human-readable detail."""

    t: float
    kind: str
    detail: str


@dataclass(frozen=True)
class SafetyLimits:
    """Franka Emika limits by default."""

    tau_max: tuple[float, ...] = param(FRANKA_TAU_MAX, "the robot's joint torque limits [N·m]")
    tau_rate_max: float = param(FRANKA_TAU_RATE_MAX, "the robot's joint torque-rate limit [N·m/s]")
    limit_margin: float = param(
        LIMIT_MARGIN, "commands are clipped at (1 − limit_margin) of tau_max and tau_rate_max, never at the "
        "limits themselves, where the robot's own check fires and round-off decides [-]")
    q_min: tuple[float, ...] = param(FRANKA_Q_MIN, "lower joint limits [rad]")
    q_max: tuple[float, ...] = param(FRANKA_Q_MAX, "upper joint limits [rad]")
    joint_limit_margin: float = param(0.1, "repulsion starts this close to a joint limit [rad]")
    joint_limit_stiffness: float = param(50.0, "repulsion stiffness inside the margin [N·m/rad]")
    joint_limit_damping: float = param(
        2.0, "joint damping inside the margin [N·m·s/rad], faded in over the first "
        "joint_kernels.LIMIT_DAMPING_RAMP_RAD of it")
    max_contact_force: float = param(40.0, "contact force that trips the retreat [N]")
    force_trip_ticks: int = param(
        10, "consecutive ticks above the force limit before tripping: impacts and sensor glitches last less [-]")
    retreat_time: float = param(0.3, "duration of the compliant retreat [s]")
    wrench_loss_ticks: int = param(
        20, "consecutive non-finite F/T readings bridged with the last finite one; one more and the sensor "
        "counts as lost and the layer retreats [-]")
    lost_contact_force_n: float = param(
        1.0, "a sensor lost while its last reading exceeded this force backs the tool off for retreat_time; "
        "lost in free space the layer only damps [N]")
    retreat_force: float = param(5.0, "pull back along −tool z during the retreat [N]")
    retreat_damping: float = param(60.0, "lateral translational damping during the retreat [N·s/m]")
    retreat_axial_damping: float = param(
        10.0, "damping along the tool axis during the retreat: low, so a surface that pushes is yielded to [N·s/m]")
    retreat_angular_damping: float = param(3.0, "rotational damping during the retreat [N·m·s/rad]")
    hold_decay_time: float = param(0.1, "a held command decays to zero with this time constant [s]")
    handover_blend_s: float = param(
        0.05, "a new or resumed inner controller's torque is blended in from the last command over this time "
        "(minimum-jerk weight); 0 switches at once [s]")
    dt: float = param(1e-3, "control period [s]")

    def __post_init__(self) -> None:
        n = len(self.tau_max)
        if len(self.q_min) != n or len(self.q_max) != n:
            raise ConfigError(f"SafetyLimits: tau_max, q_min, q_max need the same length, got {n}, "
                              f"{len(self.q_min)}, {len(self.q_max)}")
        if not (np.all(np.asarray(self.tau_max) > 0) and np.all(np.asarray(self.q_max) > np.asarray(self.q_min))):
            raise ConfigError(f"SafetyLimits: tau_max must be > 0 and q_max > q_min, got tau_max={self.tau_max}, "
                              f"q_min={self.q_min}, q_max={self.q_max}")
        for name in ("tau_rate_max", "max_contact_force", "dt", "retreat_time", "hold_decay_time"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise ConfigError(f"SafetyLimits.{name} must be finite and > 0, got {v!r}")
        for name in ("joint_limit_margin", "joint_limit_stiffness", "joint_limit_damping", "retreat_force",
                     "handover_blend_s",
                     "lost_contact_force_n",
                     "retreat_damping", "retreat_angular_damping"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ConfigError(f"SafetyLimits.{name} must be finite and ≥ 0, got {v!r}")
        if not (isinstance(self.limit_margin, (int, float)) and 0.0 < self.limit_margin < 0.5):
            raise ConfigError(f"SafetyLimits.limit_margin must lie in (0, 0.5), got {self.limit_margin!r}")
        for name in ("force_trip_ticks", "wrench_loss_ticks"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ConfigError(f"SafetyLimits.{name} must be an integer ≥ 1, got {v!r}")


#: The papers' quality bound on a force-controlled task: no contact force above this multiple of its set point.
FORCE_PEAK_RATIO = 2.0


#: The largest force set point of a task under the default limits [N].
MAX_FORCE_SET_POINT_N = SafetyLimits.max_contact_force / FORCE_PEAK_RATIO


def check_force_set_point(name: str, force_n: float, limits: SafetyLimits | None = None) -> None:
    """Refuse a task's force set point ``force_n`` [N] (the field ``name``) whose allowed peaks, up to
    :data:`FORCE_PEAK_RATIO` × it, would reach the force that trips the layer's retreat: such a task
    spends its contact retreating. The limit stays where it is: it guards the object and the robot,
    and a set point raised by a typo must not raise it too."""
    cap = (limits or SafetyLimits()).max_contact_force
    most = cap / FORCE_PEAK_RATIO
    if force_n > most:
        raise ConfigError(
            f"{name} = {force_n:g} N is more than the safety layer allows: it retreats at a contact force of "
            f"{cap:g} N, and contact peaks reach {FORCE_PEAK_RATIO:g}× the set point; give at most {most:g} N")


class SafetyLayer(Controller):
    """Wraps ``inner``; see the module docstring for what it guards."""

    def __init__(self, inner: Controller, limits: SafetyLimits | None = None) -> None:
        self.inner = inner
        self.limits = limits or SafetyLimits()
        self.name = f"safe_{inner.name}"
        lim = self.limits
        keep = 1.0 - lim.limit_margin
        self._tau_max = np.asarray(lim.tau_max, dtype=float) * keep  # where commands are clipped [N·m]
        self._q_min = np.asarray(lim.q_min, dtype=float)
        self._q_max = np.asarray(lim.q_max, dtype=float)
        self._q_lo_margin = self._q_min + lim.joint_limit_margin
        self._q_hi_margin = self._q_max - lim.joint_limit_margin
        self._rate_step = lim.tau_rate_max * keep * lim.dt  # largest change of a command per tick [N·m]
        self._hold_decay = float(np.exp(-lim.dt / lim.hold_decay_time))
        self._tau_max_l = self._tau_max.tolist()
        self._q_lo_margin_l = self._q_lo_margin.tolist()
        self._q_hi_margin_l = self._q_hi_margin.tolist()
        self.events: list[SafetyEvent] = []
        self.counts: dict[str, int] = {}
        self._tau_prev = np.zeros(len(self._tau_max_l))  # the last command [N·m]
        self._wrench_last_l = [0.0] * 6  # last finite F/T wrench, Python floats
        self._wrench_bad = 0  # consecutive non-finite F/T readings
        self._lost_at: float | None = None  # when the sensor was declared lost [s]
        self._lost_in_contact = False  # its last finite reading showed contact
        self._nan_event_t = -math.inf  # time of the last nan_wrench event [s]
        self._over = 0
        #: [N] the largest contact force magnitude the layer has seen since it was made or reset (every tick,
        #: whatever the inner controller: a move's as well as a task's)
        self.peak_force_n = 0.0
        self._retreat_until: float | None = None
        self._saturating = {"torque_limit": False, "torque_rate_limit": False}
        self._held = False
        self._last_inner: Controller = inner
        self._blend_from: list[float] | None = None  # the command a hand-over blends from
        self._blend_ticks = 0  # commands blended since the hand-over started
        #: (6,) [N, N·m] a wrench at the TCP, world frame, added to every inner controller's command: the
        #: tool's weight the robot's own load setting misses (:mod:`tactex.control.load_error`); None: nothing
        self.load_wrench_world: np.ndarray | None = None
        kernels = joint_kernels.kernels()  # compiled now, never inside a control loop
        self._finite_kernel = None if kernels is None else kernels.state_finite
        self._limit_kernel = None if kernels is None else kernels.limit_torque

    # -- bookkeeping ----------------------------------------------------------------------
    def _event(self, t: float, kind: str, detail: str) -> None:
        self.events.append(SafetyEvent(float(t) if np.isfinite(t) else float("nan"), kind, detail))
        self.counts[kind] = self.counts.get(kind, 0) + 1

    def reset(self, state: RobotState) -> None:
        self.events.clear()
        self.counts.clear()
        self._tau_prev[:] = 0.0
        self._wrench_last_l = [0.0] * 6
        self._wrench_bad = 0
        self._lost_at = None
        self._nan_event_t = -math.inf
        self._over = 0
        self.peak_force_n = 0.0
        self._retreat_until = None
        self._held = False
        self._last_inner = self.inner
        self._blend_from = None
        self.inner.reset(state)

    def compensate_load(self, wrench_world: np.ndarray | None) -> None:
        """From the next command on, add ``wrench_world`` (6,) [N, N·m] at the TCP (world frame) to every inner
        controller's command (None: nothing): the tool's weight the robot's load setting misses. Blended in
        as a hand-over, never a step."""
        self.load_wrench_world = None if wrench_world is None else np.asarray(wrench_world, dtype=float).copy()
        self._start_blend()

    @property
    def last_command(self) -> np.ndarray:
        """A copy of the last command [N·m] this layer returned."""
        return self._tau_prev.copy()

    def reseed(self, tau_last: np.ndarray) -> None:
        """Continue from ``tau_last`` [N·m], the robot's own last command: when torque
        control (re)starts after a pause the robot checks the first command against its ``tau_J_d``
        (0 at rest), not against the last one tactex sent before the pause, which may hold newtons of
        torque (a mis-set load held in place). The controller's torque is blended in from there over
        ``handover_blend_s``, as at any hand-over, rather than reached at the rate limit: a restart's
        first command may come a cycle late, and the robot then differences the next one against its
        own value over a single cycle, so a ramp at the limit would be a double step there. A non-finite
        value counts as 0."""
        tau = np.asarray(tau_last, dtype=float)
        self._tau_prev[:] = tau if tau.shape == self._tau_prev.shape and np.isfinite(tau).all() else 0.0
        self._start_blend()

    def _state_finite(self, state: RobotState) -> bool:
        """Every number of the state is finite: the compiled check when there is one (a state of
        other array types warns once and uses numpy from then on)."""
        if self._finite_kernel is not None:
            finite = joint_kernels.run(self._finite_kernel, state.t, state.q, state.dq, state.tau_measured,
                                       state.ee_position, state.ee_rotation, state.ee_twist, state.jacobian,
                                       state.mass_matrix, state.coriolis, state.gravity, state.wrench_tool,
                                       then="the safety layer checks with numpy from now on")
            if finite is not None:
                return finite
            self._finite_kernel = None
        return _state_finite(state)

    @property
    def retreating(self) -> bool:
        return self._retreat_until is not None

    # -- the tick ---------------------------------------------------------------------------
    def _hold(self) -> list[float]:
        """The last command, decayed by one tick of ``hold_decay_time``."""
        decay = self._hold_decay
        return [x * decay for x in self._tau_prev.tolist()]

    def torque(self, state: RobotState, reference: Any) -> np.ndarray:
        # Vectors as Python floats (one tolist each): for 6- and 7-vectors at 1 kHz, float arithmetic
        # is cheaper than numpy calls. A vector is finite iff its sum is (NaN and inf propagate; a sum
        # that overflows counts as non-finite, the safe side); for fewer than 8 numbers Python's sum
        # adds in the order numpy's reduction does, so the verdict is the same as np.add.reduce's.
        lim = self.limits
        if state.q.shape[0] != self._tau_max.shape[0]:
            raise ConfigError(f"SafetyLayer configured for {self._tau_max.shape[0]} joints, state has {state.n_joints}")
        wrench = state.wrench_tool.tolist()
        lost = False
        if not math.isfinite(sum(wrench)):
            self._wrench_bad += 1
            # one event per dropout, and at most one a second (a dead or flickering sensor would add
            # one per tick); every tick is counted
            if self._wrench_bad == 1 and state.t - self._nan_event_t >= 1.0:
                msg = f"non-finite F/T wrench {state.wrench_tool!r}; using the last finite one"
                self._event(state.t, "nan_wrench", msg)
                self._nan_event_t = float(state.t)
            else:
                self.counts["nan_wrench"] = self.counts.get("nan_wrench", 0) + 1
            lost = self._wrench_bad > lim.wrench_loss_ticks
            if self._wrench_bad == lim.wrench_loss_ticks + 1:
                self._lost_at = float(state.t)
                fx, fy, fz = self._wrench_last_l[:3]
                self._lost_in_contact = math.sqrt(fx * fx + fy * fy + fz * fz) > lim.lost_contact_force_n
                self._event(state.t, "wrench_lost", f"no finite F/T reading for {self._wrench_bad} ticks; "
                            "backing off, then holding, until the sensor is back")
            wrench = self._wrench_last_l
            state = _replace_wrench(state, np.array(wrench))
        else:
            self._wrench_bad = 0
            self._lost_at = None
        if not self._state_finite(state):
            self._event(state.t, "nan_state", "non-finite robot state; holding the last safe command")
            return self._finish(state, self._hold(), finite_state=False)
        self._wrench_last_l = wrench
        if lost:  # retreat while the sensor is lost, and for retreat_time after it is back
            until = state.t + lim.retreat_time
            if self._retreat_until is None or self._retreat_until < until:
                self._retreat_until = until

        fx, fy, fz = wrench[0], wrench[1], wrench[2]
        force = math.sqrt(fx * fx + fy * fy + fz * fz)
        if force > self.peak_force_n:
            self.peak_force_n = force
        self._over = self._over + 1 if force > lim.max_contact_force else 0
        if self._retreat_until is None and self._over >= lim.force_trip_ticks:
            self._retreat_until = state.t + lim.retreat_time
            msg = f"contact force {force:.1f} N > {lim.max_contact_force:.1f} N; retreating"
            self._event(state.t, "force_limit", msg)
        if self._retreat_until is not None:
            if state.t >= self._retreat_until and self._over == 0:
                self._retreat_until = None
                self.inner.resume(state)  # integrators restart; tanks keep their (possibly low) energy
                self._event(state.t, "retreat_end", "retreat finished; inner controller resumed")
                self._start_blend()
            else:
                return self._finish(state, self._retreat_torque(state).tolist())

        if self.inner is not self._last_inner:
            self._last_inner = self.inner
            self._start_blend()
        try:
            tau = self.inner.torque(state, reference)
            if tau.__class__ is not np.ndarray or tau.dtype is not _F64:  # skip the keyword call when it is a no-op
                tau = np.asarray(tau, dtype=float)
            if self.load_wrench_world is not None and tau.shape == self._tau_max.shape:
                tau = tau + state.jacobian.T @ self.load_wrench_world
        except TactexError as exc:
            self._event(state.t, "controller_fault", f"{type(exc).__name__}: {exc}")
            return self._finish(state, self._hold())
        if self._limit_kernel is not None and self._blend_from is None and tau.shape == self._tau_max.shape:
            out = self._finish_compiled(state, tau)
            if out is not None:
                return out
        tau_l = tau.tolist() if tau.shape == self._tau_max.shape else None
        if tau_l is None or not math.isfinite(sum(tau_l)):
            self._event(state.t, "nan_torque", f"inner controller returned {tau!r}; holding")
            return self._finish(state, self._hold())
        if self._blend_from is not None:
            tau_l = self._blend(tau_l)
        return self._finish(state, tau_l)

    def _start_blend(self) -> None:
        if self.limits.handover_blend_s > 0:
            self._blend_from = self._tau_prev.tolist()
            self._blend_ticks = 0

    def _blend(self, tau_l: list[float]) -> list[float]:
        """(1 − w)·the command at the hand-over + w·``tau_l``, w a minimum-jerk ramp from 0 at the
        hand-over's first tick to 1 after ``handover_blend_s``. The ramp advances a period per command, not with
        the state's time: after a stall (a late tick, the robot's clock run on by tens of ms) the next command
        still differs from the last one by one period's share, which is what the robot's rate check sees."""
        lim = self.limits
        self._blend_ticks += 1
        w, _ = min_jerk(self._blend_ticks * lim.dt / lim.handover_blend_s)
        start = self._blend_from
        if w >= 1.0 or start is None:
            self._blend_from = None
            return tau_l
        return [a + w * (b - a) for a, b in zip(start, tau_l, strict=True)]

    def _retreat_torque(self, state: RobotState) -> np.ndarray:
        """The compliant retreat: a pull back along −tool z and damping. With the sensor lost the pull
        acts only if the last reading showed contact, and for ``retreat_time`` only (unopposed it would
        carry the arm off at ~0.5 m/s); then the damping alone holds the arm until the sensor is back."""
        lim = self.limits
        z = state.ee_rotation[:, 2]
        v = state.ee_twist[:3]
        v_ax = float(v @ z) * z
        pull = lim.retreat_force
        if self._lost_at is not None and (state.t - self._lost_at > lim.retreat_time or not self._lost_in_contact):
            pull = 0.0
        f = np.empty(6)
        f[:3] = -pull * z - lim.retreat_damping * (v - v_ax) - lim.retreat_axial_damping * v_ax
        f[3:] = -lim.retreat_angular_damping * state.ee_twist[3:]
        return state.jacobian.T @ f

    def _finish(self, state: RobotState, tau_l: list[float], finite_state: bool = True) -> np.ndarray:
        """Joint-limit repulsion, then torque and torque-rate saturation of the command ``tau_l`` (a
        list of Python floats). One loop over the joints on floats: for 7 joints this is cheaper at
        1 kHz than the dozen numpy calls of the vectorised form, and gives the same numbers."""
        lim = self.limits
        q = state.q.tolist() if finite_state else None
        lo_m, hi_m = self._q_lo_margin_l, self._q_hi_margin_l
        k, d = lim.joint_limit_stiffness, lim.joint_limit_damping
        ramp = joint_kernels.LIMIT_DAMPING_RAMP_RAD
        dq = None
        near = []
        step = self._rate_step
        prev, tau_max = self._tau_prev.tolist(), self._tau_max_l
        out = []
        rate_hit = torque_hit = False
        for j in range(len(tau_max)):  # an index loop: zip(strict=True)'s keyword parsing costs more than the body
            x, p, m = tau_l[j], prev[j], tau_max[j]
            if q is not None and (q[j] < lo_m[j] or q[j] > hi_m[j]):  # joint-limit repulsion
                near.append(j)
                if dq is None:
                    dq = state.dq.tolist()
                if q[j] < lo_m[j]:  # the damping faded in with the depth, as in joint_kernels.limit_torque
                    depth = lo_m[j] - q[j]
                    x += k * depth - d * min(depth / ramp, 1.0) * dq[j]
                if q[j] > hi_m[j]:
                    depth = q[j] - hi_m[j]
                    x += -(k * depth + d * min(depth / ramp, 1.0) * dq[j])
            if not math.isfinite(x):  # nothing non-finite leaves the layer
                x = 0.0
            lo = p - step
            hi = p + step
            if lo < -m:
                lo = -m
            if hi > m:
                hi = m
            # min(max(x, lo), hi), as np.minimum(np.maximum(·)) computes it
            y = hi if (lo if x < lo else x) > hi else (lo if x < lo else x)
            if y != x:
                if x > m or x < -m:
                    torque_hit = True
                    if y != (m if x > m else -m):
                        rate_hit = True
                else:
                    rate_hit = True
            out.append(y)
        self._tau_prev[:] = out
        self._account(state.t, near if finite_state else None, torque_hit, rate_hit)
        return np.array(out)

    def _finish_compiled(self, state: RobotState, tau: np.ndarray) -> np.ndarray | None:
        """:meth:`_finish` of the inner controller's ``tau`` as one compiled call
        (:func:`tactex.control.joint_kernels.limit_torque`); a non-finite ``tau`` holds, as in
        :meth:`torque`. None (warned) when the compiled kernel cannot take the state's arrays."""
        lim = self.limits
        flags = joint_kernels.run(self._limit_kernel, tau, self._tau_prev, self._tau_max, state.q, state.dq,
                                  self._q_lo_margin, self._q_hi_margin, lim.joint_limit_stiffness,
                                  lim.joint_limit_damping, self._rate_step,
                                  then="the safety layer limits with Python from now on")
        if flags is None:
            self._limit_kernel = None
            return None
        if flags & joint_kernels.LIMIT_NOT_FINITE:
            self._event(state.t, "nan_torque", f"inner controller returned {tau!r}; holding")
            return self._finish(state, self._hold())
        near_bits = flags >> joint_kernels.LIMIT_NEAR_SHIFT
        near = [j for j in range(tau.shape[0]) if near_bits >> j & 1] if near_bits else []
        self._account(state.t, near, bool(flags & joint_kernels.LIMIT_TORQUE), bool(flags & joint_kernels.LIMIT_RATE))
        return self._tau_prev.copy()

    def _account(self, t: float, near: list[int] | None, torque_hit: bool, rate_hit: bool) -> None:
        """Events and counts of one command's limits; ``near``: joints near a limit (None when the
        state was not finite and the joint limits were not checked)."""
        if near is not None:
            if near and not self._held:
                self._event(t, "joint_limit", f"joints {near} within {self.limits.joint_limit_margin} rad of a limit; "
                            "repelling")
            self._held = bool(near)
        if torque_hit or rate_hit:
            self._flag(t, "torque_limit", torque_hit, "torque saturated at the joint limits")
            self._flag(t, "torque_rate_limit", rate_hit, "torque rate saturated")
        elif self._saturating["torque_limit"] or self._saturating["torque_rate_limit"]:
            self._flag(t, "torque_limit", False, "")
            self._flag(t, "torque_rate_limit", False, "")

    def _flag(self, t: float, kind: str, active: bool, detail: str) -> None:
        if not active and not self._saturating[kind]:
            return
        if active:
            self.counts[kind] = self.counts.get(kind, 0) + 1
            if not self._saturating[kind]:
                self.events.append(SafetyEvent(float(t) if np.isfinite(t) else float("nan"), kind, detail))
        self._saturating[kind] = active

    def telemetry(self) -> dict[str, float]:
        out = dict(self.inner.telemetry())
        out["safety_retreating"] = float(self.retreating)
        out["safety_events"] = float(len(self.events))
        return out


_add = np.add.reduce
_F64 = np.dtype(np.float64)


def _state_finite(state: RobotState) -> bool:
    """Every number of the state is finite. One concatenation and one reduction (NaN and inf
    propagate through a sum): at 1 kHz far cheaper than one check per array. (``ravel`` views, not
    ``axis=None``, which copies through a slower flattening path.)"""
    flat = np.concatenate((
        state.q, state.dq, state.tau_measured, state.ee_position, state.ee_rotation.ravel(), state.ee_twist,
        state.jacobian.ravel(), state.mass_matrix.ravel(), state.coriolis, state.gravity, state.wrench_tool,
    ))
    return math.isfinite(float(_add(flat)) + state.t)


def _replace_wrench(state: RobotState, wrench: np.ndarray) -> RobotState:
    from dataclasses import replace

    return replace(state, wrench_tool=wrench.copy())
