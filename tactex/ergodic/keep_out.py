"""Keep-out zones of the explorer: cloud points no footprint may touch (a sticker, a sensor).

They hold no target, and every agent keeps its point at least r_a + ½ voxel from them: a step that
would come closer slides along the zone or stops (a stop is a stall, and the agent relocates, see
:mod:`.relocation`). :class:`KeepOut` is the part of :class:`~tactex.ergodic.explorer.HedacExplorer`
that sets them up and guards each step; it reads the explorer's cloud (``_points``, ``spacing``,
``_r_a``, ``_step_max``, ``_off``) and agents (``_x``, ``_near``, ``_agents``, ``path_lengths``).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from tactex.ergodic.command import ExplorationCommand
from tactex.errors import InputError

__all__ = ["KEEP_OUT_MARGIN", "KeepOut"]

#: A keep-out zone's clearance beyond the footprint radius [voxels]: the footprint is laid around the
#: agent projected on its fitted patch, a fraction of a voxel from the agent point the guard checks.
KEEP_OUT_MARGIN = 0.5


class KeepOut:
    """The explorer's keep-out zones (mixed into :class:`~tactex.ergodic.explorer.HedacExplorer`)."""

    def _set_keep_out(self, keep_out: np.ndarray | None) -> None:
        n = len(self.cloud)
        if keep_out is None:
            mask = np.zeros(n, dtype=bool)
        else:
            mask = np.asarray(keep_out)
            if mask.shape != (n,) or mask.dtype != bool:
                raise InputError(f"keep_out must be a boolean mask of shape ({n},) (one per cloud point), "
                                 f"got {mask.dtype} {mask.shape}")
            mask = mask.copy()
        if mask.all():
            raise InputError("the keep-out zone marks every cloud point: nothing may be touched; mark fewer points "
                             "(--keep-out-threshold, --keep-out-mask)")
        self._keep_out = mask
        self._ko_idx = np.flatnonzero(mask)
        self._ko_clear = self._r_a + KEEP_OUT_MARGIN * self.spacing
        if self._ko_idx.size:
            self._ko_tree = cKDTree(self._points[self._ko_idx])
            self._ko_dist = self._ko_tree.query(self._points)[0]
        else:
            self._ko_tree = None
            self._ko_dist = np.full(n, np.inf)
        # Agent points near cloud point j are surely clear when j is this much farther than the
        # clearance: the agent is at most a step plus max_off_cloud_voxels from its nearest point.
        self._ko_sure = self._ko_clear + 2.0 * (self._step_max + self._off) + self.spacing
        self._safe = self._ko_dist >= self._ko_clear

    @property
    def keep_out(self) -> np.ndarray:
        """The kept-out cloud points (N,) (bool)."""
        return self._keep_out.copy()

    @property
    def clear_points(self) -> np.ndarray:
        """Cloud points (N,) (bool) an agent may stand on: at least r_a + ½ voxel from every kept-out point."""
        return self._safe.copy()

    @property
    def keep_out_clearance_m(self) -> float:
        """Least distance [m] between the agent and a kept-out point: footprint radius + ½ voxel."""
        return self._ko_clear

    @property
    def keep_out_contacts(self) -> int:
        """Kept-out cloud points inside a footprint so far (0 unless something is wrong)."""
        self._require_state()
        return int(np.count_nonzero(self._cov.take(self._ko_idx) > 0.0)) if self._ko_idx.size else 0

    def _clear_of_keep_out(self, x: np.ndarray, near: int) -> bool:
        if self._ko_tree is None or self._ko_dist.item(near) >= self._ko_sure:
            return True
        return float(self._ko_tree.query(x)[0]) >= self._ko_clear

    def _keep_out_guard(self, cmd: ExplorationCommand, x_old: np.ndarray) -> ExplorationCommand:
        """The step of cmd, kept clear of the keep-out zones: slid along the zone (its part towards the
        nearest kept-out point dropped), or not taken at all (the agent stops; a stop is a stall)."""
        i = cmd.agent
        x_new = cmd.point
        if self._clear_of_keep_out(x_new, int(self._near[i])):
            return cmd
        self._bridges[i] = None  # a hop towards a keep-out zone ends here
        _, q = self._ko_tree.query(x_new)
        away = x_old - self._points[self._ko_idx[q]]
        na = float(np.sqrt(away @ away))
        move = x_new - x_old
        step_old = float(np.sqrt(move @ move))
        x_fix = x_old.copy()
        if na > 0.0:
            away /= na
            slid = move - min(float(move @ away), 0.0) * away
            if self._clear_of_keep_out(x_old + slid, int(self._near[i])) and \
                    float(self._ko_tree.query(x_old + slid)[0]) >= self._ko_clear:
                x_fix = x_old + slid
        move = x_fix - x_old
        step = float(np.sqrt(move @ move))
        self.path_lengths[i] += step - step_old
        v = move * (1.0 / self._dt)
        v -= float(v @ cmd.normal) * cmd.normal
        self._agents[i].velocity = v
        self._x[i] = x_fix
        self._near[i] = int(self._tree.query(x_fix)[1])
        return cmd._replace(point=x_fix.copy(), velocity=v.copy())
