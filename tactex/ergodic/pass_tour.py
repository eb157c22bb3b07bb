"""The tour over the arcs of a sweep's planned passes, and the distances it is planned by.

The arcs (connected runs of the rings' middle lines, :mod:`.pass_planner`) are walked as an open tour from
the agent: nearest neighbour over their ends (a closed arc is entered at its point nearest to where the
tour is), then 2-opt, once by the chords between the ends and once by the surface distances; the planner
keeps the surface's tour where its moves are clearly shorter along the surface.

The surface distance is Dijkstra's over the walking graph (links between target points as long as their
chords). On a part of at most ``EXACT_POINTS`` target points each row is the whole graph's (scipy). On a
larger part, whose arcs number in the thousands and whose graph in the hundreds of thousands of links,
that costs tens of milliseconds per arc end and minutes per plan, so there each row stops at
``SURFACE_LIMIT`` pass spacings: pairs within it get their exact surface distance, pairs beyond it
max(chord, limit), a lower bound that still ranks a move round a fold (a short chord, a long walk) far.
The tour's moves are mostly between neighbouring rings, a pass spacing or two apart, and keep their
exact distances. The limited search is compiled (:mod:`.compiled_graph`, numba) when the ``fast``
extra is installed: it touches only the points it reaches, where scipy's touches every point of the
graph once per row.
"""

from __future__ import annotations

from collections.abc import Callable
from itertools import pairwise

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from tactex.ergodic import compiled_graph

__all__ = ["EXACT_POINTS", "SURFACE_LIMIT", "TWO_OPT_PASSES", "Distances", "nearest_arcs", "nearest_arcs_within",
           "node_matrix", "two_opt"]

#: A part of at most this many target points plans its tour by exact surface distances between all arc ends [-].
EXACT_POINTS = 20_000
#: On a larger part the surface distances are searched this many pass spacings far (beyond: max(chord, limit)) [-].
SURFACE_LIMIT = 4.0
#: Passes of 2-opt over the tour of the arcs at most (each is O(n²) in the arcs; it converges in a few).
TWO_OPT_PASSES = 20

#: The distances from target point v to target points idx (an index array) [m].
Way = Callable[[int, np.ndarray], np.ndarray]


class Distances:
    """Distances [m] from a target point to others by chord and along the walking graph, rows cached per source.

    Args:
        points: target points (T, 3) [m].
        graph: the walking graph (T, T), symmetric CSR, each link as long as its chord [m].
        limit_m: how far along the surface a row is searched [m]; inf: the whole graph (exact everywhere).
    """

    def __init__(self, points: np.ndarray, graph: csr_matrix, limit_m: float = np.inf) -> None:
        self.points = self._p = points
        self._graph = graph
        self.limit_m = float(limit_m)
        self._rows: dict[int, np.ndarray | tuple[np.ndarray, np.ndarray]] = {}
        self._search = None
        if np.isfinite(self.limit_m):
            self._search = compiled_graph.limited_search(graph)
            self._scratch = np.full(len(points), np.inf)

    def chord(self, v: int, idx: np.ndarray) -> np.ndarray:
        """Straight-line distances from point v to the points idx [m]."""
        return np.linalg.norm(self._p[idx] - self._p[v], axis=1)

    def reach(self, v: int) -> tuple[np.ndarray, np.ndarray]:
        """With a finite limit: the points within it along the surface from point v and their distances [m]."""
        row = self._rows.get(v)
        if row is None:
            row = self._rows[v] = self._search(v, self.limit_m)
        return row

    def surface(self, v: int, idx: np.ndarray) -> np.ndarray:
        """Surface distances from point v to the points idx [m] (inf: another part); with a finite limit, a point
        farther than it along the surface gets max(chord, limit)."""
        row = self._rows.get(v)
        if row is None:
            if self._search is None:
                # the graph is stored symmetric: a directed search gives the undirected distances, without
                # scipy transposing the graph for every row
                row = dijkstra(self._graph, directed=True, indices=v)
            else:
                row = self._search(v, self.limit_m)
            self._rows[v] = row
        if not isinstance(row, tuple):
            return row[idx]
        reached, dist = row
        s = self._scratch
        s[reached] = dist
        out = s[idx]
        s[reached] = np.inf
        far = ~np.isfinite(out)
        if far.any():
            out[far] = np.maximum(self.chord(v, idx[far]), self.limit_m)
        return out


