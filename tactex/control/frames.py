"""Frame changes of 6-vectors ([linear; angular]) between the tool and the world frame."""

from __future__ import annotations

import numpy as np

__all__ = ["rotate6", "tool_to_world", "world_to_tool"]


def rotate6(rot: np.ndarray, v: np.ndarray) -> np.ndarray:
    """blockdiag(rot, rot) @ v for a 6-vector (wrench or twist about the same point)."""
    return np.concatenate([rot @ v[:3], rot @ v[3:]])


def tool_to_world(rot_world_tool: np.ndarray, v_tool: np.ndarray) -> np.ndarray:
    """A tool-frame wrench/twist expressed in the world frame (same reference point, the TCP):
    [Ra; Rb], as one (2, 3) @ (3, 3) product (cheaper at 1 kHz than two mat-vecs and a concatenate)."""
    return (v_tool.reshape(2, 3) @ rot_world_tool.T).ravel()


def world_to_tool(rot_world_tool: np.ndarray, v_world: np.ndarray) -> np.ndarray:
    """A world-frame wrench/twist expressed in the tool frame (same reference point, the TCP): [Rᵀa; Rᵀb]."""
    return (v_world.reshape(2, 3) @ rot_world_tool).ravel()
