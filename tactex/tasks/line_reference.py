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

- **Lead** (:func:`led_point`): the line's point runs ``lead_s`` ahead along the agent's step, a
  velocity feed-forward: K·(x_a(t + τ) − x) − D·ẋ ≈ K·(x_a − x) − D·(ẋ − ẋ_a) for τ = D/K. The point
  is extrapolated on the step's chord (off the surface by s²/2R, along the line, where the line
  impedance does not act).
- **Normal feedback** (:class:`ToolNormal`, :func:`blend_normals`): the line's direction leans from
  the agent's normal towards the captured surface's normal under the measured tool, so the tool
  presses where it is while the line, still through the agent point, pulls it along the surface.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from tactex.errors import InputError
from tactex.pointcloud.cloud import SurfaceCloud

__all__ = ["ToolNormal", "blend_normals", "led_point"]


def led_point(p_prev: np.ndarray, p_next: np.ndarray, frac: float, lead_steps: float) -> np.ndarray:
    """The agent's point ``frac`` of the way along its step ``p_prev`` → ``p_next`` [m] (3,), led by
    ``lead_steps`` more steps on the same chord (``lead_s / dt_step``; a held agent, whose step has no
    length, has no lead)."""
    p_prev = np.asarray(p_prev, dtype=float)
    return p_prev + (frac + lead_steps) * (np.asarray(p_next, dtype=float) - p_prev)


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