def nearest_arcs(arcs: list[np.ndarray], closed: list[bool], start: int, way: Way) -> list[np.ndarray]:
    """The arcs in nearest-neighbour order from target point ``start`` by the distances ``way``, each entered at its
    nearer end (a closed one at its nearest point); of equally near arcs the first."""
    n = len(arcs)
    # where each arc may be entered: both ends of an open arc, every point of a closed one
    entry = [a if c else a[[0, -1]] for a, c in zip(arcs, closed, strict=True)]
    size = np.array([e.size for e in entry])
    owner = np.repeat(np.arange(n), size)
    flat = np.concatenate(entry)
    left = np.ones(n, dtype=bool)
    here = start
    walk: list[np.ndarray] = []
    for _ in range(n):
        on = left[owner]
        pts, own = flat[on], owner[on]
        r = way(here, pts)
        first = np.flatnonzero(np.r_[True, own[1:] != own[:-1]])
        best = np.minimum.reduceat(r, first)
        k = int(np.argmin(best))  # the first of the nearest (inf everywhere: the first arc left)
        i = int(own[first[k]])
        seg = r[first[k]:first[k] + size[i]]
        j = int(np.argmin(seg))
        a = arcs[i]
        seq = np.roll(a, -j) if closed[i] else (a if seg[0] <= seg[1] else a[::-1])
        left[i] = False
        walk.append(seq)
        here = int(seq[-1])
    return walk


def node_matrix(nodes: np.ndarray, dist: Distances, by_surface: bool) -> np.ndarray:
    """Distances [m] between the points ``nodes`` (all pairs, (M, M)) on a large part (``dist`` with a finite
    limit): chords, or the surface distances within the limit and max(chord, limit) beyond it (as
    :meth:`Distances.surface` gives them), formed at once instead of a row per node."""
    q = dist.points[nodes]
    out = cdist(q, q)
    if not by_surface:
        return out
    np.maximum(out, dist.limit_m, out=out)
    at = np.full(len(dist.points), -1, dtype=np.intp)
    at[nodes] = np.arange(nodes.size)
    for r, v in enumerate(nodes.tolist()):
        reached, d = dist.reach(v)
        c = at[reached]
        ok = c >= 0
        out[r, c[ok]] = d[ok]
    return out


def nearest_arcs_within(arcs: list[np.ndarray], closed: list[bool], start: int, dist: Distances,
                        by_surface: bool) -> list[np.ndarray]:
    """:func:`nearest_arcs` on a large part (``dist`` with a finite limit), by chord or by surface distance, without
    a pass over every entry point per arc: the nearest by chord from a K-D tree of the entry points of the arcs left
    (built again when half of its points are taken), the nearest along the surface among the entry points the
    limited search from where the tour is reaches (none: the nearest by chord, as max(chord, limit) ranks them).
    Of equally near entry points any may be taken."""
    n = len(arcs)
    entry = [a if c else a[[0, -1]] for a, c in zip(arcs, closed, strict=True)]
    size = np.array([e.size for e in entry])
    offs = np.r_[0, np.cumsum(size)[:-1]]
    owner = np.repeat(np.arange(n), size)
    flat = np.concatenate(entry)
    pts = dist.points[flat]
    alive = np.ones(flat.size, dtype=bool)
    pos = np.full(len(dist.points), -1, dtype=np.intp)
    pos[flat] = np.arange(flat.size)  # an arc of one point has it twice: either entry is the same
    tree_idx = np.arange(flat.size)
    tree = cKDTree(pts)
    here = start
    walk: list[np.ndarray] = []
    for _ in range(n):
        k = -1
        if by_surface:
            reached, d = dist.reach(here)
            cand = pos[reached]
            ok = cand >= 0
            ok[ok] = alive[cand[ok]]
            if ok.any():
                k = int(cand[ok][np.argmin(d[ok])])
        if k < 0:
            if np.count_nonzero(alive[tree_idx]) * 2 < tree_idx.size:
                tree_idx = np.flatnonzero(alive)
                tree = cKDTree(pts[tree_idx])
            m = 8
            while k < 0:
                m = min(m, tree_idx.size)
                nb = np.atleast_1d(tree.query(dist.points[here], k=m)[1])
                hit = np.flatnonzero(alive[tree_idx[nb]])
                if hit.size:
                    k = int(tree_idx[nb[hit[0]]])
                m *= 4
        i = int(owner[k])
        a = arcs[i]
        seq = np.roll(a, -(k - offs[i])) if closed[i] else (a if k == offs[i] else a[::-1])
        alive[offs[i]:offs[i] + size[i]] = False
        walk.append(seq)
        here = int(seq[-1])
    return walk


