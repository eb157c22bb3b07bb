"""The order along each arc of a ring's middle line, compiled with numba for a large part.

:meth:`~tactex.ergodic.pass_planner.PassPlanner._along` orders one connected run of a ring's middle line: from
one end by surface distance, a closed run cut next to that end and walked round. A 100k-point part has over a
thousand such runs per plan, mostly of a dozen or two points, and their Python and scipy calls (a small graph,
four searches, a few sorts each) cost about a millisecond a run. :func:`ring_orders` does the same steps for
all the runs of one ring in one compiled call: the same distances (Dijkstra's sums along the same paths, see
:mod:`.compiled_graph`), the same first maxima and the same stable sorts, so the same order.
"""

from __future__ import annotations

import numpy as np

from tactex.ergodic import compiled_graph

__all__ = ["compile_pending", "compiled_ring_orders", "ring_orders"]

_compiled = None  # ring_orders compiled, made on first use
_search = None  # compiled_graph.search_within compiled (what _distances calls once compiled)
#: Helpers compiled before ring_orders and put in place of their Python forms here (numba resolves its calls here).
HELPERS = ("_distances", "_first_max", "_norms", "_along_run")


def _distances(n, rows, cols, weights, source):
    """Surface distances (n,) from ``source`` over the links (rows, cols, weights [m], each link once; inf: not
    reached)."""
    count = np.zeros(n + 1, dtype=np.int64)
    for e in range(rows.shape[0]):
        count[rows[e] + 1] += 1
        count[cols[e] + 1] += 1
    indptr = np.cumsum(count)
    fill = indptr[:-1].copy()
    indices = np.empty(2 * rows.shape[0], dtype=np.int64)
    wts = np.empty(2 * rows.shape[0])
    for e in range(rows.shape[0]):
        a, b = rows[e], cols[e]
        indices[fill[a]] = b
        wts[fill[a]] = weights[e]
        fill[a] += 1
        indices[fill[b]] = a
        wts[fill[b]] = weights[e]
        fill[b] += 1
    dist = np.full(n, np.inf)
    reached = np.empty(n, dtype=np.int64)
    reached_d = np.empty(n)
    m = _search(indptr, indices, wts, source, np.inf, dist, reached, reached_d)
    out = np.full(n, np.inf)
    for k in range(m):
        out[reached[k]] = reached_d[k]
    return out


def _first_max(d):
    """Index of the first largest finite entry of d (inf counts as −1, as np.nan_to_num(posinf=−1) makes it)."""
    best, k = -np.inf, 0
    for i in range(d.shape[0]):
        v = d[i] if d[i] < np.inf else -1.0
        if v > best:
            best, k = v, i
    return k


def _norms(q, idx, x0, x1, x2):
    """|q[idx] − x| (len(idx),) [m], summed as np.linalg.norm(..., axis=1) sums."""
    out = np.empty(idx.shape[0])
    for k in range(idx.shape[0]):
        j = idx[k]
        a0, a1, a2 = q[j, 0] - x0, q[j, 1] - x1, q[j, 2] - x2
        out[k] = (a0 * a0 + a1 * a1 + a2 * a2) ** 0.5
    return out


