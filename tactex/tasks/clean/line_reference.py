"""The commanded line of the contact phase between two agent steps: led ahead of the agent, and its
normal turned towards the surface under the tool.

TEC's target line (eq. 28) runs through the agent point along the agent's normal. The GA line
impedance (eq. 46–47) damps the tool's own twist, not its error from a moving target, so a tool that
follows an agent moving at speed v settles about v·D/K behind it (tool x/y: D/K = 150/750 = 0.2 s,
1.2 cm at the agent's 6 cm/s), plus the pad's friction over the stiffness. On a flat plate the lag only
shifts where the pad wipes. On a strongly curved wall it is an angle: the pad presses where the surface
faces another way than the commanded line (a 4 cm cup radius turns 17° over 1.2 cm), so the force
along the tool axis leaves its band and the line's pull around the wall fights the contact.

Two general remedies, both zero-effect on a plane:

- **Lead** (:class:`LineLead`): the line's point runs ``lead_s`` times the agent's velocity ahead, a
  velocity feed-forward: K·(x_a + τ·ẋ_a − x) − D·ẋ = K·(x_a − x) − D·(ẋ − ẋ_a) for τ = D/K, and a
  little more makes up for the pad's sliding friction μ·F, which holds the tool μ·F/K back. The point
  leaves the surface along the tangent (by s²/2R, about along the line, where the line impedance
  does not act).
- **Normal feedback** (:class:`ToolNormal`, :func:`blend_normals`): the line's direction leans from
  the agent's normal towards the captured surface's normal under the measured tool, so the tool
  presses where it is while the line, still through the agent point, pulls it along the surface.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from tactex.errors import InputError
from tactex.pointcloud.cloud import SurfaceCloud

__all__ = ["LEAD_SMOOTHING_S", "LineLead", "ToolNormal", "blend_normals"]

#: [s] time constant of the lead's low-pass, the line impedance's D/K: the offset follows a change of the agent's
#: velocity about as quickly as the tool itself can (a shorter 0.1 s leaves torque-rate clips on the cup's wall)
LEAD_SMOOTHING_S = 0.2


class LineLead:
    """The lead of the line's point ahead of the agent [m]: ``lead_s`` times the agent's velocity (its
    last step over the step's duration), through a first-order low-pass of ``smoothing_s``.

    The agent moves in steps, so its velocity jumps at every step boundary (a turn, a reversal at a
    stroke's end, a held step); an unfiltered lead would jump with it, by up to ``lead_s`` × the speed
    change (1.2 cm at a hold), a step in the reference the line stiffness turns into a torque step.

    Args:
        lead_s: how far ahead [s], ≥ 0 (the line impedance's D/K, 0.2 s, and the friction's share).
        step_s: the agent's step duration [s], > 0.
        smoothing_s: time constant of the low-pass [s], > 0.
    """

    def __init__(self, lead_s: float, step_s: float, smoothing_s: float = LEAD_SMOOTHING_S) -> None:
        if not (np.isfinite(lead_s) and lead_s >= 0):
            raise InputError(f"LineLead: lead_s must be a time ≥ 0 s, got {lead_s!r}")
        if not (np.isfinite(step_s) and step_s > 0 and np.isfinite(smoothing_s) and smoothing_s > 0):
            raise InputError(f"LineLead: step_s and smoothing_s must be > 0 s, got {step_s!r} and {smoothing_s!r}")
        self.lead_steps = lead_s / step_s
        self.smoothing_s = float(smoothing_s)
        self._offset = (0.0, 0.0, 0.0)
        self._gain, self._gain_dt = 0.0, float("nan")  # the low-pass's gain and the period it was made for

    def reset(self) -> None:
        """No lead (a new contact leg: the agent starts from rest)."""
        self._offset = (0.0, 0.0, 0.0)

    def offset(self, step_start: np.ndarray, step_end: np.ndarray, dt_s: float) -> np.ndarray:
        """Advance the low-pass by ``dt_s`` [s] towards the lead of the current step ``step_start`` →
        ``step_end`` [m] and return the offset (3,) [m] to add to the agent's interpolated point."""
        # on Python floats: called every control tick, between a robot state and its command
        if dt_s != self._gain_dt:
            self._gain, self._gain_dt = 1.0 - math.exp(-dt_s / self.smoothing_s), dt_s
        a, k = self._gain, self.lead_steps
        s0, s1, s2 = np.asarray(step_start, dtype=float).tolist()
        e0, e1, e2 = np.asarray(step_end, dtype=float).tolist()
        o0, o1, o2 = self._offset
        o0 += a * (k * (e0 - s0) - o0)
        o1 += a * (k * (e1 - s1) - o1)
        o2 += a * (k * (e2 - s2) - o2)
        self._offset = (o0, o1, o2)
        return np.array(self._offset)


class ToolNormal:
    """The captured surface's unit normal under the tool: the mean normal of the ``k`` cloud points
    nearest the tool centre point (a capture's normals carry noise; 8 points of a 3 mm voxel grid span
    about a centimetre, well inside a 2.5 cm pad).

    Args:
        cloud: the captured (or given) cloud, with normals.
        tree: a KD-tree over ``cloud.points`` to share (one is built when None).
        k: neighbours averaged [-], ≥ 1.
    """

    def __init__(self, cloud: SurfaceCloud, tree: cKDTree | None = None, k: int = 8) -> None:
        if cloud.normals is None:
            raise InputError("the normal under the tool needs a cloud with normals")
        if k < 1:
            raise InputError(f"ToolNormal: k must be ≥ 1, got {k}")
        self._normals = cloud.normals
        self._tree = tree if tree is not None else cKDTree(cloud.points)
        self._k = min(int(k), len(cloud))

    def at(self, tcp_m: np.ndarray) -> np.ndarray:
        """Unit normal (3,) of the surface nearest ``tcp_m`` (3,) [m]."""
        _, idx = self._tree.query(np.asarray(tcp_m, dtype=float), k=self._k)
        n = self._normals[np.atleast_1d(idx)].mean(axis=0)
        norm = float(np.sqrt(n @ n))
        if not norm > 1e-9:  # opposed normals cancel (a knife edge): the nearest point's own normal
            return self._normals[int(np.atleast_1d(idx)[0])].copy()
        return n / norm


def blend_normals(agent_normal: np.ndarray, tool_normal: np.ndarray, feedback: float) -> np.ndarray:
    """The line's unit normal (3,): ``agent_normal`` turned towards ``tool_normal`` (both unit, (3,)) by the
    weight ``feedback`` in [0, 1] (0: the agent's, TEC eq. 28; 1: the surface's under the tool). Opposed
    normals (the tool on the far side of a thin wall) keep the agent's."""
    a, t = np.asarray(agent_normal, dtype=float), np.asarray(tool_normal, dtype=float)
    n = (1.0 - feedback) * a + feedback * t
    norm = float(np.sqrt(n @ n))
    if not norm > 1e-6 or float(a @ t) <= 0.0:
        return a.copy()
    return n / norm
