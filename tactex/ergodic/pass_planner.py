"""The pass planner: the ring passes of a sweep laid along rings of surface distance, and their tour.

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
into the tour where each lengthens it least, or toured as arcs of their own when that is shorter.

The plan is a set of waypoints, the target points on the middle line of their ring (|d − (k+½)·w| ≤ ½ voxel). On
a closed or holed surface a ring's middle line breaks into several arcs (its connected runs); each arc is
ordered along itself, and the arcs are walked as an open tour from the agent: nearest neighbour over their ends
(a closed arc is entered anywhere), then 2-opt, by the chords and by the surface distances between the ends; the
surface's tour is kept when its moves are clearly shorter along the surface (the agent walks them on the surface:
round a fold or an ear's base the chord is a fraction of the walk). The tour and its distances live in
:mod:`.pass_tour`; on a part of over ``EXACT_POINTS`` target points the surface distances are searched only a few
pass spacings far, and the nearest-neighbour tour, 2-opt's distances and the order along each run are formed
without a pass over the whole part per arc (:mod:`.compiled_graph`, :mod:`.compiled_arcs`): the plan of a
100k-point part takes seconds, not many minutes.

d is Dijkstra's distance (scipy.sparse.csgraph) over the links of the cloud's Laplacian between
target points, each as long as its chord: the same neighbourhoods the heat diffuses over, and the
same parts, except links longer than ``MAX_LINK`` voxels (a hole the agent cannot walk across). A
graph distance zigzags along the links, so it is smoothed before its level sets are taken.

:class:`PassPlanner` is the planning half of :class:`~tactex.ergodic.passes.RingPasses`, which follows
the plan online (:mod:`.passes`).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from tactex.ergodic import compiled_arcs
from tactex.ergodic.compiled_arcs import compiled_ring_orders
from tactex.ergodic.compiled_graph import SmallGraph
from tactex.ergodic.pass_tour import (
    EXACT_POINTS,
    SURFACE_LIMIT,
    TWO_OPT_PASSES,
    Distances,
    nearest_arcs,
    nearest_arcs_within,
    node_matrix,
    surface_moves,
    two_opt,
)

__all__ = [
    "AT_RISK",
    "CLEAN_UP",
    "EDGE_LINKS",
    "EDGE_OFFSET",
    "EXACT_POINTS",
    "HUNT_FACTOR",
    "ISLAND_COST",
    "LEFTOVER",
    "MAX_LINK",
    "MIN_EDGE_POINTS",
    "SMOOTHING",
    "SPACING_SHARES",
    "START_PENALTY",
    "SUBSAMPLE",
    "SURFACE_GAIN",
    "SURFACE_LIMIT",
    "TWO_OPT_PASSES",
    "WINDOW",
    "PassPlanner",
]

#: Rounds of averaging of the distance over the links before its level sets are taken (see RingPasses._smooth).
SMOOTHING = 10
#: Longest link of the distance graph [voxels]: the agent walks up to a voxel off the cloud
#: (max_off_cloud_voxels), so it crosses a gap of two voxels between cloud points, not more.
MAX_LINK = 2.0
#: Edge points: centroid offset of EDGE_NEIGHBOURS nearest neighbours over their radius above EDGE_OFFSET; a part
#: whose longest connected run of them is shorter than MIN_EDGE_POINTS has no edge (a closed surface).
EDGE_NEIGHBOURS = 12
EDGE_OFFSET = 0.25
MIN_EDGE_POINTS = 10
#: Edge points this close [voxels] are one run of the edge, tried in turn (a rim where the surface turns steep is
#: sampled sparsely and its edge points lie a few voxels apart; a scan's dropouts lie a few voxels inside its rim).
EDGE_LINKS = (2.0, 4.0)
#: Waypoints of an arc the follower looks at for the agent's place on it and for the carrot; an arc longer than twice
#: this that ends next to its start is a loop [-].
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
#: What an island of points at risk (points within a footprint radius joined) costs the hunt, in footprint radii [-]
#: of path: a detour to the island and back.
ISLAND_COST = 2.0
#: Waypoints of an arc between two along which its length is measured [-] (see RingPasses._tour_length).
SUBSAMPLE = 3
#: The tour over the arcs planned by surface distance replaces the one planned by chord when its moves between arcs
#: are shorter along the surface than this share of the chord tour's [-]: on a flat or gently curved part the two
#: differ by the graph distance's zigzag, and the chord's tour is kept (see RingPasses._tour_of).
SURFACE_GAIN = 0.9
#: Target points farther than LEFTOVER footprint radii from every waypoint of the chosen plan (where the rings'
#: wavefronts meet) get clean-up waypoints: centres of a greedy cover by discs of CLEAN_UP footprint radii [-].
LEFTOVER = 1.0
#: Radius of the clean-up discs, in footprint radii [-] (see LEFTOVER).
CLEAN_UP = 0.6


#: A part with this many target points announces its plan before it starts (it takes seconds to minutes).
PROGRESS_MIN_POINTS = 20_000
#: Seconds between the planner's progress lines.
PROGRESS_EVERY_S = 3.0


class PassPlanner:
    """Laying a part's rings and planning the tour over their arcs (the planning half of
    :class:`~tactex.ergodic.passes.RingPasses`: it reads the target points, their walking graph and parts, the
    spacing and the footprint set there, and writes the plan into ``ring``, ``pending``, ``_tour``, ``_arc``,
    ``_at``, ``spacing_m`` and ``_clean``). ``progress``, when set, is called with one-line messages while a
    large part is planned (the first step of a whole-surface run waits for it)."""

    progress: Callable[[str], None] | None = None
    _tick_from: float | None = None  # when the plan being laid started, while it says how far it got (see _tick)
    _said_at = 0.0
    _tick_about = ""  # what the plan is at (the candidate), before the tick's own words
    #: Order the arcs of a large part's rings with :mod:`.compiled_arcs` when numba is there (False: in Python).
    compiled_arcs: bool = True

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
        t_start = time.perf_counter()
        self._said_at = t_start  # when the last progress line went out
        self._tick_from = t_start if members.size >= PROGRESS_MIN_POINTS else None  # see _tick

        def say(msg: str, now: float | None = None) -> None:
            if self.progress is not None:
                self._said_at = time.perf_counter() if now is None else now
                self.progress(msg)
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
        n_plans = len(seeds) * (len(SPACING_SHARES) if self.order == "tour" else 1)
        if members.size >= PROGRESS_MIN_POINTS:
            say(f"pass plan: {members.size} target points in this part, {n_plans} candidate plan(s) to compare ...")
        if members.size > EXACT_POINTS and compiled_arcs.compile_pending():
            say("pass plan: preparing its compiled searches (a second or two from numba's cache; the first time on a "
                "machine numba compiles them, 10–20 s) ...")
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
                self._tick_about = f"candidate {len(plans) + 1} of {n_plans}: "
                self._tick(f"{way.size} waypoints on its rings")
                self._plan(part, self._points[start])
                length = self._tour_length(part)
                if seed.size == 1 and len(seeds) > 1:
                    length *= START_PENALTY
                gap = self._gap(members, way)
                length += self._hunt_length(members, gap) / (HUNT_FACTOR if thin else 1.0)
                plans.append((n_seed, share, length, length + self._island_cost(members, gap),
                              (way, self.ring[way].copy(), self._tour[part], self._arc[part], w, self._last_arcs)))
                self.ring[way] = -1
                self.pending[way] = False
                now = time.perf_counter()
                if now - self._said_at >= PROGRESS_EVERY_S:
                    say(f"pass plan: {len(plans)} of {n_plans} candidate plans ({now - t_start:.0f} s)", now)
        # The origin by its plan at the full spacing (tour and the hunt for what it leaves), then its spacing also by
        # the islands it leaves at risk: compared over origins, the islands would choose worse origins.
        origin = min((p for p in plans if p[1] == SPACING_SHARES[0]), key=lambda p: p[2])[0]
        way, ring, self._tour[part], self._arc[part], self.spacing_m[part], arcs = min(
            (p for p in plans if p[0] == origin), key=lambda p: p[3])[4]
        self.ring[way] = ring
        self.pending[way] = True
        extra = self._clean_up(members, way)
        if extra.size:
            # a ring of its own per clean-up waypoint: an arc of one, which the agent's place on an arc never passes
            # (only CLEAN_REACH marks it done)
            self.ring[extra] = ring.max() + 1 + np.arange(extra.size)
            self.pending[extra] = True
            # the passes' own arcs and tour are the chosen plan's (the same waypoints, from the same start)
            self._tick_about = f"the chosen plan and {extra.size} clean-up waypoints: "
            self._plan(part, self._points[start], known=(self._tour[part], self._arc[part], arcs))
        self._at[part] = 0
        if time.perf_counter() - t_start >= PROGRESS_EVERY_S or members.size >= PROGRESS_MIN_POINTS:
            say(f"pass plan: laid in {time.perf_counter() - t_start:.1f} s")
        self._tick_from = None

    def _tick(self, what: str) -> None:
        """A progress line "pass plan: <candidate>: ``what`` (t s)" while a large part's plan is laid, at most every
        ``PROGRESS_EVERY_S`` (a candidate plan of a 100k-point part takes seconds)."""
        if self.progress is None or self._tick_from is None:
            return
        now = time.perf_counter()
        if now - self._said_at >= PROGRESS_EVERY_S:
            self._said_at = now
            self.progress(f"pass plan: {self._tick_about}{what} ({now - self._tick_from:.0f} s)")

    # ------------------------------------------------------------------ the tour over the arcs
    def _plan(self, part: int, x: np.ndarray, known: tuple | None = None) -> None:
        """The part's pending waypoints as arcs (connected runs of one ring's middle line, each in order along it),
        and the arcs in the order of a short open tour from x (3,) [m] (see _tour_of). ``known``: the tour, its
        arc numbers and the arcs of the waypoints other than the clean-up ones, planned from x already."""
        idx = np.flatnonzero(self.pending & (self._part == part))
        clean = np.isin(idx, np.fromiter(self._clean, dtype=np.intp, count=len(self._clean)))
        if known is None:
            self._plan_arcs(part, idx[~clean], x)
        else:
            self._tour[part], self._arc[part], self._last_arcs = known
            self._at[part] = 0
        if clean.any():
            self._insert(part, idx[clean])
            inserted = self._tour[part], self._arc[part], self._tour_length(part)
            # a clean-up waypoint is a ring of its own, after the passes' rings: an arc of one (see _arcs)
            arcs = None if known is None else list(known[2]) + [idx[clean][self.ring[idx[clean]] == k]
                                                                for k in np.unique(self.ring[idx[clean]])]
            self._plan_arcs(part, idx, x, arcs)
            if self._tour_length(part) >= inserted[2]:
                self._tour[part], self._arc[part] = inserted[:2]

    def _plan_arcs(self, part: int, idx: np.ndarray, x: np.ndarray, arcs: list[np.ndarray] | None = None) -> None:
        """The waypoints idx as arcs (``arcs`` when known) in the order of a short open tour from x (3,) [m] (see
        _tour_of)."""
        if arcs is None:
            arcs = self._arcs(idx)
            self._tick(f"{len(arcs)} arcs along the rings")
        self._last_arcs = list(arcs)
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
        once by the chords between the ends and once by the surface distances (:mod:`.pass_tour`). The agent walks
        the moves down the surface distance: round a fold or an ear's base the chord ranks them wrongly, so the
        surface's tour is kept when its moves are shorter along the surface than ``SURFACE_GAIN`` times the
        chord's; on a flat part the graph distance zigzags along the links and ranks straight moves wrongly, and
        the chord's tour is kept."""
        closed = [self._closed(a) for a in arcs]
        start = self._on_arcs(arcs, x)
        size = np.count_nonzero(self._part == self._part[start])
        limit = np.inf if size <= EXACT_POINTS else SURFACE_LIMIT * self.pass_spacing_m
        dist = Distances(self._points, self._graph, limit)
        tours = []
        for way in (dist.chord, dist.surface):
            if np.isfinite(limit):
                along = way == dist.surface
                first = nearest_arcs_within(arcs, closed, start, dist, by_surface=along)
                walk = two_opt(first, start, way, lambda nodes, along=along: node_matrix(nodes, dist, along))
            else:
                walk = two_opt(nearest_arcs(arcs, closed, start, way), start, way)
            tours.append((walk, surface_moves(walk, start, dist)))
            self._tick(f"a tour over {len(arcs)} arcs by {'chord' if way == dist.chord else 'surface distance'}")
        (by_chord, chord_m), (by_surface, surface_m) = tours
        return by_surface if surface_m < SURFACE_GAIN * chord_m else by_chord

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
        balls = [np.asarray(b, dtype=np.intp) for b in cKDTree(q).query_ball_point(q, CLEAN_UP * self.footprint_m)]
        open_ = np.ones(left.size, dtype=bool)
        gain = np.array([b.size for b in balls])  # open points per disc
        n_open = left.size
        centres = []
        while n_open:
            c = int(gain.argmax())
            closing = balls[c][open_[balls[c]]]
            centres.append(left[c])
            self._clean[int(left[c])] = left[closing]
            open_[closing] = False
            n_open -= closing.size
            # a point closing leaves every disc that holds it: the discs centred within the radius of it
            np.subtract.at(gain, np.concatenate([balls[j] for j in closing]), 1)
        return np.asarray(centres, dtype=np.intp)

    def _gap(self, members: np.ndarray, way: np.ndarray) -> np.ndarray | None:
        """Distance [m] (M,) from each point of ``members`` to the nearest of the waypoints ``way``, inf beyond the
        footprint radius (what the hunt and the islands ask of a plan); None without waypoints."""
        if way.size == 0:
            return None
        return cKDTree(self._points[way]).query(self._points[members], distance_upper_bound=self.footprint_m)[0]

    def _hunt_length(self, members: np.ndarray, gap: np.ndarray | None) -> float:
        """Estimated path [m] of the hunt for the points of ``members`` a plan leaves, given their distances ``gap``
        to its waypoints (:meth:`_gap`): those farther than the footprint radius from every waypoint, HUNT_FACTOR
        times their ideal path."""
        left = members.size if gap is None else int(np.count_nonzero(~np.isfinite(gap)))
        voxel = 2.0 * self._half_line
        return HUNT_FACTOR * left * voxel * voxel / (2.0 * self.footprint_m)

    def _island_cost(self, members: np.ndarray, gap: np.ndarray | None) -> float:
        """Estimated detours [m] of the hunt for the islands of points of ``members`` that a plan leaves at risk
        (farther than AT_RISK footprint radii from every waypoint; ``gap``: see :meth:`_gap`): ISLAND_COST radii
        each."""
        if gap is None:
            return 0.0  # the hunt estimate already counts the whole part
        risk = self._points[members[gap > AT_RISK * self.footprint_m]]
        if len(risk) == 0:
            return 0.0
        pairs = cKDTree(risk).query_pairs(self.footprint_m, output_type="ndarray")
        g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(risk), len(risk)))
        return ISLAND_COST * self.footprint_m * connected_components(g, directed=False)[0]

    def _arcs(self, idx: np.ndarray) -> list[np.ndarray]:
        """Waypoints idx split into arcs: per ring, the connected runs of its middle line (links ≤ MAX_LINK
        voxels), each ordered along itself."""
        link = MAX_LINK * 2.0 * self._half_line
        arcs: list[np.ndarray] = []
        large = idx.size > 0 and self._sizes[self._part[idx[0]]] > EXACT_POINTS  # see pass_tour.EXACT_POINTS
        compiled = compiled_ring_orders() if large and self.compiled_arcs else None
        for k in np.unique(self.ring[idx]):
            ring = idx[self.ring[idx] == k]
            if ring.size <= 2:
                arcs.extend(ring[i:i + 1] for i in range(ring.size))
                continue
            q = self._points[ring]
            pairs = cKDTree(q).query_pairs(link, output_type="ndarray")
            length = np.maximum(np.linalg.norm(q[pairs[:, 0]] - q[pairs[:, 1]], axis=1), 1e-12)
            g = coo_matrix((length, (pairs[:, 0], pairs[:, 1])), shape=(ring.size, ring.size))
            n, label = connected_components(g, directed=False)
            if compiled is not None:  # every run of the ring in one compiled call (the same orders)
                voxel = 2.0 * self._half_line
                order, starts = compiled(ring.size, pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64),
                                         length, label.astype(np.int64), n, q, MAX_LINK * voxel,
                                         (MAX_LINK + 1.5) * voxel, 2.0 * (MAX_LINK + 1.5) * voxel)
                arcs.extend(ring[order[starts[c]:starts[c + 1]]] for c in range(n))
                continue
            whole = SmallGraph(ring.size, pairs[:, 0], pairs[:, 1], length, compiled=large)
            for c in range(n):
                m = np.flatnonzero(label == c)
                arcs.append(ring[m[self._along(whole.sub(m), q[m])]])
        return arcs

    def _along(self, g: SmallGraph, q: np.ndarray) -> np.ndarray:
        """The order along a connected run of a middle line (its graph g, points q): from one end by surface
        distance; a closed run is cut next to that end and walked round from one side of the cut to the other."""
        if len(q) <= 2:
            return np.arange(len(q))
        a = int(np.nan_to_num(g.distances(0), posinf=-1.0).argmax())  # an end (the farthest from any point)
        da = g.distances(a)
        voxel = 2.0 * self._half_line
        cut = np.linalg.norm(q - q[a], axis=1) <= MAX_LINK * voxel
        rest = np.flatnonzero(~cut)
        if rest.size > 2:
            sub = g.sub(rest)
            d_first = sub.distances(0)
            if np.isfinite(d_first).all():  # the rest is connected
                e0 = int(np.nan_to_num(d_first, posinf=-1.0).argmax())
                d0 = sub.distances(e0)
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