def _along_run(n, rows, cols, weights, q, cut_r, near_r, loop_len):
    """PassPlanner._along on one run of n > 2 points q (n, 3) [m] linked by (rows, cols, weights)."""
    a = _first_max(_distances(n, rows, cols, weights, 0))
    da = _distances(n, rows, cols, weights, a)
    everyone = np.arange(n)
    cut = _norms(q, everyone, q[a, 0], q[a, 1], q[a, 2]) <= cut_r
    rest = np.flatnonzero(~cut)
    if rest.shape[0] > 2:
        pos = np.full(n, -1, dtype=np.int64)
        for k in range(rest.shape[0]):
            pos[rest[k]] = k
        keep = (pos[rows] >= 0) & (pos[cols] >= 0)
        sr, sc, sw = pos[rows[keep]], pos[cols[keep]], weights[keep]
        d_first = _distances(rest.shape[0], sr, sc, sw, 0)
        if np.all(d_first < np.inf):  # the rest is connected
            e0 = _first_max(d_first)
            d0 = _distances(rest.shape[0], sr, sc, sw, e0)
            e1 = _first_max(d0)
            ends = np.array([rest[e0], rest[e1]])
            near_a = _norms(q, ends, q[a, 0], q[a, 1], q[a, 2]) <= near_r
            if near_a[0] and near_a[1] and d0[e1] > loop_len:  # a loop: both ends of the rest by a
                head = rest[np.argsort(d0, kind="mergesort")]
                tail = np.flatnonzero(cut)
                last = head[head.shape[0] - 1]
                tail = tail[np.argsort(_norms(q, tail, q[last, 0], q[last, 1], q[last, 2]), kind="mergesort")]
                return np.concatenate((head, tail))
    return np.argsort(da, kind="mergesort")


def ring_orders(n, rows, cols, weights, label, n_comp, q, cut_r, near_r, loop_len):
    """The order along each connected run of a ring's middle line: its n points q (n, 3) [m], links (rows, cols,
    weights [m], each once), the run of each point (``label``, ``n_comp`` runs). Returns the points of run c in
    order as ``order[starts[c]:starts[c + 1]]`` (indices into q); ``cut_r``, ``near_r``, ``loop_len`` [m] are
    _along's cut radius, loop-end radius and shortest loop."""
    starts = np.zeros(n_comp + 1, dtype=np.int64)
    for i in range(n):
        starts[label[i] + 1] += 1
    starts = np.cumsum(starts)
    members = np.empty(n, dtype=np.int64)
    pos = np.empty(n, dtype=np.int64)
    fill = starts[:-1].copy()
    for i in range(n):  # ascending within each run
        c = label[i]
        pos[i] = fill[c] - starts[c]
        members[fill[c]] = i
        fill[c] += 1
    ecount = np.zeros(n_comp + 1, dtype=np.int64)
    for e in range(rows.shape[0]):
        ecount[label[rows[e]] + 1] += 1
    eptr = np.cumsum(ecount)
    efill = eptr[:-1].copy()
    eidx = np.empty(rows.shape[0], dtype=np.int64)
    for e in range(rows.shape[0]):  # a link joins two points of one run
        c = label[rows[e]]
        eidx[efill[c]] = e
        efill[c] += 1
    order = np.empty(n, dtype=np.int64)
    for c in range(n_comp):
        m = members[starts[c]:starts[c + 1]]
        if m.shape[0] <= 2:
            order[starts[c]:starts[c + 1]] = m
            continue
        es = eidx[eptr[c]:eptr[c + 1]]
        local = _along_run(m.shape[0], pos[rows[es]], pos[cols[es]], weights[es], q[m], cut_r, near_r, loop_len)
        order[starts[c]:starts[c + 1]] = m[local]
    return order, starts


def compile_pending() -> bool:
    """Whether the next large plan makes (or loads from numba's cache) the compiled searches of
    :mod:`.compiled_graph` and this module: numba is installed and enabled and this process holds them not yet."""
    if _compiled is not None or not compiled_graph.compiled_step.available():
        return False
    from numba import config

    return not config.DISABLE_JIT


def compiled_ring_orders():
    """ring_orders compiled by numba, or None (numba missing, switched off, or failing to compile)."""
    global _compiled, _search
    if _compiled is None:
        _search = compiled_graph._compiled_search()
        if _search is None:
            return None
        from numba import njit

        def jit(fn):
            try:
                return njit(cache=True, nogil=True)(fn)
            except RuntimeError:  # no writable cache location: compile in this process only
                return njit(nogil=True)(fn)

        namespace = globals()
        try:
            for name in HELPERS:
                namespace[name] = jit(namespace[name])
            _compiled = jit(ring_orders)
        except Exception:  # numba's typing: the planner goes on in Python
            return None
    return _compiled
