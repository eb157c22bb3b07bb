"""Ring passes: the walking plan of a sweep, passes along rings of surface distance from the target's edge.

Whatever a coverage path does, it covers at most a band of width 2 r_a per metre, so a target of
area A needs at least A / (2 r_a) of path. HEDAC's strokes, even with the sweep source, lay passes
as the potential happens to curve and leave slivers and single points between them, each costing a
later pass. A planned sweep lays its passes side by side instead: along the level sets of the
geodesic distance d (its rings), ``pass_spacing`` apart, from the target's outer edge (origin
"edge": contour-parallel passes, as a pocket is milled; the first pass's footprint reaches the
edge, and a disc is covered in closed loops) or, on a surface without an edge or with origin
"start", from the agent's start. The ring k holds
the target points with k·w ≤ d < (k+1)·w, w = ``pass_spacing``; its pass runs along d = (k+½)·w,
so a footprint of radius r_a ≥ w/2 centred on it covers the ring, and w a little under 2 r_a leaves
an overlap for the agent's tracking error. On a closed or holed surface a ring breaks into several
arcs; at the end of an arc the agent goes on with the next ring when that is near (one pass back
along it, a boustrophedon) and comes back for the rest of the ring later.

The plan is a set of waypoints, the target points on the middle line of their ring
(|d − (k+½)·w| ≤ ½ voxel). The agent steers at the pending waypoint of least

    cost_j = |x_j − x| + ``ring_cost`` · w · (k_j − k_low),  k_low = the lowest ring with a pending waypoint,

and a waypoint is done once the agent came within ``reach_m`` of it (the same voxel, about). When no
waypoint of the agent's part is left the explorer takes it to the nearest untouched point of the
part, one after the other, and then the sweep source's potential and the relocation rules take over
(other parts get their rings when the agent touches down there).

d is Dijkstra's distance (scipy.sparse.csgraph) over the links of the cloud's Laplacian between
target points, each as long as its chord: the same neighbourhoods the heat diffuses over, and the
same parts, except links longer than ``MAX_LINK`` voxels (a hole the agent cannot walk across). A
graph distance zigzags along the links, so it is smoothed before its level sets are taken.
"""

from __future__ import annotations

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
#: On the way to a far goal the agent steers at the point within this many half-voxels nearest to it by surface
#: distance (a carrot a few voxels ahead on the shortest path).
CARROT = 6.0


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
            from the start on a part without one) or "start".
    """

    def __init__(self, points: np.ndarray, links, pass_spacing_m: float, reach_m: float, voxel_m: float,
                 ring_cost: float = 1.0, allowed: np.ndarray | None = None, origin: str = "edge") -> None:
        self._points = np.asarray(points, dtype=np.float64)
        n = len(self._points)
        self.pass_spacing_m = float(pass_spacing_m)
        self.reach_m = float(reach_m)
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
        self._tree = cKDTree(self._points)
        if origin not in PASS_ORIGINS:
            raise ValueError(f"origin must be one of {PASS_ORIGINS}, got {origin!r}")
        self.origin = origin
        self._edge = self._edge_points() if origin == "edge" else np.zeros(n, dtype=bool)
        self.reset()

    def reset(self) -> None:
        """No rings laid, nothing done."""
        self.ring = np.full(len(self._points), -1, dtype=np.intp)  # ring index of each waypoint, −1: none
        self.pending = np.zeros(len(self._points), dtype=bool)
        self._laid = np.zeros(self.n_parts, dtype=bool)
        self._goal = -1
        self._to_goal = None  # surface distance to a far goal [m] (T,), or None: steer straight at it

    def drop_goal(self, abandon: bool) -> None:
        """Forget the current goal (the agent relocated); ``abandon``: it could not reach it, mark it done."""
        if abandon and self._goal >= 0:
            self.pending[self._goal] = False
        self._goal = -1
        self._to_goal = None

    def lay(self, start: int) -> None:
        """Lay the rings of target point ``start``'s part from it (once per part)."""
        part = int(self._part[start])
        if self._laid[part]:
            return
        self._laid[part] = True
        members = np.flatnonzero(self._part == part)
        sub = self._graph[members][:, members]
        edge = self._outer_edge(members) if self.origin == "edge" else np.zeros(0, dtype=np.intp)
        if edge.size >= MIN_EDGE_POINTS:
            d = dijkstra(sub, directed=False, indices=edge, min_only=True)
        else:  # no edge (a closed surface) or rings from the start asked for
            d = dijkstra(sub, directed=False, indices=int(np.searchsorted(members, start)))
        d = self._smooth(sub, d)
        w = self.pass_spacing_m
        k = np.floor(d / w)
        on_line = np.abs(d - (k + 0.5) * w) <= self._half_line
        way = members[on_line & self._allowed[members]]
        self.ring[way] = k[on_line & self._allowed[members]].astype(np.intp)
        self.pending[way] = True

    def _edge_points(self) -> np.ndarray:
        """Target points (T,) (bool) on the edge of the target: their nearest neighbours' centroid lies more than
        ``EDGE_OFFSET`` of the neighbourhood's radius away from them (≈ 0 inside, ≈ 0.42 on a straight edge)."""
        k = min(EDGE_NEIGHBOURS, len(self._points))
        dist, idx = self._tree.query(self._points, k=k)
        offset = np.linalg.norm(self._points[idx].mean(axis=1) - self._points, axis=1)
        return offset > EDGE_OFFSET * np.maximum(dist[:, -1], 1e-12)

    def _outer_edge(self, members: np.ndarray) -> np.ndarray:
        """Positions in ``members`` of the longest connected run of edge points of that part (its outer edge; a scan's
        holes and dropouts inside have edges too, and rings from all of them would cut the part into pieces)."""
        edge = np.flatnonzero(self._edge[members])
        if edge.size < MIN_EDGE_POINTS:
            return edge
        tree = cKDTree(self._points[members[edge]])
        pairs = tree.query_pairs(2.0 * self._half_line * MAX_LINK, output_type="ndarray")
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
            self.pending[idx] = False

    def nearest(self, x: np.ndarray) -> int:
        """The target point nearest to x (3,) [m]."""
        return int(self._tree.query(x)[1])

    def waypoint(self, x: np.ndarray, near: int) -> np.ndarray | None:
        """The waypoint [m] (3,) the agent at x (3,) [m], nearest target point ``near``, steers at; None
        when its part has no pending waypoint (lays the part's rings first if they are not)."""
        self.lay(near)
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
        if self._to_goal is None:
            return self._points[g]
        around = np.asarray(self._tree.query_ball_point(x, CARROT * self._half_line), dtype=np.intp)
        if around.size == 0:
            return self._points[g]
        to = self._to_goal[around]
        k = int(to.argmin())
        if not np.isfinite(to[k]) or to[k] <= self.reach_m:
            self._to_goal = None
            return self._points[g]
        return self._points[around[k]]
