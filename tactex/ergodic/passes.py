"""Ring passes: the walking plan of a sweep, passes along rings of surface distance from the target's edge.

Whatever a coverage path does, it covers at most a band of width 2 r_a per metre, so a target of
area A needs at least A / (2 r_a) of path. HEDAC's strokes, even with the sweep source, lay passes
as the potential happens to curve and leave slivers and single points between them, each costing a
later pass. A planned sweep lays its passes side by side instead: along the level sets of the
geodesic distance d (its rings), ``pass_spacing`` apart, from the target's outer edge (origin
"edge": contour-parallel passes, as a pocket is milled; the first pass's footprint reaches the
edge, and a disc is covered in closed loops) or from the agent's start, whichever tour (below) plus the
hunt for what its plan leaves is shorter; origin "start" always from the start. Each origin is planned at
w and at 0.9 w (``SPACING_SHARES``), and the tighter plan is kept where the islands of points the full
one leaves at the footprint's edge (``AT_RISK``) cost the hunt more detours than its longer tour.
The ring k holds the target points with k·w ≤ d < (k+1)·w, w = ``pass_spacing``; its pass runs along
d = (k+½)·w, so a footprint of radius r_a ≥ w/2 centred on it covers the ring, and w a little under
2 r_a leaves an overlap for the agent's tracking error.

Where the rings' wavefronts meet (the medial axis, the last ring round a maximum of d) no middle line runs, and
the plan leaves a sliver farther than r_a from every waypoint (the uncut region of contour-parallel pocketing):
those points get clean-up waypoints, the centres of a greedy disc cover (``LEFTOVER``, ``CLEAN_UP``), inserted
into the tour where each lengthens it least, or toured as arcs of their own when that is shorter; one is done
within ``CLEAN_REACH`` footprint radii, or skipped when its points are touched already.

The plan is a set of waypoints, the target points on the middle line of their ring (|d − (k+½)·w| ≤ ½ voxel). On
a closed or holed surface a ring's middle line breaks into several arcs (its connected runs); each arc is
ordered along itself, and the arcs are walked as an open tour from the agent: nearest neighbour over their ends
(a closed arc is entered anywhere), then 2-opt, by the chords and by the surface distances between the ends; the
surface's tour is kept when its moves are clearly shorter along the surface (the agent walks them on the surface:
round a fold or an ear's base the chord is a fraction of the walk). Along an arc the agent steers at a carrot, the
farthest of its next waypoints within ``AHEAD`` voxels; the waypoints behind its place on the arc are done. A target
point the passes walked past untouched (the agent's tracking error left it at the footprint's edge) and no pending
waypoint will cover (``missed``) is touched at once when it lies within a couple of footprint radii: the
explorer steps aside to it; a speck (a small part the hops join, ``specks``) within that reach is touched in
passing too. The start of the next arc, when farther than a pass spacing, is reached down the
surface distance to it. (Order "greedy", the earlier rule: the pending waypoint of least cost_j = |x_j − x| +
``ring_cost`` · w · (k_j − k_low).) A waypoint is also done once the agent came within ``reach_m`` of it. When
no waypoint of the agent's part is left the explorer hunts the untouched points one after the other, each the
nearest along the surface (``closest``: on the walking part and the parts the hops join it to, or a speck within
r_a across a gap) and reached down the surface distance to it (``route``; across a hop in contact, ``hop_due``),
and then the sweep source's potential and the relocation rules take
over (other parts get their rings when the agent touches down there; a relocation plans the tour again from
where it lands).

d is Dijkstra's distance (scipy.sparse.csgraph) over the links of the cloud's Laplacian between
target points, each as long as its chord: the same neighbourhoods the heat diffuses over, and the
same parts, except links longer than ``MAX_LINK`` voxels (a hole the agent cannot walk across). A
graph distance zigzags along the links, so it is smoothed before its level sets are taken.
"""

from __future__ import annotations

from itertools import pairwise

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from tactex.ergodic.config import PASS_ORIGINS

__all__ = ["RingPasses"]

