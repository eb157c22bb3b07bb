"""Virtual exploration agents moving on the tangent plane (TEC eq. 6, Table II limits).

An agent turns the unit gradient direction ĝ (in the tangent plane) into a displacement for one
step. Its velocity lives in the tangent plane of the previous step; it is carried to the new
tangent plane by removing its normal component and restoring its length (a first-order parallel
transport), so a turn of the surface does not count as acceleration. Limits are exact for the
tangential dynamics: ‖v‖ ≤ v_max and ‖v_new − transport(v_old)‖ ≤ a_max·dt.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from tactex.ergodic.compiled_step import braked_direction, transported_floats

__all__ = ["Agent", "FirstOrderAgent", "SecondOrderAgent", "make_agent", "transport"]


def transport(v: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """v [m/s] (3,) carried to the plane ⊥ ``normal``, keeping its length (see
    :func:`tactex.ergodic.compiled_step.transported_floats`: a v along the normal fades instead)."""
    v0, v1, v2 = (float(x) for x in v)
    n0, n1, n2 = (float(x) for x in normal)
    return np.array(transported_floats(v0, v1, v2, n0, n1, n2))


class Agent(ABC):
    """Base class: state = velocity [m/s] (3,); limits in SI units."""

    def __init__(self, max_velocity: float, max_acceleration: float, dt: float) -> None:
        self.max_velocity = float(max_velocity)
        self.max_acceleration = float(max_acceleration)
        self.dt = float(dt)
        self.velocity = np.zeros(3)

    def reset(self) -> None:
        self.velocity = np.zeros(3)

    @abstractmethod
    def command_velocity(self, direction: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """New velocity [m/s] from the unit gradient direction (tangent, or zero) and the unit normal."""

    def command_velocity_floats(self, direction: tuple, normal: tuple) -> tuple:
        """:meth:`command_velocity` on float triples (the explorer's per-step path)."""
        return tuple(self.command_velocity(np.array(direction), np.array(normal)).tolist())

    def edge_direction(self, direction: tuple, inward: tuple, normal: tuple) -> tuple:
        """The unit acceleration direction at a scan edge, from the gradient's ``direction`` (its
        outward part already removed), the unit tangent ``inward`` pointing into the cloud and the
        unit ``normal`` (float triples). Without inertia there is nothing to brake: ``direction``."""
        return direction

    def _clip(self, v: np.ndarray) -> np.ndarray:
        nv = float(np.sqrt(v @ v))
        return v * (self.max_velocity / nv) if nv > self.max_velocity else v

    def reachable_velocity(self, wanted: np.ndarray) -> tuple[np.ndarray, bool]:
        """The velocity [m/s] (3,) nearest to ``wanted`` (within v_max) that this agent can take in one
        step from its current one, for a move that is not the gradient's (a hop), and whether it
        differs from ``wanted``. A first-order agent has no acceleration limit: ``wanted`` as it is."""
        return wanted, False


class FirstOrderAgent(Agent):
    """ẋ = v_max ĝ: full speed along the gradient."""

    def command_velocity(self, direction: np.ndarray, normal: np.ndarray) -> np.ndarray:
        return self._clip(self.max_velocity * direction)


class SecondOrderAgent(Agent):
    """ẍ = a_max ĝ (eq. 6 with the acceleration limit), then ‖ẋ‖ ≤ v_max."""

    def reachable_velocity(self, wanted: np.ndarray) -> tuple[np.ndarray, bool]:
        # the change clipped to a_max·dt, then ‖v‖ ≤ v_max (a projection onto the ball: it never
        # lengthens the change)
        dv = wanted - self.velocity
        dvn = float(np.sqrt(dv @ dv))
        a_dt = self.max_acceleration * self.dt
        if dvn <= a_dt * (1.0 + 1e-12):
            return wanted, False
        return self._clip(self.velocity + dv * (a_dt / dvn)), True

    def command_velocity(self, direction: np.ndarray, normal: np.ndarray) -> np.ndarray:
        return np.array(self.command_velocity_floats(tuple(direction.tolist()), tuple(normal.tolist())))

    def edge_direction(self, direction: tuple, inward: tuple, normal: tuple) -> tuple:
        """At a scan edge the velocity's outward part must go (the agent stays within
        max_off_cloud_voxels of the cloud); dropping it after the fact changes the velocity by up to
        v_max in one step, well over a_max·dt. So the acceleration brakes it first: its inward
        share is at least b = min(1, v_out / (a_max·dt)) (all of it while the outward speed exceeds
        one step's change). A gradient that already turns inward that much is kept; otherwise the
        inward share is b and the rest, √(1 − b²), goes along the edge in the gradient's sense."""
        t0, t1, t2 = self._transported_floats(normal)
        i0, i1, i2 = inward
        d0, d1, d2 = direction
        v_out = -(t0 * i0 + t1 * i1 + t2 * i2)
        return braked_direction(d0, d1, d2, i0, i1, i2, v_out, self.max_acceleration * self.dt)

    def _transported_floats(self, normal: tuple) -> tuple:
        """:func:`transport` of the velocity to the plane ⊥ normal, in Python floats."""
        v0, v1, v2 = self.velocity.tolist()
        n0, n1, n2 = normal
        return transported_floats(v0, v1, v2, n0, n1, n2)

    def command_velocity_floats(self, direction: tuple, normal: tuple) -> tuple:
        # transport() and the clip in Python floats (hot path: three numbers per vector)
        t0, t1, t2 = self._transported_floats(normal)
        a = self.max_acceleration * self.dt
        d0, d1, d2 = direction
        w0, w1, w2 = t0 + a * d0, t1 + a * d1, t2 + a * d2
        nw = (w0 * w0 + w1 * w1 + w2 * w2) ** 0.5
        if nw > self.max_velocity:
            k = self.max_velocity / nw
            w0, w1, w2 = w0 * k, w1 * k, w2 * k
        return w0, w1, w2


def make_agent(order: int, max_velocity: float, max_acceleration: float, dt: float) -> Agent:
    """The agent of the given order (1 or 2) with limits in m/s and m/s²."""
    cls = FirstOrderAgent if order == 1 else SecondOrderAgent
    return cls(max_velocity, max_acceleration, dt)
