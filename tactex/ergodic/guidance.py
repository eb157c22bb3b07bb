"""Guidance along the planned passes: where the explorer's single agent steers on a sweep.

With one agent and ``HedacConfig.sweep_pass_spacing`` > 0, the agent steers at the waypoints of the
passes (:class:`~tactex.ergodic.passes.RingPasses`) instead of up the potential's slope: along its
pass, stepping aside to a target point the pass walked past (a repair), touching the specks it passes
(small parts across a hop), and, once its part has no pass left, hunting the untouched points nearest
along the surface, hopping (:mod:`.hops`) where the way crosses a scan hole. A goal the agent cannot
reach (it stalled on the way, or the way led off a scan edge) is given up. :class:`PassGuidance` is
that part of :class:`~tactex.ergodic.explorer.HedacExplorer`.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix

from tactex.ergodic.command import ExplorationCommand

__all__ = ["EDGE_BLOCKED", "PASS_REACH", "REPAIR_RADIUS", "REPAIR_STEPS", "SPECK_POINTS", "PassGuidance"]

#: On a pass, untouched target points within this many footprint radii of the agent that the passes walked past
#: and none to come covers are touched at once (see PassGuidance._missed) [-]: the points the passes leave lie about
#: a footprint radius beside the agent's path, short of the neighbouring pass (passes lie under 2 r_a apart).
REPAIR_RADIUS = 2.0
#: A part of at most this many footprint discs of points is a speck, touched in passing (see _speck) [-].
SPECK_POINTS = 1.0
#: Steps an agent steers at one such point before it leaves it to the hunt [-].
REPAIR_STEPS = 6
#: A planned pass's waypoint is given up when the scan edge leaves less than this share of the way to it [-].
EDGE_BLOCKED = 0.2
#: A planned pass's waypoint is done once the agent came this close [voxels] (see :mod:`.passes`): the agent goes on
#: along its pass instead of working its way onto each waypoint (at the scan's rim, where it dithers at the off-cloud
#: limit, it cannot); what the footprint then leaves beside the pass it steps aside to.
PASS_REACH = 2.5


class _Open:
    """The target points no footprint touched yet that one may and that are not given up (nor in ``skip``, (T,)
    bool), looked up by target index (an int or an index array): the guidance asks only around the agent, and a
    whole (T,) mask each step costs more than the rest of the step on a 100k-point target."""

    def __init__(self, explorer, skip: np.ndarray | None = None) -> None:
        self._ex = explorer
        self._skip = skip

    def __getitem__(self, idx):
        ex = self._ex
        out = (ex._cov[ex._tidx[idx]] < ex._p_t[idx]) & ex._t_safe[idx] & ~ex._given_up[idx]
        if self._skip is not None:
            out = out & ~self._skip[idx]
        return out


class PassGuidance:
    """The explorer's guidance along the planned passes (mixed into :class:`~tactex.ergodic.explorer.HedacExplorer`;
    ``_passes`` is its :class:`~tactex.ergodic.passes.RingPasses` or None)."""

    def _guide(self, i: int, x: np.ndarray, sf: tuple, nrm: np.ndarray) -> tuple[np.ndarray | None,
                                                                                ExplorationCommand | None]:
        """Agent i at x [m] (projected at x + sf, normal ``nrm``) on the planned passes: the direction (3,) towards
        its next waypoint on the tangent plane, or None (the potential leads); or, when the hunt's way hops a scan
        hole here, the hop's first move as the second value."""
        guide = self._pass_direction(x, sf, nrm)
        if self._hop_to >= 0:
            here = np.array((x.item(0) + sf[0], x.item(1) + sf[1], x.item(2) + sf[2]))
            bridge = self._hop_bridge(self._hop_to, here, nrm)
            self._hop_to = -1
            if bridge is not None:
                self._bridges[i] = bridge
                return None, self._bridge_move(i, x, bridge)
            self._given_up[self._hop_goal] = True  # the hop's far side faces away: not a goal again
            guide = None
        return guide, None

    def _check_blocked(self, g: np.ndarray, guide: np.ndarray) -> None:
        """The scan edge left the gradient g (3,) of the way ``guide`` (3,): when less than ``EDGE_BLOCKED`` of it,
        the way leads off the edge (across a hole the agent cannot cross), and the goal is given up."""
        if float(g.dot(g)) < EDGE_BLOCKED**2 * float(guide.dot(guide)):
            if not self._on_speck:
                self._passes.drop_goal(abandon=True)
            if self._leftover_goal >= 0:
                self._given_up[self._leftover_goal] = True
                self._leftover_goal = -1

    def _target_hops(self) -> coo_matrix | None:
        """The gap links (hops, :mod:`.bridges`) between target points clear of the keep-out zones, as a (T, T) matrix
        of target positions, or None without any."""
        g = self._gaps
        if not g.n_links:
            return None
        src = np.repeat(np.arange(len(self._points)), np.diff(g.ptr))
        a, b = self._tpos[src], self._tpos[g.far]
        ok = (a >= 0) & (b >= 0)
        a, b = a[ok], b[ok]
        ok = self._t_safe[a] & self._t_safe[b]
        a, b = a[ok], b[ok]
        if a.size == 0:
            return None
        t = self._tidx.size
        return coo_matrix((np.ones(a.size), (a, b)), shape=(t, t))

    def _walkable_left(self, untouched: np.ndarray) -> bool:
        """Whether untouched target (T,) (bool) is left that the agent may walk to: on its part of the passes'
        graph (links ≤ 2 voxels, see :mod:`.passes`) and not given up (it stalled on the way, or the way led off
        a scan edge). A speck across a wider gap, e.g. a few scan points hanging below a rim, is reached by
        relocating."""
        j = self._tpos.item(self._near[0])
        if j < 0:
            return True  # off the target: the potential leads there
        return self._passes.touchable(j, untouched & ~self._given_up, self._r_a)

    def _next_on_tour(self, i: int) -> int | None:
        """Where a guided agent that stalled touches down: its tour's next waypoint past the one it stalled on
        (cloud index), if that is untouched (it hops the obstacle and goes on with the plan); else None."""
        if not self.planned_passes:
            return None
        t = self._tpos.item(self._near[i])
        if t < 0:
            return None
        passes = self._passes
        passes.drop_goal(abandon=True)
        g = passes.next_pending(t)
        while g >= 0 and self._cov.item(self._tidx.item(g)) >= self._p_t.item(g):
            passes.pending[g] = False  # touched already: a footprint passed over it
            g = passes.next_pending(t)
        return None if g < 0 else int(self._tidx.item(g))

    def _pass_direction(self, x: np.ndarray, shift: tuple, nrm: np.ndarray) -> np.ndarray | None:
        """Towards the next waypoint of the planned passes, on the tangent plane (3,), or None: no pass left
        on the agent's part (the potential leads)."""
        here = np.array((x.item(0) + shift[0], x.item(1) + shift[1], x.item(2) + shift[2]))
        passes = self._passes
        j = self._tpos.item(self._near[0])
        near = j if j >= 0 else passes.nearest(here)
        wp = passes.waypoint(here, near, self._untouched)
        if wp is not None and passes.heading_far:
            self._drop_speck()  # a speck is touched in passing, not on the way to a far arc
        elif wp is None:
            self._drop_speck()
            wp = self._leftover(here)
            if wp is None:
                return None
        else:
            open_ = _Open(self)  # both look at it, each only around the agent
            speck = self._speck(here, near, open_)
            if speck is not None:
                wp = speck
            else:
                miss = self._missed(here, near, open_)
                if miss is not None:
                    wp = miss
        to = wp - here
        to -= float(to.dot(nrm)) * nrm
        return to if float(to.dot(to)) > 0.0 else None

    def _missed(self, here: np.ndarray, near: int, open_: _Open | None = None) -> np.ndarray | None:
        """On a pass: the nearest untouched target point [m] (3,) within ``REPAIR_RADIUS`` footprint radii of the agent
        at ``here`` that the passes walked past and none to come covers (the agent's tracking error left it
        at the footprint's edge), or None. The agent steps aside to touch it now, a detour of a fraction of a
        footprint radius; the hunt after the passes would come back for it from afar. A point it steered at for
        ``REPAIR_STEPS`` steps without touching it (across a fold, off an edge) is given up here and left to the
        hunt. ``open_``: unused (the open points are looked up around the agent)."""
        cand = _Open(self, self._repair_failed)
        passes = self._passes
        for g in passes.missed(here, near, cand, REPAIR_RADIUS * self._r_a).tolist():
            p = passes.point(g)
            if float(np.linalg.norm(p - here)) < 0.5 * self._r_a:
                continue  # under the footprint: touched as the agent goes on
            n = self._repair_steps.get(g, 0) + 1
            self._repair_steps[g] = n
            if n > REPAIR_STEPS:
                self._repair_failed[g] = True
                continue
            return p
        return None

    def _drop_speck(self) -> None:
        """The agent no longer steers at a speck: its goal is not the hunt's."""
        if self._on_speck:
            self._on_speck = False
            self._leftover_goal = -1

    def _speck(self, here: np.ndarray, near: int, open_: _Open) -> np.ndarray | None:
        """On a pass: where the agent steers [m] (3,) on its way to an untouched speck (a part of at most
        ``SPECK_POINTS`` footprint discs that the hops join to the agent's) within ``REPAIR_RADIUS`` footprint radii
        of the agent at ``here``, or None. The agent touches it as it passes: the hunt after the passes would walk
        back for each speck from afar. ``open_``: the untouched target not given up, looked up by index."""
        passes = self._passes
        if not passes.has_specks:
            return None
        g = self._leftover_goal
        if self._on_speck and g >= 0 and open_[g]:
            return self._leftover(here)
        limit = SPECK_POINTS * np.pi * (self._r_a / self.spacing) ** 2
        specks = passes.specks(here, near, open_, REPAIR_RADIUS * self._r_a, limit)
        self._on_speck = bool(specks.any())
        self._leftover_goal = -1
        if not self._on_speck:
            return None
        return self._leftover(here, specks)

    def _leftover(self, here: np.ndarray, candidates: np.ndarray | None = None) -> np.ndarray | None:
        """After the passes (or, with ``candidates``, on a pass to a speck): where the agent steers [m] (3,) on its
        way to the untouched target point nearest by
        surface distance over its walking part and the hops from it (or a speck within a footprint radius of them),
        kept as the goal until a footprint touches it; None when none is left. At the near end of a hop on the way
        it sets ``_hop_to`` (the far end's cloud index): the step hops there along the chord."""
        g = self._leftover_goal
        passes = self._passes
        if not (g >= 0 and self._cov.item(self._tidx.item(g)) < self._p_t.item(g)):
            j = self._tpos.item(self._near[0])
            near = j if j >= 0 else passes.nearest(here)
            if candidates is None:
                candidates = self._untouched() & ~self._given_up
            g = passes.closest(near, candidates, self._r_a)
            self._leftover_goal = g
            if g < 0:
                return None
        aim = passes.route(here, g)
        hop = passes.hop_due(here)
        if hop >= 0:
            self._hop_to = int(self._tidx.item(hop))
            self._hop_goal = g
            self._leftover_goal = -1  # planned again from the far side
        return aim
