"""Surface distances within a radius, compiled with numba (the optional ``fast`` extra) where it is there.

The pass planner of a large part (:mod:`.pass_tour`) needs the surface distances from each of thousands of
arc ends to the points around it, a few pass spacings far. scipy's Dijkstra sets up every point of the graph
once per source (about a millisecond per source on 100k points, whatever the limit); the search here
touches only the points it reaches, keeping one distance array over calls and clearing what it wrote.
:class:`SmallGraph` runs the same search over the small graph of one arc of a ring (hundreds of them per
plan, where scipy's set-up and checks cost more than the search). It is Dijkstra's algorithm with a binary
heap: each reached point's distance is the same sum along the same shortest path as scipy's, so the two
agree to the last bit. Without numba scipy's search runs.

Machine code is made on first use and cached by numba beside this file (as :mod:`.compiled_step` is).
"""

from __future__ import annotations

import heapq
from collections.abc import Callable

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from tactex.ergodic import compiled_step

__all__ = ["SmallGraph", "limited_search", "search_within"]

#: A search from a point: (point, limit [m]) → (indices of the points reached within the limit, their distances [m]).
Search = Callable[[int, float], tuple[np.ndarray, np.ndarray]]

_compiled = None  # search_within compiled, made on first use


def search_within(indptr, indices, weights, source, limit, dist, reached, reached_d):
    """Dijkstra from ``source`` over the CSR graph (indptr, indices, weights [m]) up to ``limit`` [m]: the points
    reached in order of distance into ``reached`` and their distances into ``reached_d``; returns how many.
    ``dist`` (N,) is all inf on entry and on return (scratch)."""
    heap = [(0.0, source)]
    dist[source] = 0.0
    touched = [source]
    n = 0
    while heap:
        d, v = heapq.heappop(heap)
        if d > dist[v]:
            continue  # a stale entry: v was reached shorter since
        reached[n] = v
        reached_d[n] = d
        n += 1
        for k in range(indptr[v], indptr[v + 1]):
            u = indices[k]
            nd = d + weights[k]
            if nd < dist[u] and nd <= limit:
                if dist[u] == np.inf:
                    touched.append(u)
                dist[u] = nd
                heapq.heappush(heap, (nd, u))
    for u in touched:
        dist[u] = np.inf
    return n


def _compiled_search():
    """search_within compiled by numba, or None (numba missing, switched off, or failing)."""
    global _compiled
    if _compiled is None:
        if not compiled_step.available():
            return None
        try:
            from numba import config, njit

            if config.DISABLE_JIT:
                return None
            try:
                _compiled = njit(cache=True, nogil=True)(search_within)
            except RuntimeError:  # no writable cache location: compile in this process only
                _compiled = njit(nogil=True)(search_within)
        except ImportError:
            return None
    return _compiled


def limited_search(graph: csr_matrix) -> Search:
    """A search of surface distances within a limit over ``graph`` (N, N), symmetric CSR [m]: compiled when numba is
    there, else scipy's limited Dijkstra."""
    g = graph.tocsr()
    fn = _compiled_search()
    if fn is not None:
        indptr = g.indptr.astype(np.int64)
        indices = g.indices.astype(np.int64)
        weights = g.data.astype(np.float64)
        n = g.shape[0]
        dist = np.full(n, np.inf)
        reached = np.empty(n, dtype=np.int64)
        reached_d = np.empty(n)
        try:
            fn(indptr, indices, weights, 0, 0.0, dist, reached, reached_d)  # compile (or load) now
        except Exception:  # numba's typing or compilation: scipy still works
            fn = None
    if fn is not None:
        def search(v: int, limit: float) -> tuple[np.ndarray, np.ndarray]:
            m = fn(indptr, indices, weights, int(v), float(limit), dist, reached, reached_d)
            return reached[:m].copy(), reached_d[:m].copy()
        return search

    def scipy_search(v: int, limit: float) -> tuple[np.ndarray, np.ndarray]:
        row = dijkstra(g, directed=True, indices=int(v), limit=limit)
        idx = np.flatnonzero(np.isfinite(row))
        return idx, row[idx]
    return scipy_search


class SmallGraph:
    """A small undirected graph of ``n`` points (one arc of a ring's middle line) for repeated full searches.

    Args:
        n: its points.
        rows, cols: the ends of each link, each link once (int arrays).
        weights: the links' lengths [m] (> 0).
        compiled: search with the compiled search when numba is there (else, or when False, scipy's: a small part
            need not import numba, which costs a second or two).
    """

    def __init__(self, n: int, rows: np.ndarray, cols: np.ndarray, weights: np.ndarray, compiled: bool = True) -> None:
        self.n = int(n)
        self._edges = (np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64),
                       np.asarray(weights, dtype=np.float64))
        r = np.concatenate((self._edges[0], self._edges[1]))  # both directions
        c = np.concatenate((self._edges[1], self._edges[0]))
        w = np.concatenate((self._edges[2], self._edges[2]))
        order = np.argsort(r, kind="stable")
        self._indices, self._weights = c[order], w[order]
        self._indptr = np.zeros(self.n + 1, dtype=np.int64)
        np.cumsum(np.bincount(r, minlength=self.n), out=self._indptr[1:])
        self._compiled = compiled
        self._fn = _compiled_search() if compiled else None

    def sub(self, keep: np.ndarray) -> SmallGraph:
        """The graph on the points ``keep`` (ascending indices), numbered in that order, and the links between them."""
        pos = np.full(self.n, -1, dtype=np.int64)
        pos[keep] = np.arange(keep.size)
        r, c, w = self._edges
        ok = (pos[r] >= 0) & (pos[c] >= 0)
        return SmallGraph(keep.size, pos[r[ok]], pos[c[ok]], w[ok], self._compiled)

    def distances(self, source: int) -> np.ndarray:
        """Surface distances [m] (n,) from point ``source`` along the links (inf: not connected to it)."""
        out = np.full(self.n, np.inf)
        if self._fn is None:
            g = csr_matrix((self._weights, self._indices, self._indptr), shape=(self.n, self.n))
            return dijkstra(g, directed=True, indices=int(source))
        reached = np.empty(self.n, dtype=np.int64)
        reached_d = np.empty(self.n)
        m = self._fn(self._indptr, self._indices, self._weights, int(source), np.inf, np.full(self.n, np.inf),
                     reached, reached_d)
        out[reached[:m]] = reached_d[:m]
        return out
