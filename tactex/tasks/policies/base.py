"""The base of VA-UFIC's force-motion policies: a reference over time in the tool's tangent plane.

A policy says, at time t [s] from its start, where the tool should be in the tangent plane at the
contact, as an in-plane offset (u, v) [m] along the tool frame's x and y axes from where the policy
started, how fast it moves there (du/dt, dv/dt) [m/s], and the normal force set point along the tool
axis [N]. The wipe applies the offset's increments in the current tool frame, so the path follows the
surface as VA-UFIC re-orients the tool (VA-UFIC §II-B: "regenerates the motion and force policy").

Each kind is one file that subclasses :class:`PolicySegment`; a :class:`~.sequence.PolicySequence`
runs segments one after another, each starting where the previous one ended.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import NamedTuple

from tactex.errors import ConfigError

__all__ = ["ForceMotionPolicy", "ForceRamp", "PolicyPoint", "PolicySegment", "point_problem"]


class PolicyPoint(NamedTuple):
    """A policy at one instant, tool frame: offset u, v [m], rate du, dv [m/s], force set point [N]."""

    u_m: float
    v_m: float
    du_m_s: float
    dv_m_s: float
    force_n: float


def point_problem(point: object) -> str | None:
    """What is wrong with what a policy's ``at`` returned, or None for a :class:`PolicyPoint` of finite floats."""
    if not isinstance(point, PolicyPoint):
        return (f"at() returned {type(point).__name__}, not a PolicyPoint(u_m, v_m, du_m_s, dv_m_s, force_n) "
                "(tactex.tasks.policies.PolicyPoint)")
    try:
        if all(math.isfinite(x) for x in point):
            return None
    except TypeError:
        pass
    return f"at() returned {point}: every field must be a finite number"


@dataclass(frozen=True)
class ForceRamp:
    """The normal force set point over a segment: ``start_n`` at its start, ``end_n`` at its end,
    linear in between [N] (a constant force has ``start_n == end_n``)."""

    start_n: float
    end_n: float

    @property
    def constant(self) -> bool:
        return self.start_n == self.end_n

    def at(self, t_s: float, duration_s: float) -> float:
        """The set point at ``t_s`` [s] into a segment of ``duration_s`` [s], held outside it [N]."""
        if self.constant or not math.isfinite(duration_s) or duration_s <= 0.0:
            return self.start_n
        s = min(max(t_s / duration_s, 0.0), 1.0)
        return self.start_n + (self.end_n - self.start_n) * s

    @property
    def bounds_n(self) -> tuple[float, float]:
        return min(self.start_n, self.end_n), max(self.start_n, self.end_n)


class ForceMotionPolicy(ABC):
    """What the wipe follows: :meth:`at` gives the reference at policy time t [s].

    The contract a policy of one's own keeps (the wipe checks it before the arm moves, over the run's
    length every 2 ms, and at every tick while the run follows it, :mod:`.guard`): ``at`` returns a
    :class:`PolicyPoint` of finite floats; its rates are those of its offsets (du = d(u)/dt); speed,
    acceleration and force stay within the task's limits; ``duration_s`` is finite, or ``math.inf`` for a
    policy the run's duration ends; ``at`` is cheap (it runs inside the robot's 1 ms cycle). Not checkable,
    so the policy's own to keep: the same time gives the same answer."""

    #: how long the policy runs [s]; ``math.inf`` for one that runs until the task stops it
    duration_s: float

    @abstractmethod
    def at(self, t_s: float) -> PolicyPoint:
        """The reference ``t_s`` [s] after the policy started."""

    def segment_index(self, t_s: float) -> int:
        """Which segment runs at ``t_s`` [s] (0 for a single one)."""
        return 0

    @property
    def segment_starts_s(self) -> tuple[float, ...]:
        """The start time of each segment [s]."""
        return (0.0,)

    @property
    def constant_force_n(self) -> float | None:
        """The force set point if it never changes [N], else None."""
        return None


class PolicySegment(ForceMotionPolicy):
    """One kind of motion over ``duration_s`` [s] with a :class:`ForceRamp`, starting at offset (0, 0).

    A kind implements :meth:`path` (offset and rate at a time inside the segment). Outside
    [0, duration_s] the segment continues in a straight line at its end velocity (what a blend between
    segments mixes), and the force holds its end value."""

    kind: str = ""
    #: the kind's own fields, in the order a policy file lists them (for messages)
    fields: tuple[str, ...] = ()

    def __init__(self, duration_s: float, force: ForceRamp) -> None:
        if not (isinstance(duration_s, (int, float)) and duration_s > 0 and not math.isnan(duration_s)):
            raise ConfigError(f"{self.kind}: duration_s must be a positive number of seconds, got {duration_s!r}")
        self.duration_s = float(duration_s)
        self.force = force

    @abstractmethod
    def path(self, t_s: float) -> tuple[float, float, float, float]:
        """Offset u, v [m] and rate du, dv [m/s] at ``t_s`` ∈ [0, duration_s] [s]; (0, 0) at t = 0."""

    def at(self, t_s: float) -> PolicyPoint:
        d = self.duration_s
        if t_s < 0.0:
            u, v, du, dv = self.path(0.0)
            u, v = u + du * t_s, v + dv * t_s
        elif t_s > d:
            u, v, du, dv = self.path(d)
            u, v = u + du * (t_s - d), v + dv * (t_s - d)
        else:
            u, v, du, dv = self.path(t_s)
        return PolicyPoint(u, v, du, dv, self.force.at(t_s, d))

    @property
    def constant_force_n(self) -> float | None:
        return self.force.start_n if self.force.constant else None