def two_opt(walk: list[np.ndarray], start: int, way: Way,
            matrix: Callable[[np.ndarray], np.ndarray] | None = None) -> list[np.ndarray]:
    """2-opt on an open tour of arcs from target point ``start`` by the distances ``way``: reversing a run of arcs
    reverses each of them too (``matrix``: the distances between given points at once, or None: row by row from
    ``way``). Each pass takes the first arc i (in tour order) whose reversal with some later run
    shortens the tour, with its best such run, and starts over. The arcs before i had no such run, and the move
    changes their gains only for runs ending in i − 1 … j: the next pass looks there only for them."""
    n = len(walk)
    if n < 3:
        return walk
    nodes = np.unique(np.concatenate([[start]] + [a[[0, -1]] for a in walk]))
    # between the ends (both ways: an arc may turn); ``matrix`` forms them at once where given
    dist = matrix(nodes) if matrix is not None else np.array([way(int(v), nodes) for v in nodes])
    at = {int(v): k for k, v in enumerate(nodes)}
    known, window = 0, (0, 0)  # arcs before ``known`` improve, if at all, only by runs ending in ``window``
    for _ in range(TWO_OPT_PASSES):
        entry = np.array([at[int(a[0])] for a in walk])
        out = np.array([at[int(a[-1])] for a in walk])
        move = _first_gain(dist, at[start], entry, out, known=known, window=window)
        if move is None:
            break
        i, j = move
        walk[i:j + 1] = [a[::-1] for a in walk[i:j + 1][::-1]]
        known, window = i, (max(i - 1, 0), j)
    return walk


def _first_gain(dist: np.ndarray, start: int, entry: np.ndarray, out: np.ndarray, block_elements: int = 1 << 16,
                known: int = 0, window: tuple[int, int] = (0, 0)) -> tuple[int, int] | None:
    """The first arc i whose run i..j reversed shortens the tour (gain over 1e-9 m) and the j of its largest gain,
    or None; the tour's arcs are entered at nodes ``entry`` and left at ``out`` (indices into ``dist``), from node
    ``start``. Reversing i..j turns the edge (before_i → entry_i) into (before_i → out_j) and (out_j → entry_{j+1})
    into (entry_i → entry_{j+1}); the last arc has no edge after it. Rows of i are scanned a block of about
    ``block_elements`` gains at a time (the first improving arc is often early in the tour); the rows before
    ``known`` only over the runs ending in ``window`` (j from window[0] to window[1]: their other gains are known
    not to improve)."""
    n = entry.size
    before = np.r_[start, out[:-1]]  # where the tour is before arc i
    nxt = np.r_[entry[1:], 0]  # where it goes after arc j
    old_after = dist[out, nxt]
    old_after[-1] = 0.0
    cols = np.arange(window[0], min(window[1], n - 1) + 1)
    for rows, js in ((np.arange(min(known, n - 1)), cols), (np.arange(min(known, n - 1), n - 1), np.arange(n))):
        if rows.size == 0 or js.size == 0:
            continue
        block = max(1, block_elements // js.size)
        for b0 in range(0, rows.size, block):
            i = rows[b0:b0 + block]
            old = dist[before[i], entry[i]][:, None]
            new = dist[before[i][:, None], out[js][None, :]]
            new_after = dist[entry[i][:, None], nxt[js][None, :]]
            new_after[:, js == n - 1] = 0.0
            gain = old + old_after[js]
            gain -= new
            gain -= new_after
            gain[js[None, :] <= i[:, None]] = -np.inf  # j > i only
            best = gain.max(axis=1)
            hit = np.flatnonzero(best > 1e-9)
            if hit.size:
                r = int(hit[0])
                return int(i[r]), int(js[gain[r].argmax()])
    return None


def surface_moves(walk: list[np.ndarray], start: int, dist: Distances) -> float:
    """Length [m] along the surface of the tour's moves between arcs (from ``start`` to the first arc, and from each
    arc's end to the next one's start)."""
    moves = [(start, walk[0][0])] + [(a[-1], b[0]) for a, b in pairwise(walk)]
    return sum(float(dist.surface(int(u), np.array([v]))[0]) for u, v in moves)
