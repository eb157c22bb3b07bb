"""Hops: the explorer's in-contact moves across a scan hole, along a gap link of the Laplacian.

Where the agent stands at a scan edge and the potential beyond a hole (at the far end of a link of
:func:`~tactex.ergodic.bridges.gap_links`) beats everything around it, the agent slides along the
link's chord to the far side (:class:`~tactex.ergodic.bridges.Bridge`), laying its footprint on
the way, within its speed and acceleration limits. :class:`Hops` is that part of
:class:`~tactex.ergodic.explorer.HedacExplorer`; the planned passes' hunt asks for a hop too
(:mod:`.guidance`).
"""

from __future__ import annotations

import numpy as np

from tactex.ergodic.bridges import Bridge
from tactex.ergodic.command import ExplorationCommand
from tactex.ergodic.hedac_step import FOOTPRINT, MOVE
from tactex.ergodic.surface_fit import normal_at, tangent_basis

__all__ = ["Hops"]


class Hops:
    """The explorer's hops across scan holes (mixed into :class:`~tactex.ergodic.explorer.HedacExplorer`);
    ``_bridges[i]`` is agent i's hop in progress, or None."""

    def _plan_bridge(self, nbr: np.ndarray, u: np.ndarray, u0: float, here: np.ndarray,
                     nrm: np.ndarray) -> Bridge | None:
        """A hop along a gap link of the neighbours (see :mod:`.bridges`) when the potential at its
        far end beats every value around the agent (u − u0 at the neighbours, plus the raw source)."""
        far = np.unique(self._gaps.of(nbr))
        # The flight starts here, not at the neighbour the link leaves from: keep it within max_bridge_voxels.
        reach = self._points.take(far, 0) - here
        far = far[np.einsum("ij,ij->i", reach, reach) <= self._bridge_max2]
        if far.size == 0:
            return None
        u_far = self._phi.take(far, 0).dot(self._coef)
        local = u
        if self._source_w > 0.0:
            local = u + self._source_w * self._source_at(nbr)
            u_far += self._source_w * self._source_at(far)
        k = int(u_far.argmax())
        if float(u_far[k]) <= float(local.max()) + u0:
            return None
        return self._hop_bridge(int(far[k]), here, nrm)

    def _hop_bridge(self, j: int, here: np.ndarray, nrm: np.ndarray) -> Bridge | None:
        """A hop from ``here`` [m] (normal ``nrm``) to cloud point j across a gap link, or None when j's side faces the
        other way (the back of a part, not across a hole)."""
        end = self._points[j]
        normals = self.cloud.normals
        ref = nrm if normals is None else normals[j]  # the cloud's own outward side when it has one
        end_normal = normal_at(self._points, self._tree, self._n_n, end, ref)
        if float(end_normal @ nrm) < 0.0:
            return None
        self.bridges_taken += 1
        return Bridge(j, here.copy(), end.copy(), nrm.copy(), end_normal)

    def _bridge_step(self, i: int) -> ExplorationCommand:
        """One step of a hop in progress: the footprint where the agent is, the potential, then
        on along the chord."""
        bridge = self._bridges[i]
        x = self._x[i]
        if self._pass != MOVE:
            nrm = bridge.normal_at(x)
            cand = self._ball[int(self._tree.query(x)[1])]
            d = self._points.take(cand, 0)
            d -= x
            dd = np.einsum("ij,ij->i", d, d)
            inside = (dd <= self._r_a2).nonzero()[0]
            dn = d.take(inside, 0).dot(nrm)
            phi = np.exp(-self._eps2 * (dd.take(inside) - dn * dn))  # r on the plane ⊥ the chord's normal
            self._add_coverage(cand.take(inside), phi)
            if self._pass == FOOTPRINT:
                return None
            self._update_potential()
        return self._bridge_move(i, x, bridge)

    def _bridge_move(self, i: int, x: np.ndarray, bridge: Bridge) -> ExplorationCommand:
        """Move from x [m] (the agent, or the robot's measured point) along the chord towards the
        bridge's end, at most v_max·dt from x: the goal is x's projection on the chord advanced by
        v_max·dt, so an agent off the chord (a measured point above it, the unprojected agent at
        the start) converges to it instead of drifting. The agent's limits hold on the hop too:
        the velocity changes by at most a_max·dt per step, so a hop that starts across the
        agent's heading first bends towards the chord. On arrival the walk resumes from the end."""
        chord = bridge.end - bridge.start
        length = float(np.sqrt(chord @ chord))
        t = bridge.share(x)
        if (1.0 - t) * length <= self._step_max:
            goal = bridge.end
        else:
            goal = bridge.start + chord * (t + self._step_max / length)
        move = goal - x
        ml = float(np.sqrt(move @ move))
        arrived = goal is bridge.end and ml <= self._step_max
        if ml > self._step_max:
            move *= self._step_max / ml
            ml = self._step_max
        v, limited = self._agents[i].reachable_velocity(move * (1.0 / self._dt))
        if limited:
            move = v * self._dt
            ml = float(np.sqrt(move @ move))
            arrived = False
        x_new = x + move
        if arrived:
            x_new = bridge.end.copy()
            nrm = bridge.end_normal.copy()
            self._bridges[i] = None
            self._near[i] = bridge.target
        else:
            nrm = bridge.normal_at(x_new)
        v = move * (1.0 / self._dt)
        self._agents[i].velocity = v - float(v @ nrm) * nrm
        self.path_lengths[i] += ml
        self._nrm_t[i] = tuple(nrm.tolist())
        self._x[i] = x_new
        t1, t2 = tangent_basis(nrm)
        return ExplorationCommand(x_new.copy(), v, nrm, t1, t2, self.step_count, i)

    def hopping(self, agent: int = 0) -> bool:
        """True while the agent is hopping a scan hole (on the chord between its two sides)."""
        return self._bridges[agent] is not None if agent < len(self._bridges) else False
