"""Ring passes: the walking plan of a sweep and its online follower.

:class:`RingPasses` lays the passes of a target part the first time the agent stands on it (the
planner, :mod:`.pass_planner`: rings of surface distance from the target's edge or the start, their
arcs in the order of a short tour, clean-up waypoints where the rings' wavefronts meet) and then tells
the agent where to steer, step by step.

Along an arc the agent steers at a carrot, the farthest of its next waypoints within ``AHEAD`` voxels;
the waypoints behind its place on the arc are done. A target point the passes walked past untouched (the
agent's tracking error left it at the footprint's edge) and no pending waypoint will cover (``missed``) is
touched at once when it lies within a couple of footprint radii: the explorer steps aside to it; a speck (a
small part the hops join, ``specks``) within that reach is touched in passing too. The start of the next
arc, when farther than a pass spacing, is reached down the surface distance to it. (Order "greedy": the
pending waypoint of least cost_j = |x_j − x| + ``ring_cost`` · w · (k_j − k_low).) A waypoint is also done
once the agent came within ``reach_m`` of it; a clean-up waypoint only within ``CLEAN_REACH`` footprint
radii, and it is skipped when its points are touched already. When no waypoint of the agent's part is left
the explorer hunts the untouched points one after the other, each the nearest along the surface
(``closest``: on the walking part and the parts the hops join it to, or a speck within r_a across a gap)
and reached down the surface distance to it (``route``; across a hop in contact, ``hop_due``), and then
the sweep source's potential and the relocation rules take over (other parts get their rings when the
agent touches down there; a relocation plans the tour again from where it lands).
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from tactex.ergodic.config import PASS_ORIGINS
from tactex.ergodic.pass_planner import (
    AT_RISK,
    CLEAN_UP,
    LEFTOVER,
    MAX_LINK,
    SPACING_SHARES,
    WINDOW,
    PassPlanner,
)

# The planner's constants a reader of the passes looks for are importable from here too (their home is the planner).
__all__ = ["AHEAD", "AT_RISK", "CARROT", "CLEAN_REACH", "CLEAN_UP", "HOP_REACH", "LEFTOVER", "MAX_LINK", "ORDERS",
           "SPACING_SHARES", "WINDOW", "RingPasses"]

#: On the way to a far goal the agent steers at the point within this many half-voxels nearest to it by surface
#: distance (a carrot a few voxels ahead on the shortest path).
CARROT = 6.0
#: Walking an arc, the agent steers at the farthest of its next waypoints still within AHEAD voxels of it (a
#: carrot on the line: it tracks the pass, not each point, and does not wiggle around them).
AHEAD = 3.0
#: A clean-up waypoint is done once the agent came this close [footprint radii] (its points lie at the
#: footprint's edge from the passes; the wider reach of a pass's waypoints would leave them untouched) [-].
CLEAN_REACH = 0.5
#: The hunt hops once the agent is within this many voxels of the hop's near end (see RingPasses.hop_due).
HOP_REACH = 2.0
#: "tour": the arcs in the order of a short tour over their end points (nearest neighbour, then 2-opt);
#: "greedy": the pending waypoint of least cost (distance plus ring).
ORDERS = ("tour", "greedy")


class RingPasses(PassPlanner):
    """Waypoints of the ring passes over the target points, laid lazily per connected part.

    Args:
        points: target points (T, 3) [m].
        links: symmetric sparse (T, T) matrix whose nonzeros link neighbouring target points (e.g. the
            Laplacian's off-diagonal restricted to the target), or None: points within ``link_radius_m``.
        pass_spacing_m: distance w between neighbouring passes [m].
        reach_m: a waypoint is done once the agent came this close [m].
        voxel_m: the cloud's spacing h [m]: the middle line of a ring is h thick.
        ring_cost: cost of one ring beyond the lowest pending one, in pass spacings [-].
        allowed: target points (T,) (bool) a waypoint may be on (e.g. clear of keep-out zones), or None: all.
        origin: where the rings start, one of ``PASS_ORIGINS``: "edge" (the part's longest run of edge points;
            from the start on a part without one; with order "tour", also from the start, and the shorter tour is
            kept) or "start".
        order: the walking order, one of ``ORDERS``: "tour" (the arcs as a tour, a carrot along each) or "greedy"
            (the pending waypoint of least cost).
        footprint_m: the footprint radius r_a [m] (default half the spacing).
        hops: symmetric sparse (T, T) matrix whose nonzeros join target points across a gap the agent may hop in
            contact (a scan hole the Laplacian spans, see :mod:`.bridges`), or None: none. The hunt after the
            passes reaches untouched points over walking links and hops (see closest and hop_due).
    """

    def __init__(self, points: np.ndarray, links, pass_spacing_m: float, reach_m: float, voxel_m: float,
                 ring_cost: float = 1.0, allowed: np.ndarray | None = None, origin: str = "edge",
                 order: str = "tour", footprint_m: float | None = None, hops=None) -> None:
        self._points = np.asarray(points, dtype=np.float64)
        n = len(self._points)
        self.pass_spacing_m = float(pass_spacing_m)
        self.footprint_m = 0.5 * self.pass_spacing_m if footprint_m is None else float(footprint_m)
        self.reach_m = float(reach_m)
        self._clean_reach = min(self.reach_m, CLEAN_REACH * self.footprint_m)
        self._half_line = 0.5 * float(voxel_m)
        self.ring_cost = float(ring_cost)
        self._allowed = np.ones(n, dtype=bool) if allowed is None else np.asarray(allowed, dtype=bool)
        if links is None:
            pairs = cKDTree(self._points).query_pairs(1.8 * float(voxel_m), output_type="ndarray")
            links = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        g = coo_matrix(links)
        r, c = g.row, g.col
        length = np.linalg.norm(self._points[r] - self._points[c], axis=1)
        # Links across a scan hole wider than the agent may stray off the cloud would lay passes it cannot walk.
        keep = (r != c) & (length <= MAX_LINK * float(voxel_m))
        r, c, length = r[keep], c[keep], length[keep]
        length = np.maximum(length, 1e-12)  # a zero weight is no link to csgraph
        self._graph = csr_matrix((length, (r, c)), shape=(n, n))
        self._graph = self._graph.maximum(self._graph.T)
        self.n_parts, self._part = connected_components(self._graph, directed=False)
        # The hunt's graph: the walking links and the hops between parts, each as long as its chord.
        self._reach = self._graph
        if hops is not None:
            h = coo_matrix(hops)
            keep = (h.row != h.col) & (self._part[h.row] != self._part[h.col])
            hr, hc = h.row[keep], h.col[keep]
            if hr.size:
                hl = np.maximum(np.linalg.norm(self._points[hr] - self._points[hc], axis=1), 1e-12)
                hop = csr_matrix((hl, (hr, hc)), shape=(n, n))
                self._reach = self._graph.maximum(hop.maximum(hop.T))
        _, self._reach_part = connected_components(self._reach, directed=False)
        self._tree = cKDTree(self._points)
        self._sizes = np.bincount(self._part)  # points per walking part (see specks)
        self._any_speck: bool | None = None  # see has_specks
        if origin not in PASS_ORIGINS:
            raise ValueError(f"origin must be one of {PASS_ORIGINS}, got {origin!r}")
        self.origin = origin
        if order not in ORDERS:
            raise ValueError(f"order must be one of {ORDERS}, got {order!r}")
        self.order = order
        self._edge = self._edge_points() if origin == "edge" else np.zeros(n, dtype=bool)
        self.reset()

    @property
    def parts(self) -> np.ndarray:
        """Connected part of each target point (T,) over the links the agent may walk (≤ ``MAX_LINK`` voxels)."""
        return self._part

    def reset(self) -> None:
        """No rings laid, nothing done."""
        self.ring = np.full(len(self._points), -1, dtype=np.intp)  # ring index of each waypoint, −1: none
        self.pending = np.zeros(len(self._points), dtype=bool)
        self._laid = np.zeros(self.n_parts, dtype=bool)
        self._goal = -1
        self._to_goal = None  # surface distance to a far goal [m] (T,), or None: steer straight at it
        self._tour: dict[int, np.ndarray] = {}  # per part: its waypoints in walking order
        self._arc: dict[int, np.ndarray] = {}  # per part: the arc of each entry of the tour (a new arc: a jump)
        self._at: dict[int, int] = {}  # per part: the first entry of the tour not walked yet
        self.spacing_m: dict[int, float] = {}  # per laid part: the spacing of its passes [m] (see SPACING_SHARES)
        self._clean: dict[int, np.ndarray] = {}  # per clean-up waypoint: the left points it is for (target indices)
        self._replan = False
        self._route_goal = -1  # the goal of route() and its surface distance map (T,) [m], or None: straight
        self._route = None
        self._via = -1  # the walking-part point route() steers at on its way to a goal across a gap
        self._hop = -1  # the far end of the hop route() takes at ``_via``, or −1: none (a walk or a speck's touch)

    def drop_goal(self, abandon: bool, replan: bool = False) -> None:
        """Forget the current goal; ``abandon``: the agent could not reach it, mark it done; ``replan``: the agent
        moved (it relocated), the tour of the part it is on is planned again from there."""
        if abandon and self._goal >= 0:
            self.pending[self._goal] = False
        self._goal = -1
        self._to_goal = None
        self._replan = self._replan or replan

    def _follow(self, x: np.ndarray, part: int) -> int:
        """The waypoint the agent at x (3,) [m] on the part steers at along the tour, or −1 when none is left.
        Entries of the tour behind the agent's place on its arc are done; far from the tour's next entry (the
        start of another arc) the entry itself is the goal."""
        tour, arc = self._tour[part], self._arc[part]
        i = self._at[part]
        p = self._points
        while True:
            while i < tour.size and not self.pending[tour[i]]:
                i += 1
            if i >= tour.size:
                self._at[part] = i
                return -1
            if np.linalg.norm(p[tour[i]] - x) > self.pass_spacing_m:
                self._at[part] = i
                return int(tour[i])
            end = min(tour.size, i + WINDOW)
            same = (arc[i:end] == arc[i]) & self.pending[tour[i:end]]  # a given-up waypoint is no carrot
            win = tour[i:end][same]
            d = np.linalg.norm(p[win] - x, axis=1)
            m = int(d.argmin())
            self.pending[win[:m]] = False  # the agent's place on the arc: what lies behind it is walked
            i += m
            d = d[m:]
            beyond = np.flatnonzero(d > AHEAD * 2.0 * self._half_line)
            c = (int(beyond[0]) - 1 if beyond.size else d.size - 1)
            if c <= 0 and d[0] <= self._reach_of(int(tour[i])):
                self.pending[tour[i]] = False
                i += 1
                continue
            self._at[part] = i
            return int(win[m + max(c, 0)])

    def mark(self, x: np.ndarray) -> None:
        """Waypoints within ``reach_m`` of the agent point x (3,) [m] are done."""
        idx = self._tree.query_ball_point(x, self.reach_m)
        if idx:
            if self._clean:
                # the ball holds the passes' reach already: only a clean-up waypoint's own reach is checked
                idx = [j for j in idx if j not in self._clean
                       or np.linalg.norm(self._points[j] - x) <= self._reach_of(j)]
            self.pending[idx] = False

    def _reach_of(self, j: int) -> float:
        """How close [m] the agent must come to waypoint j for it to be done: a clean-up waypoint's points lie at
        the footprint's edge from the passes, so it is done only within ``CLEAN_REACH`` footprint radii."""
        return self._clean_reach if j in self._clean else self.reach_m

    def point(self, j: int) -> np.ndarray:
        """Target point j [m] (3,)."""
        return self._points[j]

    def nearest(self, x: np.ndarray) -> int:
        """The target point nearest to x (3,) [m]."""
        return int(self._tree.query(x)[1])

    def waypoint(self, x: np.ndarray, near: int, untouched=None) -> np.ndarray | None:
        """The waypoint [m] (3,) the agent at x (3,) [m], nearest target point ``near``, steers at; None
        when its part has no pending waypoint (lays the part's rings first if they are not). ``untouched``: a
        callable giving the untouched target points (T,) (bool), or None; a clean-up waypoint none of whose points
        is untouched any more is skipped."""
        self.lay(near)
        if self.order == "tour":
            return self._tour_waypoint(x, near, untouched)
        g = self._goal
        if not (g >= 0 and self.pending[g] and self._part[g] == self._part[near]):
            cand = np.flatnonzero(self.pending & (self._part == self._part[near]))
            if cand.size == 0:
                self._goal = -1
                return None
            ring = self.ring[cand]
            dist = np.linalg.norm(self._points[cand] - x, axis=1)
            cost = dist + self.ring_cost * self.pass_spacing_m * (ring - ring.min())
            k = int(cost.argmin())
            g = self._goal = int(cand[k])
            self._to_goal = None
            if dist[k] > self.pass_spacing_m:
                # Far (the start of another arc): a straight line across a curved surface may lead into a fold
                # or off an edge; walk down the surface distance to the goal instead.
                self._to_goal = dijkstra(self._graph, directed=False, indices=g, limit=4.0 * float(dist[k]))
        return self._descend(x, g)

    @property
    def heading_far(self) -> bool:
        """Whether the agent is on its way to a far waypoint (the start of another arc), not along a pass."""
        return self._to_goal is not None

    def missed(self, x: np.ndarray, near: int, candidates: np.ndarray, radius_m: float) -> np.ndarray:
        """Target points of ``candidates`` (T,) (bool) within ``radius_m`` [m] of the agent at x (3,) [m] on target
        point ``near``'s part that no pending waypoint lies within a footprint radius of: the passes walked past
        them and none to come covers them (indices, nearest first)."""
        idx = np.asarray(self._tree.query_ball_point(x, radius_m), dtype=np.intp)
        idx = idx[candidates[idx] & (self._part[idx] == self._part[near])]
        if idx.size == 0:
            return idx
        idx = idx[np.argsort(np.linalg.norm(self._points[idx] - x, axis=1), kind="stable")]
        # the pending waypoints that may lie within a footprint radius of a candidate (a few along the passes), and
        # each candidate's squared distances to them
        around = np.asarray(self._tree.query_ball_point(x, radius_m + self.footprint_m), dtype=np.intp)
        pend = self._points[around[self.pending[around]]]
        if pend.shape[0] == 0:
            return idx
        d = self._points[idx][:, None, :] - pend[None, :, :]
        d *= d
        covered = ((d[:, :, 0] + d[:, :, 1] + d[:, :, 2]) <= self.footprint_m * self.footprint_m).any(axis=1)
        return idx[~covered]

    @property
    def has_specks(self) -> bool:
        """Whether the hops join some walking part to another: only then may a speck lie beside a pass; without
        one, :meth:`specks` has nothing to find and the explorer skips it."""
        if self._any_speck is None:
            # a point whose hop-joined part holds more points than its walking part: a hop joins its part to another
            joined = np.bincount(self._reach_part)[self._reach_part] > self._sizes[self._part]
            self._any_speck = bool(joined.any())
        return self._any_speck

    def specks(self, x: np.ndarray, near: int, candidates: np.ndarray, radius_m: float,
               max_points: float) -> np.ndarray:
        """Target points (T,) (bool) of ``candidates`` within ``radius_m`` [m] of the agent at x (3,) [m] on parts
        other than target point ``near``'s, of at most ``max_points`` points each, that the walking links and the
        hops join to it (specks the hunt would otherwise come back for)."""
        out = np.zeros(len(self._points), dtype=bool)
        idx = np.asarray(self._tree.query_ball_point(x, radius_m), dtype=np.intp)
        if idx.size == 0:
            return out
        part = self._part
        idx = idx[candidates[idx] & (part[idx] != part[near]) & (self._sizes[part[idx]] <= max_points)
                  & (self._reach_part[idx] == self._reach_part[near])]
        out[idx] = True
        return out

    def next_pending(self, near: int) -> int:
        """The next pending waypoint on the tour of target point ``near``'s part (target index), or −1."""
        part = int(self._part[near])
        tour = self._tour.get(part)
        if tour is None:
            return -1
        i = self._at[part]
        while i < tour.size and not self.pending[tour[i]]:
            i += 1
        self._at[part] = i
        return int(tour[i]) if i < tour.size else -1

    def _tour_waypoint(self, x: np.ndarray, near: int, untouched=None) -> np.ndarray | None:
        part = int(self._part[near])
        if self._replan:
            self._replan = False
            self._goal, self._to_goal = -1, None
            self._plan(part, x)
        g = self._follow(x, part)
        while g in self._clean and untouched is not None and not untouched()[self._clean[g]].any():
            self.pending[g] = False  # what it was for is touched already (a step aside, a pass's footprint)
            g = self._follow(x, part)
        if g < 0:
            self._goal, self._to_goal = -1, None
            return None
        if g != self._goal:
            self._goal, self._to_goal = g, None
            dist = float(np.linalg.norm(self._points[g] - x))
            if dist > self.pass_spacing_m:
                self._to_goal = dijkstra(self._graph, directed=False, indices=g, limit=4.0 * dist)
        return self._descend(x, g)

    def closest(self, near: int, candidates: np.ndarray, touch_m: float = 0.0) -> int:
        """Among the target points ``candidates`` (T,) (bool), the one nearest to target point ``near`` by surface
        distance over the walking links and the hops (the straight nearest may lie across a fold or a crease), or −1
        when none is in reach. A candidate off the reachable parts but within ``touch_m`` [m] of them (a speck
        across a gap, a footprint reaches it from the near side) counts at the surface distance to its nearest
        point there plus the gap, and route() steers at that point first. On a way with hops, route() steers at the
        first hop's near end and hop_due() then names its far end."""
        d, pred = dijkstra(self._reach, directed=False, indices=near, return_predecessors=True)
        cost = np.where(candidates, d, np.inf)
        via = {}
        off = np.flatnonzero(candidates & ~np.isfinite(d))
        if touch_m > 0.0 and off.size:
            walk = np.flatnonzero(np.isfinite(d))
            gap, q = cKDTree(self._points[walk]).query(self._points[off], distance_upper_bound=touch_m)
            ok = np.isfinite(gap)
            cost[off[ok]] = d[walk[q[ok]]] + gap[ok]
            via = dict(zip(off[ok].tolist(), walk[q[ok]].tolist(), strict=True))
        k = int(cost.argmin())
        if not np.isfinite(cost[k]):
            return -1
        self._route_goal, self._via, self._hop = -1, via.get(k, k), -1
        if self._reach is not self._graph:
            b = self._via  # the first hop on the way back from there: the last one found walking back
            while b != near and b >= 0:
                a = int(pred[b])
                if self._part[a] != self._part[b]:
                    self._via, self._hop = a, b
                b = a
        return k

    def hop_due(self, x: np.ndarray) -> int:
        """The far end (target index) of the hop the agent at x (3,) [m] takes now on its way to the last closest()
        goal: it is at the hop's near end (within ``HOP_REACH`` voxels: the near end lies on a scan's rim, where the
        step may not bring the agent any closer); else −1."""
        if self._hop < 0 or np.linalg.norm(self._points[self._via] - x) > HOP_REACH * 2.0 * self._half_line:
            return -1
        hop, self._hop, self._via, self._route_goal = self._hop, -1, -1, -1
        return hop

    def reach_mask(self, near: int, candidates: np.ndarray) -> np.ndarray:
        """The target points of ``candidates`` (T,) (bool) on target point ``near``'s side of the walking links and
        the hops (T,) (bool); none when ``near`` is off the target (−1)."""
        if near < 0:
            return np.zeros_like(candidates)
        return candidates & (self._reach_part == self._reach_part[near])

    def touchable(self, near: int, candidates: np.ndarray, touch_m: float) -> bool:
        """Whether a target point of ``candidates`` (T,) (bool) is reachable from target point ``near`` over the
        walking links and the hops, or within ``touch_m`` [m] of such a point (see closest)."""
        part = self._reach_part == self._reach_part[near]
        if (candidates & part).any():
            return True
        idx = np.flatnonzero(candidates)
        if idx.size == 0:
            return False
        return any(part[b].any() for b in self._tree.query_ball_point(self._points[idx], touch_m) if b)

    def route(self, x: np.ndarray, g: int) -> np.ndarray:
        """Where the agent at x (3,) [m] steers on its way to target point g (the last closest()): g itself when
        near, else a carrot down the surface distance to g, or to the point closest() reaches g from, or to the near
        end of the first hop on the way."""
        if g != self._route_goal:
            self._route_goal = g
            via = self._via if self._via >= 0 else g
            dist = float(np.linalg.norm(self._points[via] - x))
            self._route = (dijkstra(self._graph, directed=False, indices=via, limit=8.0 * dist)
                           if dist > 2.0 * self._half_line else None)
        via = self._via if self._via >= 0 else g
        if self._route is None:
            return self._points[via if self._hop >= 0 else g]
        return self._carrot(x, via, "_route", 2.0 * self._half_line)  # the hunt's goals are points: a voxel

    def _descend(self, x: np.ndarray, g: int) -> np.ndarray:
        """Goal g, or on the way to a far one the carrot a few voxels ahead down the surface distance to it."""
        return self._carrot(x, g, "_to_goal", self.reach_m)

    def _carrot(self, x: np.ndarray, g: int, field: str, reach_m: float) -> np.ndarray:
        """Goal g, or the point within CARROT half-voxels of x lowest in the surface distance to g held in
        attribute ``field`` (cleared once the agent is within ``reach_m`` [m] of g, or off the map)."""
        to_goal = getattr(self, field)
        if to_goal is None:
            return self._points[g]
        around = np.asarray(self._tree.query_ball_point(x, CARROT * self._half_line), dtype=np.intp)
        if around.size == 0:
            return self._points[g]
        to = to_goal[around]
        k = int(to.argmin())
        if not np.isfinite(to[k]) or to[k] <= reach_m:
            setattr(self, field, None)
            return self._points[g]
        return self._points[around[k]]
