"""What the tasks share about the loop: the tool's orientation on a surface, and the loop itself
(:class:`~tactex.robots.loop.ControlLoop`, in the robot stage, named here for the tasks)."""

from __future__ import annotations

import numpy as np

from tactex.robots.loop import ControlLoop

__all__ = ["TOOL_DOWN", "ControlLoop", "tool_rotation_for_normal"]

#: Tool pointing straight down (tool z = −world z), tool x along world x.
TOOL_DOWN = np.diag([1.0, -1.0, -1.0])


def tool_rotation_for_normal(normal_out: np.ndarray, x_hint: np.ndarray | None = None) -> np.ndarray:
    """world_R_tool with the tool z axis along −``normal_out`` (pressing into the surface) and the
    tool x axis as close as possible to ``x_hint`` (default world x)."""
    z = -np.asarray(normal_out, dtype=float)
    z = z / np.linalg.norm(z)
    hint = np.array([1.0, 0.0, 0.0]) if x_hint is None else np.asarray(x_hint, dtype=float)
    x = hint - (hint @ z) * z
    if np.linalg.norm(x) < 1e-6:
        x = np.array([0.0, 1.0, 0.0]) - z[1] * z
    x = x / np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])