#: Rounds of averaging of the distance over the links before its level sets are taken (see RingPasses._smooth).
SMOOTHING = 10
#: Longest link of the distance graph [voxels]: the agent walks up to a voxel off the cloud (max_off_cloud), so it
#: crosses a gap of two voxels between cloud points, not more.
MAX_LINK = 2.0
#: Edge points: centroid offset of EDGE_NEIGHBOURS nearest neighbours over their radius above EDGE_OFFSET; a part
#: whose longest connected run of them is shorter than MIN_EDGE_POINTS has no edge (a closed surface).
EDGE_NEIGHBOURS = 12
EDGE_OFFSET = 0.25
MIN_EDGE_POINTS = 10
#: Edge points this close [voxels] are one run of the edge, tried in turn (a rim where the surface turns steep is
#: sampled sparsely and its edge points lie a few voxels apart; a scan's dropouts lie a few voxels inside its rim).
EDGE_LINKS = (2.0, 4.0)
#: On the way to a far goal the agent steers at the point within this many half-voxels nearest to it by surface
#: distance (a carrot a few voxels ahead on the shortest path).
CARROT = 6.0
#: Walking an arc, the agent steers at the farthest of its next waypoints still within AHEAD voxels of it (a
#: carrot on the line: it tracks the pass, not each point, and does not wiggle around them).
AHEAD = 3.0
#: Waypoints of an arc looked at for the agent's place on it and for the carrot [-].
WINDOW = 16
#: A tour of rings from the start counts this many times its length against one from the edge: the edge's own
#: points are then left for the end, each a trip, where the first ring from the edge covers them [-].
START_PENALTY = 1.1
#: A plan's target points farther than the footprint radius from all its waypoints are left to the hunt after the
#: passes, which walks about this many times the ideal path over them (A / (2 r_a)); the plans are compared by
#: tour length plus that estimate [-] (a part narrower than the first ring otherwise wins with no waypoint at all).
HUNT_FACTOR = 4.0
#: Pass spacings planned per origin, as shares of ``pass_spacing_m`` [-]: the tighter one leaves fewer points at the
#: footprint's edge (on a bowl's steep rim, round its middle, at ring changes), each a detour of the hunt later, at
#: the price of a longer tour (see RingPasses.lay).
SPACING_SHARES = (1.0, 0.9)
#: A target point farther than this share of the footprint radius from every waypoint of a plan is at risk: the
#: agent's tracking error may leave it untouched [-].
AT_RISK = 0.9
#: What an island of points at risk (points within a footprint radius joined) costs the hunt, in footprint radii
#: of path [-]. Measured: the hunts after the passes walk ~1.5-3 cm per island at r_a = 7.5 mm.
ISLAND_COST = 2.0
#: Waypoints of an arc between two along which its length is measured [-] (see RingPasses._tour_length).
SUBSAMPLE = 3
#: Passes of 2-opt over the tour of the arcs at most (each is O(n²) in the arcs; it converges in a few).
TWO_OPT_PASSES = 20
#: The tour over the arcs planned by surface distance replaces the one planned by chord when its moves between arcs
#: are shorter along the surface than this share of the chord tour's [-]: on a flat or gently curved part the two
#: differ by the graph distance's zigzag, and the chord's tour is kept (see RingPasses._tour_of).
SURFACE_GAIN = 0.9
#: Target points farther than LEFTOVER footprint radii from every waypoint of the chosen plan (where the rings'
#: wavefronts meet) get clean-up waypoints: centres of a greedy cover by discs of CLEAN_UP footprint radii [-].
LEFTOVER = 1.0
#: Radius of the clean-up discs, in footprint radii [-] (see LEFTOVER).
CLEAN_UP = 0.6
#: A clean-up waypoint is done once the agent came this close [footprint radii] (its points lie at the
#: footprint's edge from the passes; the wider reach of a pass's waypoints would leave them untouched) [-].
CLEAN_REACH = 0.5
#: The hunt hops once the agent is within this many voxels of the hop's near end (see RingPasses.hop_due).
HOP_REACH = 2.0
#: "tour": the arcs in the order of a short tour over their end points (nearest neighbour, then 2-opt);
#: "greedy": the pending waypoint of least cost (distance plus ring), the earlier rule.
ORDERS = ("tour", "greedy")


