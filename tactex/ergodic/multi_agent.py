"""Several agents in one step (TEC eq. 3 and 19 with a team): footprints first, then one diffusion, then moves.

Every agent's footprint of this step goes into the shared coverage first; then one source and one
diffusion; then each agent follows that potential from where it stood. Stepping the agents one after
the other would diffuse the potential once per agent. The compiled step walks one agent at a time and
is not used here. :class:`MultiAgent` is that part of :class:`~tactex.ergodic.explorer.HedacExplorer`.
"""

from __future__ import annotations

from tactex.ergodic.command import ExplorationCommand
from tactex.ergodic.hedac_step import FOOTPRINT, MOVE, WHOLE

__all__ = ["MultiAgent"]


class MultiAgent:
    """The explorer's team step (mixed into :class:`~tactex.ergodic.explorer.HedacExplorer`)."""

    def _step_together(self, agents: list[int], exact: bool) -> list[ExplorationCommand]:
        """One step of the agents (indices, two or more): their footprints, one diffusion, their moves (in order)."""
        near = self._near.copy()
        self._pass = FOOTPRINT
        try:
            for i in agents:
                self._step_agent(i, exact)
            self._update_potential()
            self._near[:] = near  # the move pass starts from the same neighbourhoods
            self._pass = MOVE
            return [self._step_agent(i, exact) for i in agents]
        finally:
            self._pass = WHOLE
