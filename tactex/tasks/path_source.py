"""What a task follows on the surface: the :class:`PathSource` protocol.

A contact task (``tactex clean``) drives the tool along the commands of a path source, one per
exploration step, and does not care where they come from: the HEDAC explorer
(:class:`~tactex.ergodic.explorer.HedacExplorer`, which follows the target), a boustrophedon
(:class:`~tactex.tasks.raster.RasterPath`, which ignores it) or a straight stroke through an island
of dirt (:class:`~tactex.tasks.stroke.IslandStroke`'s :class:`~tactex.tasks.raster.WaypointPath`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np

from tactex.ergodic.command import ExplorationCommand
from tactex.ergodic.relocation import RelocationCommand

__all__ = ["PathSource", "start"]


@runtime_checkable
class PathSource(Protocol):
    """A path on the surface served one :class:`ExplorationCommand` per step.

    An explorer's ``step`` may return a :class:`~tactex.ergodic.relocation.RelocationCommand` instead: lift
    off, fly, touch down at its point.
    """

    def reset(self, x0: np.ndarray) -> ExplorationCommand | Sequence[ExplorationCommand]:
        """Start again at ``x0`` (3,) [m] (path length and relocations from zero): the first command, or one
        per agent of a multi-agent explorer (:func:`start` takes the first)."""
        ...

    def step(self, measured_position: np.ndarray | None = None) -> ExplorationCommand | RelocationCommand:
        """The next command; ``measured_position`` (3,) [m]: where the tool is, for a source that follows it."""
        ...

    def update_target(self, mass: np.ndarray, keep_coverage: bool = False) -> None:
        """A new target mass (N,) on the same points (the camera's re-measurement, the wear model's
        prediction); a source that ignores the target keeps its path."""
        ...

    @property
    def done(self) -> bool:
        """The path has ended (a waypoint path at its last point; an explorer never ends by itself)."""
        ...

    @property
    def path_length(self) -> float:
        """Length slid on the surface since the last reset [m]."""
        ...

    @property
    def relocations(self) -> Sequence[RelocationCommand]:
        """The flights through the air since the last reset (none for a path that never leaves the surface)."""
        ...


def start(path: PathSource, x0: np.ndarray) -> ExplorationCommand:
    """Reset ``path`` at ``x0`` (3,) [m] and return its first command (the first agent's)."""
    out = path.reset(x0)
    return out if isinstance(out, ExplorationCommand) else out[0]