class RingPasses:
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

    def lay(self, start: int) -> None:
        """Lay the rings of target point ``start``'s part (once per part). With origin "edge" and the tour, the
        rings from the outer edge found with each of ``EDGE_LINKS`` and from the start are all planned, and the
        shortest tour is kept (a scan's rim may be sampled sparsely, a closed surface has only the edges of its
        holes; no single rule suits every part)."""
        part = int(self._part[start])
        if self._laid[part]:
            return
        self._laid[part] = True
        members = np.flatnonzero(self._part == part)
        sub = self._graph[members][:, members]
        s = int(np.searchsorted(members, start))
        seeds: list[np.ndarray] = []
        if self.origin == "edge":
            for link in EDGE_LINKS if self.order == "tour" else EDGE_LINKS[:1]:
                edge = self._outer_edge(members, link)
                if edge.size >= MIN_EDGE_POINTS and not any(np.array_equal(edge, e) for e in seeds):
                    seeds.append(edge)
        if not seeds or self.order == "tour":  # no edge (closed), rings from the start asked for, or a candidate
            seeds.append(np.array([s]))
        plans = []  # (seed, share, cost of the origin, cost of the spacing, plan)
        for n_seed, seed in enumerate(seeds):
            d = self._smooth(sub, dijkstra(sub, directed=False, indices=seed, min_only=True))
            for share in SPACING_SHARES if self.order == "tour" else SPACING_SHARES[:1]:
                w = share * self.pass_spacing_m
                k = np.floor(d / w)
                on_line = (np.abs(d - (k + 0.5) * w) <= self._half_line) & self._allowed[members]
                thin = False
                if not on_line.any() and seed.size > 1:
                    # A part narrower than the first ring (a strip under 2 r_a wide): one pass along its ridge,
                    # the points farthest from the edge, whose footprint reaches both sides; with no ridge (every
                    # point on the edge, a strip a few voxels wide) no pass: the hunt walks it nearest first,
                    # which along a strip is one pass.
                    ridge = d >= d.max() - 2.0 * self._half_line
                    thin = 2 * np.count_nonzero(ridge) > ridge.size
                    on_line = ridge & self._allowed[members] & ~thin
                    k = np.zeros_like(k)
                way = members[on_line]
                self.ring[way] = k[on_line].astype(np.intp)
                self.pending[way] = True
                if self.order != "tour":
                    self.spacing_m[part] = w
                    return
                self._plan(part, self._points[start])
                length = self._tour_length(part)
                if seed.size == 1 and len(seeds) > 1:
                    length *= START_PENALTY
                length += self._hunt_length(members, way) / (HUNT_FACTOR if thin else 1.0)
                plans.append((n_seed, share, length, length + self._island_cost(members, way),
                              (way, self.ring[way].copy(), self._tour[part], self._arc[part], w)))
                self.ring[way] = -1
                self.pending[way] = False
        # The origin by its plan at the full spacing (tour and the hunt for what it leaves), then its spacing also by
        # the islands it leaves at risk: compared over origins, the islands chose worse origins on the TEC bunny.
        origin = min((p for p in plans if p[1] == SPACING_SHARES[0]), key=lambda p: p[2])[0]
        way, ring, self._tour[part], self._arc[part], self.spacing_m[part] = min(
            (p for p in plans if p[0] == origin), key=lambda p: p[3])[4]
        self.ring[way] = ring
        self.pending[way] = True
        extra = self._clean_up(members, way)
        if extra.size:
            # a ring of its own per clean-up waypoint: an arc of one, which the agent's place on an arc never passes
            # (only CLEAN_REACH marks it done)
            self.ring[extra] = ring.max() + 1 + np.arange(extra.size)
            self.pending[extra] = True
            self._plan(part, self._points[start])
        self._at[part] = 0

    # ------------------------------------------------------------------ the tour over the arcs
    def _plan(self, part: int, x: np.ndarray) -> None:
        """The part's pending waypoints as arcs (connected runs of one ring's middle line, each in order along it),
        and the arcs in the order of a short open tour from x (3,) [m] (see _tour_of)."""
        idx = np.flatnonzero(self.pending & (self._part == part))
        clean = np.isin(idx, np.fromiter(self._clean, dtype=np.intp, count=len(self._clean)))
        self._plan_arcs(part, idx[~clean], x)
        if clean.any():
            self._insert(part, idx[clean])
            inserted = self._tour[part], self._arc[part], self._tour_length(part)
            self._plan_arcs(part, idx, x)
            if self._tour_length(part) >= inserted[2]:
                self._tour[part], self._arc[part] = inserted[:2]

    def _plan_arcs(self, part: int, idx: np.ndarray, x: np.ndarray) -> None:
        """The waypoints idx as arcs in the order of a short open tour from x (3,) [m] (see _tour_of)."""
        arcs = self._arcs(idx)
        self._at[part] = 0
        if not arcs:
            self._tour[part] = np.zeros(0, dtype=np.intp)
            self._arc[part] = np.zeros(0, dtype=np.intp)
            return
        walk = self._tour_of(arcs, np.asarray(x, dtype=np.float64))
        self._tour[part] = np.concatenate(walk)
        self._arc[part] = np.repeat(np.arange(len(walk)), [len(a) for a in walk])

    def _insert(self, part: int, extra: np.ndarray) -> None:
        """Clean-up waypoints ``extra`` (target indices) into the part's tour, each where it lengthens the tour
        least (cheapest insertion by chord): a detour off the pass next to it, an arc of its own that splits the
        arc it leaves from."""
        tour, arc = list(self._tour[part]), self._arc[part]
        new = list(np.r_[True, arc[1:] != arc[:-1]]) if arc.size else []
        p = self._points
        for c in extra.tolist():
            if not tour:
                tour, new = [c], [True]
                continue
            q = p[tour]
            to = np.linalg.norm(q - p[c], axis=1)
            cost = np.r_[to[:-1] + to[1:] - np.linalg.norm(np.diff(q, axis=0), axis=1), to[-1]]
            g = int(cost.argmin()) + 1  # insert before entry g (after entry g − 1)
            tour.insert(g, c)
            new.insert(g, True)
            if g + 1 < len(new):
                new[g + 1] = True
        self._tour[part] = np.asarray(tour, dtype=np.intp)
        self._arc[part] = np.cumsum(new).astype(np.intp) - 1

    def _tour_of(self, arcs: list[np.ndarray], x: np.ndarray) -> list[np.ndarray]:
        """The arcs, each in walking direction, in the order of a short open tour from x (3,) [m]: nearest
        neighbour over their ends (a closed arc is entered at its point nearest to where the tour is), then 2-opt,
        once by the chords between the ends and once by the surface distances. The agent walks the moves down the
        surface distance: round a fold or an ear's base the chord ranks them wrongly, so the surface's tour is kept
        when its moves are shorter along the surface than ``SURFACE_GAIN`` times the chord's; on a flat part the
        graph distance zigzags along the links and ranks straight moves wrongly, and the chord's tour is kept."""
        p = self._points
        closed = [self._closed(a) for a in arcs]
        start = self._on_arcs(arcs, x)
        ends = np.unique(np.concatenate([[start]] + [a[[0, -1]] for a in arcs]))
        rows = dict(zip(ends.tolist(), dijkstra(self._graph, directed=False, indices=ends), strict=True))

        def surface(v: int) -> np.ndarray:
            if v not in rows:
                rows[v] = dijkstra(self._graph, directed=False, indices=v)
            return rows[v]

        def chord(v: int) -> np.ndarray:
            return np.linalg.norm(p - p[v], axis=1)

        tours = []
        for way in (chord, surface):
            walk = self._two_opt(self._nearest_arcs(arcs, closed, start, way), start, way)
            moves = [(start, walk[0][0])] + [(a[-1], b[0]) for a, b in pairwise(walk)]
            tours.append((walk, sum(float(surface(int(u))[v]) for u, v in moves)))
        (by_chord, chord_m), (by_surface, surface_m) = tours
        return by_surface if surface_m < SURFACE_GAIN * chord_m else by_chord

    @staticmethod
    def _nearest_arcs(arcs: list[np.ndarray], closed: list[bool], start: int, way) -> list[np.ndarray]:
        """The arcs in nearest-neighbour order from target point ``start`` by the distances ``way(v)`` (T,) [m]
        from target point v, each entered at its nearer end (a closed one at its nearest point)."""
        left = list(range(len(arcs)))
        here = start
        walk: list[np.ndarray] = []
        while left:
            best, best_d, best_seq = -1, np.inf, None
            r = way(here)
            for i in left:
                a = arcs[i]
                if closed[i]:
                    d = r[a]
                    j = int(d.argmin())
                    cand, dist = np.roll(a, -j), float(d[j])
                else:
                    d0, d1 = float(r[a[0]]), float(r[a[-1]])
                    cand, dist = (a, d0) if d0 <= d1 else (a[::-1], d1)
                if dist < best_d or best < 0:
                    best, best_d, best_seq = i, dist, cand
            left.remove(best)
            walk.append(best_seq)
            here = int(best_seq[-1])
        return walk

    def _on_arcs(self, arcs: list[np.ndarray], x: np.ndarray) -> int:
        """The target point of the arcs' part nearest to x (3,) [m] (where the tour starts)."""
        members = np.flatnonzero(self._part == self._part[arcs[0][0]])
        return int(members[np.linalg.norm(self._points[members] - x, axis=1).argmin()])

    def _tour_length(self, part: int) -> float:
        """Length [m] of the part's tour: along each arc through every third waypoint (the middle line is a voxel
        thick, and a polyline through each of its points zigzags across it), and the jumps between arcs."""
        tour, arc = self._tour[part], self._arc[part]
        if tour.size < 2:
            return 0.0
        starts = np.flatnonzero(np.r_[True, arc[1:] != arc[:-1]])
        ends = np.r_[starts[1:], tour.size] - 1
        keep = np.zeros(tour.size, dtype=bool)
        keep[::SUBSAMPLE] = True
        keep[starts] = keep[ends] = True
        return float(np.linalg.norm(np.diff(self._points[tour[keep]], axis=0), axis=1).sum())

    def _clean_up(self, members: np.ndarray, way: np.ndarray) -> np.ndarray:
        """Clean-up waypoints (target indices) for the points of ``members`` that the passes along waypoints ``way``
        leave (farther than ``LEFTOVER`` footprint radii from every waypoint): where the rings' wavefronts meet (the
        medial axis, a last ring round a maximum of the distance) no middle line runs. A greedy disc cover of those
        points by discs of ``CLEAN_UP`` footprint radii centred on them; each centre is a waypoint of its own."""
        if way.size == 0 or CLEAN_UP <= 0.0:
            return np.zeros(0, dtype=np.intp)
        gap = cKDTree(self._points[way]).query(self._points[members])[0]
        left = members[(gap > LEFTOVER * self.footprint_m) & self._allowed[members]]
        if left.size == 0:
            return left
        q = self._points[left]
        balls = cKDTree(q).query_ball_point(q, CLEAN_UP * self.footprint_m)
        open_ = np.ones(left.size, dtype=bool)
        centres = []
        while open_.any():
            gain = np.array([np.count_nonzero(open_[b]) for b in balls])
            c = int(gain.argmax())
            centres.append(left[c])
            self._clean[int(left[c])] = left[np.asarray(balls[c], dtype=np.intp)[open_[balls[c]]]]
            open_[balls[c]] = False
        return np.asarray(centres, dtype=np.intp)

    def _hunt_length(self, members: np.ndarray, way: np.ndarray) -> float:
        """Estimated path [m] of the hunt for the points of ``members`` a plan with waypoints ``way`` leaves: those
        farther than the footprint radius from every waypoint, HUNT_FACTOR times their ideal path."""
        if way.size:
            gap = cKDTree(self._points[way]).query(self._points[members], distance_upper_bound=self.footprint_m)[0]
            left = int(np.count_nonzero(~np.isfinite(gap)))
        else:
            left = members.size
        voxel = 2.0 * self._half_line
        return HUNT_FACTOR * left * voxel * voxel / (2.0 * self.footprint_m)

    def _island_cost(self, members: np.ndarray, way: np.ndarray) -> float:
        """Estimated detours [m] of the hunt for the islands of points of ``members`` that a plan with waypoints
        ``way`` leaves at risk (farther than AT_RISK footprint radii from every waypoint): ISLAND_COST radii each."""
        if way.size == 0:
            return 0.0  # the hunt estimate already counts the whole part
        gap = cKDTree(self._points[way]).query(self._points[members])[0]
        risk = self._points[members[gap > AT_RISK * self.footprint_m]]
        if len(risk) == 0:
            return 0.0
        pairs = cKDTree(risk).query_pairs(self.footprint_m, output_type="ndarray")
        g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(risk), len(risk)))
        return ISLAND_COST * self.footprint_m * connected_components(g, directed=False)[0]

    def _two_opt(self, walk: list[np.ndarray], start: int, row) -> list[np.ndarray]:
        """2-opt on an open tour of arcs from target point ``start``, by the distances ``row(v)`` (T,) [m] from
        target point v: reversing a run of arcs reverses each of them too."""
        n = len(walk)
        if n < 3:
            return walk
        nodes = np.unique(np.concatenate([[start]] + [a[[0, -1]] for a in walk]))
        dist = np.array([row(int(v))[nodes] for v in nodes])  # between the ends (both ways: an arc may turn)
        at = {int(v): k for k, v in enumerate(nodes)}
        for _ in range(TWO_OPT_PASSES):
            entry = np.array([at[int(a[0])] for a in walk])
            out = np.array([at[int(a[-1])] for a in walk])
            before = np.r_[at[start], out[:-1]]  # where the tour is before arc i
            improved = False
            for i in range(n - 1):
                # reverse arcs i..j: the edge (before_i → entry_i) becomes (before_i → out_j), and
                # (out_j → entry_{j+1}) becomes (entry_i → entry_{j+1}); the last arc has no edge after it
                j = np.arange(i + 1, n)
                old = dist[before[i], entry[i]]
                new = dist[before[i], out[j]]
                nxt = np.r_[entry[j[:-1] + 1], 0]
                old_after = dist[out[j], nxt]
                new_after = dist[entry[i], nxt]
                old_after[-1] = new_after[-1] = 0.0
                gain = old + old_after - new - new_after
                k = int(gain.argmax())
                if gain[k] > 1e-9:
                    jj = int(j[k])
                    walk[i:jj + 1] = [a[::-1] for a in walk[i:jj + 1][::-1]]
                    improved = True
                    break
            if not improved:
                break
        return walk

    def _arcs(self, idx: np.ndarray) -> list[np.ndarray]:
        """Waypoints idx split into arcs: per ring, the connected runs of its middle line (links ≤ MAX_LINK
        voxels), each ordered along itself."""
        link = MAX_LINK * 2.0 * self._half_line
        arcs: list[np.ndarray] = []
        for k in np.unique(self.ring[idx]):
            ring = idx[self.ring[idx] == k]
            if ring.size <= 2:
                arcs.extend(ring[i:i + 1] for i in range(ring.size))
                continue
            q = self._points[ring]
            pairs = cKDTree(q).query_pairs(link, output_type="ndarray")
            length = np.maximum(np.linalg.norm(q[pairs[:, 0]] - q[pairs[:, 1]], axis=1), 1e-12)
            g = coo_matrix((length, (pairs[:, 0], pairs[:, 1])), shape=(ring.size, ring.size)).tocsr()
            g = g.maximum(g.T)
            n, label = connected_components(g, directed=False)
            for c in range(n):
                m = np.flatnonzero(label == c)
                arcs.append(ring[m[self._along(g[m][:, m], q[m])]])
        return arcs

    def _along(self, g: csr_matrix, q: np.ndarray) -> np.ndarray:
        """The order along a connected run of a middle line (its graph g, points q): from one end by surface
        distance; a closed run is cut next to that end and walked round from one side of the cut to the other."""
        if len(q) <= 2:
            return np.arange(len(q))
        a = int(np.nan_to_num(dijkstra(g, indices=0), posinf=-1.0).argmax())  # an end (the farthest from any point)
        da = dijkstra(g, indices=a)
        voxel = 2.0 * self._half_line
        cut = np.linalg.norm(q - q[a], axis=1) <= MAX_LINK * voxel
        rest = np.flatnonzero(~cut)
        if rest.size > 2:
            sub = g[rest][:, rest]
            n, _ = connected_components(sub, directed=False)
            if n == 1:
                e0 = int(np.nan_to_num(dijkstra(sub, indices=0), posinf=-1.0).argmax())
                d0 = dijkstra(sub, indices=e0)
                e1 = int(np.nan_to_num(d0, posinf=-1.0).argmax())
                near_a = np.linalg.norm(q[rest[[e0, e1]]] - q[a], axis=1) <= (MAX_LINK + 1.5) * voxel
                if near_a.all() and d0[e1] > 2.0 * (MAX_LINK + 1.5) * voxel:  # a loop: both ends of the rest by a
                    head = rest[np.argsort(d0, kind="stable")]
                    tail = np.flatnonzero(cut)
                    tail = tail[np.argsort(np.linalg.norm(q[tail] - q[head[-1]], axis=1), kind="stable")]
                    return np.concatenate([head, tail])
        return np.argsort(np.nan_to_num(da, posinf=np.inf), kind="stable")

    def _closed(self, arc: np.ndarray) -> bool:
        """Whether the arc (in order) ends next to where it starts (a loop, entered anywhere)."""
        return arc.size > 2 * WINDOW and bool(
            np.linalg.norm(self._points[arc[0]] - self._points[arc[-1]]) <= (MAX_LINK + 1.5) * 2.0 * self._half_line)

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

    def _edge_points(self) -> np.ndarray:
        """Target points (T,) (bool) on the edge of the target: their nearest neighbours' centroid lies more than
        ``EDGE_OFFSET`` of the neighbourhood's radius away from them (≈ 0 inside, ≈ 0.42 on a straight edge)."""
        k = min(EDGE_NEIGHBOURS, len(self._points))
        dist, idx = self._tree.query(self._points, k=k)
        offset = np.linalg.norm(self._points[idx].mean(axis=1) - self._points, axis=1)
        return offset > EDGE_OFFSET * np.maximum(dist[:, -1], 1e-12)

    def _outer_edge(self, members: np.ndarray, link: float = EDGE_LINKS[0]) -> np.ndarray:
        """Positions in ``members`` of the longest connected run of edge points of that part (its outer edge; a scan's
        holes and dropouts inside have edges too, and rings from all of them would cut the part into pieces)."""
        edge = np.flatnonzero(self._edge[members])
        if edge.size < MIN_EDGE_POINTS:
            return edge
        tree = cKDTree(self._points[members[edge]])
        pairs = tree.query_pairs(2.0 * self._half_line * link, output_type="ndarray")
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(edge.size, edge.size))
        _, label = connected_components(graph, directed=False)
        size = np.bincount(label)
        if size.max() < MIN_EDGE_POINTS:  # scattered points of a noisy or curved surface, not an edge
            return np.zeros(0, dtype=np.intp)
        return edge[label == size.argmax()]

    @staticmethod
    def _smooth(links: csr_matrix, d: np.ndarray) -> np.ndarray:
        """d averaged over each point's links ``SMOOTHING`` times: a graph distance zigzags along the links, its
        level sets wobble by about a voxel, and a pass along them is longer than it needs to be; averaging keeps
        a distance that varies linearly (and the spacing of the level sets) away from the start and the edges."""
        d = np.where(np.isfinite(d), d, 0.0)
        adj = links.copy()
        adj.data[:] = 1.0
        deg = np.asarray(adj.sum(axis=1)).ravel()
        inv = np.divide(1.0, deg, out=np.zeros_like(deg), where=deg > 0)
        for _ in range(SMOOTHING):
            d = 0.5 * d + 0.5 * inv * (adj @ d)
        return d

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
        covered = [self.pending[b].any() for b in self._tree.query_ball_point(self._points[idx], self.footprint_m)]
        return idx[~np.array(covered, dtype=bool)]

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
