"""The HEDAC source term and its spectral image Φᵀ M s, updated from what changed (TEC eq. 1–2, 19).

On the T target rows, s_r = max(p_r − c_r/n, 0)² / Σ s, with p the normalised target, c the coverage
and n its normaliser (eq. 1–2). Every c_r/n moves whenever n does, so s changes everywhere each step;
but on the rows where s_r > 0 ("active") the square expands into three fixed-row sums,

    Φᵀ M s = (S_pp − 2 S_pc / n + S_cc / n²) / Σ s,   S_pp = Σ_active p² φ_r, S_pc = Σ_active p c φ_r,
                                                       S_cc = Σ_active c² φ_r   (φ_r: row r of Φᵀ M),

and a row's terms change only when its coverage changes (the footprint) or it enters or leaves the
active set: n never decreases, so a row leaves only under the footprint and re-enters at most once
per leave. The K-vector work per step is therefore O((footprint + entries) · K) instead of O(T · K);
the scalar pass that finds them, forms Σ s and the source values the gradient reads is O(T), about
1 ns a row compiled. The sums carry round-off from every update; the explorer rebuilds them from
scratch every ``REBUILD_STEPS`` steps (tests compare against the direct sum).

:func:`update_source` is the loop form (compiled with the explorer's step, :mod:`.compiled_step`);
:func:`update_source_numpy` the vectorised one for the numpy step. Both leave the same state.
"""

from __future__ import annotations

import numpy as np

__all__ = ["REBUILD_STEPS", "SourceSums", "update_source", "update_source_numpy"]

#: Steps between rebuilds of the running sums from scratch (bounds their accumulated round-off).
REBUILD_STEPS = 2000


class SourceSums:
    """The running state of the source's spectral image for T target rows and K modes.

    Attributes:
        sums: (3, K) S_pp, S_pc, S_cc.
        c_used: (T,) the coverage each row's terms in ``sums`` were formed with.
        active: (T,) uint8, 1 where the row's terms are in ``sums``.
    """

    def __init__(self, n_rows: int, n_modes: int) -> None:
        self.sums = np.zeros((3, n_modes))
        self.c_used = np.zeros(n_rows)
        self.active = np.zeros(n_rows, dtype=np.uint8)

    def clear(self) -> None:
        """Forget every row: the next update rebuilds the sums from all of them (O(T K) once)."""
        self.sums[:] = 0.0
        self.active[:] = 0


def update_source(cov, tidx, p_t, norm, s_ext, c_used, active, sums, phitm_t, dcoef):
    """Source on the target rows into s_ext[:T] (unit sum) and its image Φᵀ M s into dcoef (K,).

    Args:
        cov: (N,) coverage c̃. tidx: (T,) target rows' cloud indices. p_t: (T,) normalised target.
        norm: the coverage normaliser n (> 0, or 0 before any coverage).
        s_ext: (T + 1,) source, written. c_used, active, sums: :class:`SourceSums`' arrays, updated.
        phitm_t: (T, K) rows of Φᵀ M on the target. dcoef: (K,) written.

    Returns:
        Σ s before normalisation (0: no source anywhere, dcoef is then 0).
    """
    T = tidx.shape[0]
    K = dcoef.shape[0]
    inv_n = 1.0 / norm if norm > 0.0 else 0.0
    tot = 0.0
    for r in range(T):
        c = cov[tidx[r]]
        p = p_t[r]
        z = p - c * inv_n
        now = 1 if z > 0.0 else 0
        s = z * z if now == 1 else 0.0
        s_ext[r] = s
        tot += s
        was = active[r]
        if now != was or (now == 1 and c != c_used[r]):
            a_pp = 0.0
            a_pc = 0.0
            a_cc = 0.0
            if was == 1:
                co = c_used[r]
                a_pp -= p * p
                a_pc -= p * co
                a_cc -= co * co
            if now == 1:
                a_pp += p * p
                a_pc += p * c
                a_cc += c * c
            for k in range(K):
                f = phitm_t[r, k]
                sums[0, k] += a_pp * f
                sums[1, k] += a_pc * f
                sums[2, k] += a_cc * f
            active[r] = now
            c_used[r] = c
    if tot > 0.0:
        ti = 1.0 / tot
        for r in range(T):
            s_ext[r] *= ti
        w1 = -2.0 * inv_n * ti
        w2 = inv_n * inv_n * ti
        for k in range(K):
            dcoef[k] = sums[0, k] * ti + sums[1, k] * w1 + sums[2, k] * w2
    else:
        for k in range(K):
            dcoef[k] = 0.0
    return tot


def update_source_numpy(cov, tidx, p_t, norm, s_t, state: SourceSums, phitm_t) -> np.ndarray:
    """:func:`update_source` vectorised: fills s_t (T,) and returns Φᵀ M s (K,)."""
    ct = cov.take(tidx)
    inv_n = 1.0 / norm if norm > 0.0 else 0.0
    np.multiply(ct, -inv_n, s_t)
    s_t += p_t
    now = s_t > 0.0
    np.maximum(s_t, 0.0, out=s_t)
    s_t *= s_t
    was = state.active.view(bool)
    changed = now != was
    changed |= now & (ct != state.c_used)
    rows = changed.nonzero()[0]
    if rows.size:
        p = p_t.take(rows)
        n_r = now.take(rows)
        w_r = was.take(rows)
        c_new = ct.take(rows) * n_r
        c_old = state.c_used.take(rows) * w_r
        coeff = np.empty((3, rows.size))
        coeff[0] = p * p * (n_r.astype(np.float64) - w_r)
        coeff[1] = p * (c_new - c_old)
        coeff[2] = c_new * c_new - c_old * c_old
        state.sums += coeff @ phitm_t.take(rows, 0)
        state.active[rows] = n_r
        state.c_used[rows] = ct.take(rows)
    tot = float(np.add.reduce(s_t))
    if tot <= 0.0:
        return np.zeros(phitm_t.shape[1])
    s_t *= 1.0 / tot
    return (state.sums[0] - (2.0 * inv_n) * state.sums[1] + (inv_n * inv_n) * state.sums[2]) * (1.0 / tot)
