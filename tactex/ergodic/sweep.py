"""The sweep source: HEDAC's source term for targets where every point must be passed over once.

Eq. 1–2 match a distribution: a point keeps a source until its coverage reaches its share of the
total. With the whole surface as the target (sanding, polishing, inspection) the goal is different:
every point inside a footprint once, the shortest way. Two things waste path there with eq. 1–2:
strokes laid about a footprint width apart leave slivers and single points just beyond r_a between
them, each costing a later pass; and the potential, smooth over several footprints, pulls the agent
across the middle of the open region instead of along the edge of what it has covered, cutting the
rest into islands.

The sweep source instead puts, on every target point not yet *done*,

    s_r = p_r · (base + (1 − base) · f_r),   f_r = share of the target points within ``frontier_radius``
                                                   of r that are done (or missing: the cloud's edge),

scaled to unit sum, and 0 on done points. "Done" uses a planning footprint narrower than the real
one (``plan_ratio`` · r_a): a point the footprint only grazed keeps its source, so the next stroke
overlaps the last a little instead of leaving single points between them. The frontier share f_r
makes the open target next to covered ground (and to the cloud's edge) weigh most: the agent works
along the edge of the covered region, and coverage grows in passes, like a spiral, rather than in
scattered strokes. The sum s is normalised over what is left, so the last specks draw the agent
as strongly as the first open field did.

The frontier share is kept incrementally: when a point becomes done, the done-counts of the target
points around it go up by one (a sparse row), so a step costs O(new points · neighbours). On a target
of up to ``INCREMENTAL_POINTS`` points the spectral image Φᵀ M s is formed in full (O(T K)) each step;
on a larger one (100k points: 10–40 ms a step) the unnormalised weights, their sum and their image are
kept as running sums updated on the rows whose weight changed (the new points and their neighbours),
rebuilt from scratch every ``source.REBUILD_STEPS`` steps, and s is their quotient: the same source to
round-off.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree

from tactex.ergodic.setup_progress import in_chunks

__all__ = ["INCREMENTAL_POINTS", "SweepSource", "uniform_whole_target"]

#: A target of more points than this keeps the sweep source's spectral image as running sums [-].
INCREMENTAL_POINTS = 20_000


def sweeps(source_mode: str, target: np.ndarray, keep_out: np.ndarray | None = None) -> bool:
    """Whether an explorer with ``source_mode`` ("auto", "sweep", "ergodic") uses the sweep source on ``target`` (N,)
    outside ``keep_out`` (N,) (bool, or None)."""
    return source_mode == "sweep" or (source_mode == "auto" and uniform_whole_target(target, keep_out))


def uniform_whole_target(target: np.ndarray, keep_out: np.ndarray | None = None) -> bool:
    """True when the target puts the same mass on every cloud point outside ``keep_out`` (N,) (bool: the
    zone and the band the footprint may not stand in; a whole-surface target, ``--target all``): the case
    ``source_mode = "auto"`` sweeps."""
    t = np.asarray(target, dtype=np.float64)
    if keep_out is not None and keep_out.any():
        t = t[~keep_out]
    return bool(t.size > 0 and t.min() > 0.0 and t.max() == t.min())


class SweepSource:
    """The sweep source on the target points.

    Args:
        points: target points (T, 3) [m].
        p: their normalised target mass (T,).
        plan_radius_m: radius of the planning footprint [m]: a point is done once an agent point came
            this close.
        frontier_radius_m: radius of the neighbourhood of the frontier share [m].
        base: weight of a target point with no done neighbour, relative to one surrounded by done ones
            (in (0, 1]: 1 = no frontier preference).
        image_rows: the rows (T, K) of Φᵀ M on the target points, or None; with them, ``image`` gives the source's
            spectral image, kept as running sums on a target of over ``INCREMENTAL_POINTS`` points.
        progress: called with one-line messages while a large target's neighbourhoods are taken, or None.
    """

    def __init__(self, points: np.ndarray, p: np.ndarray, plan_radius_m: float, frontier_radius_m: float,
                 base: float, image_rows: np.ndarray | None = None, progress=None) -> None:
        self._tree = cKDTree(points)
        self._p = np.asarray(p, dtype=np.float64)
        self.plan_radius_m = float(plan_radius_m)
        self.base = float(base)
        balls: list = []

        def chunk(lo: int, hi: int) -> None:
            balls.extend(self._tree.query_ball_point(points[lo:hi], frontier_radius_m, return_sorted=True))
        in_chunks(len(points), chunk, progress, "explorer: the sweep's neighbourhoods")
        sizes = np.array([len(b) for b in balls])
        rows = np.repeat(np.arange(len(points)), sizes)
        cols = np.concatenate(balls).astype(np.intp) if len(balls) else np.zeros(0, dtype=np.intp)
        self._near = csr_matrix((np.ones(rows.size), (rows, cols)), shape=(len(points), len(points)))
        # The full neighbourhood of an inner point: fewer neighbours (the cloud's edge) count as done.
        self._full = float(sizes.max()) if sizes.size else 1.0
        self._missing = self._full - sizes
        self._rows = image_rows
        self.incremental = image_rows is not None and len(points) > INCREMENTAL_POINTS
        self.reset()

    def reset(self) -> None:
        """Nothing done yet."""
        self.done = np.zeros(self._p.size, dtype=bool)
        self._open = self._p.size  # points not done
        self._all_done = self._open == 0
        self._done_near = self._missing.astype(np.float64)
        if self.incremental:
            self._dirty: list[np.ndarray] = []  # rows marked since the last image (see _flush)
            self._w_ext = np.zeros(self._p.size + 1)  # with a trailing 0: w_ext[t] is 0 off the target (t = −1)
            self._w = self._w_ext[:-1]
            self._w[:] = self._weights(np.arange(self._p.size))
            self.rebuild()

    def rebuild(self) -> None:
        """The running sums (incremental mode) from scratch: their round-off does not build up."""
        if self.incremental:
            self._flush()
            self._tot = float(self._w.sum())
            self._image = self._w.dot(self._rows)
            self._inv = 1.0 / self._tot if self._tot > 0.0 else 0.0

    def _weights(self, rows: np.ndarray) -> np.ndarray:
        """The unnormalised source on the target rows ``rows`` (the arithmetic of :meth:`source`)."""
        f = self._done_near[rows] * (1.0 / self._full)
        np.minimum(f, 1.0, out=f)
        f *= 1.0 - self.base
        f += self.base
        f *= self._p[rows]
        f[self.done[rows]] = 0.0
        return f

    def mark(self, x: np.ndarray) -> None:
        """Target points within the planning radius of the agent point x (3,) [m] are done."""
        idx = np.asarray(self._tree.query_ball_point(x, self.plan_radius_m), dtype=np.intp)
        if idx.size == 0:
            return
        new = idx[~self.done[idx]]
        if new.size == 0:
            return
        self.done[new] = True
        self._open -= new.size
        self._all_done = self._open == 0
        # the rows of the new points are their neighbourhoods (the relation is symmetric); each neighbour's count
        # goes up by one per new point next to it
        ptr, cols = self._near.indptr, self._near.indices
        near = np.concatenate([cols[ptr[r]:ptr[r + 1]] for r in new.tolist()])
        np.add.at(self._done_near, near, 1.0)
        if self.incremental:
            self._dirty.append(new)
            self._dirty.append(near)

    def _flush(self) -> None:
        """The running sums brought up to the marks since the last image: the rows whose weight changed (the new
        points and their neighbours). Until then :meth:`at` reads the source of the last image, as the full
        source in ``out`` is."""
        if self._dirty:
            rows = np.unique(np.concatenate(self._dirty))
            self._dirty.clear()
            w = self._weights(rows)
            dw = w - self._w[rows]
            self._w[rows] = w
            self._tot += float(dw.sum())
            self._image += dw.dot(self._rows[rows])

    def image(self, out: np.ndarray) -> np.ndarray:
        """The spectral image Φᵀ M s (K,) of the source (zero when all is done; needs ``image_rows``), and without
        running sums the source itself (T,) into ``out`` (scaled to unit sum, see :meth:`source`); with them, read
        the source with :meth:`at` (writing all T values each step would cost more than the step)."""
        if not self.incremental:
            return out.dot(self._rows) if self.source(out) > 0.0 else np.zeros(self._rows.shape[1])
        self._flush()
        # all done: the sum's round-off is no source (the full path's sum is exactly 0 there)
        self._inv = 1.0 / self._tot if self._tot > 0.0 and not self._all_done else 0.0
        return self._image * self._inv

    def at(self, t: np.ndarray) -> np.ndarray:
        """With running sums: the source (scaled to unit sum as of the last :meth:`image`) at target rows ``t`` (−1:
        off the target, 0 there)."""
        return self._w_ext.take(t) * self._inv

    def source(self, out: np.ndarray) -> float:
        """The source (T,) into ``out``, scaled to unit sum; returns the sum before scaling (0: all done)."""
        f = self._done_near * (1.0 / self._full)
        np.minimum(f, 1.0, out=f)
        np.multiply(f, 1.0 - self.base, out=out)
        out += self.base
        out *= self._p
        out[self.done] = 0.0
        tot = float(out.sum())
        if tot > 0.0:
            out *= 1.0 / tot
        return tot
