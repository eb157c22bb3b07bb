"""Sparse LDLᵀ solves of a whole block of right-hand sides at once (small clouds' hierarchical eigensolver).

On a cloud of a few thousand points the hierarchical eigensolver factors L − σM once and solves it for
p ≈ 150 right-hand sides two or three times. QDLDL (``qdldl``, the OSQP project's LDLᵀ with SuiteSparse's
AMD ordering) factors such a matrix faster than SuperLU with its minimum-degree ordering, and
much faster than CHOLMOD through cholespy (whose nested-dissection route pays off only on large clouds),
and it hands its factors over. Neither it nor scipy nor cholespy solves a block of right-hand sides in one
sweep on a CPU, so the two substitutions here sweep the factor once for the whole (n, p) block, the p values
of a row contiguous in memory: one compiled loop each (numba). Both come with the optional ``fast`` extra.
Without them, or if they fail, :func:`available` is False and the eigensolver keeps cholespy.

numba compiles the loops on first use (about a second) and keeps the machine code in its cache (beside
this file when the folder is writable, else in a per-user folder).
"""

from __future__ import annotations

import importlib.util
import logging

import numpy as np
import scipy.sparse as sp
from scipy.linalg.blas import dsyrk

__all__ = ["BlockLU", "available", "disable", "product_norms2"]

_log = logging.getLogger(__name__)

_kernel = None  # the compiled substitutions, made on first use
_failure: str | None = None  # why they could not be made or run, once that failed in this process


def available() -> bool:
    """Whether the compiled block solve can be used: numba and qdldl installed, numba's JIT enabled, nothing
    failed."""
    if _failure is not None or importlib.util.find_spec("numba") is None or importlib.util.find_spec("qdldl") is None:
        return False
    from numba import config

    return not config.DISABLE_JIT


def disable(reason: str) -> None:
    """Stop using the compiled solve in this process (``reason`` is kept for the log)."""
    global _failure
    _failure = reason
    _log.warning("compiled block solve disabled: %s", reason)


def _forward(rp, ri, rx, scale, order, B, row, col, Z):  # pragma: no cover - runs compiled
    """Z ← diag(scale) (I + L)⁻¹ (diag(row) B diag(col))[order] with L strictly lower triangular, from the CSR
    arrays of L diag(1/scale) (its rows, each value divided by its column's scale, since Z's rows are stored
    scaled). Z's dtype sets the arithmetic; each row is summed in a separate buffer (no aliasing with the rows
    it reads, so the loops vectorise without checks)."""
    n, m = Z.shape
    acc = np.empty(m, dtype=Z.dtype)
    for i in range(n):
        r = order[i]
        s = row[r]
        b = B[r]
        for c in range(m):
            acc[c] = b[c] * s * col[c]
        for jj in range(rp[i], rp[i + 1]):
            v = rx[jj]
            z = Z[ri[jj]]
            for c in range(m):
                acc[c] -= v * z[c]
        t = scale[i]
        z = Z[i]
        for c in range(m):
            z[c] = acc[c] * t


def _backward(cp, ci, cx, scale, order, Z, X):  # pragma: no cover - runs compiled
    """X[order] ← (I + L)ᵀ⁻¹ diag(scale) Z, in place in Z, from the CSC arrays of L (strictly lower triangular):
    its columns are the rows of Lᵀ."""
    n, m = Z.shape
    acc = np.empty(m, dtype=Z.dtype)
    for i in range(n - 1, -1, -1):
        t = scale[i]
        z = Z[i]
        for c in range(m):
            acc[c] = z[c] * t
        for jj in range(cp[i], cp[i + 1]):
            v = cx[jj]
            y = Z[ci[jj]]
            for c in range(m):
                acc[c] -= v * y[c]
        x = X[order[i]]
        for c in range(m):
            z[c] = acc[c]
            x[c] = acc[c]


def _product_norms2(ap, ai, ax, X, w, out):  # pragma: no cover - runs compiled
    """out[c] ← Σ_i w_i (A X)_{ic}² from the CSR arrays of A, one row of A X at a time."""
    n, m = X.shape
    r = np.zeros(m)
    for c in range(m):
        out[c] = 0.0
    for i in range(n):
        for c in range(m):
            r[c] = 0.0
        for jj in range(ap[i], ap[i + 1]):
            j = ai[jj]
            v = ax[jj]
            for c in range(m):
                r[c] += v * X[j, c]
        s = w[i]
        for c in range(m):
            out[c] += s * r[c] * r[c]


def _compiled():
    global _kernel
    if _kernel is None:
        from numba import njit

        _log.info("preparing the compiled block solve (numba compiles it once per machine, about a second)")
        _kernel = tuple(njit(cache=True, boundscheck=False)(fn) for fn in (_forward, _backward, _product_norms2))
    return _kernel


def product_norms2(A: sp.csr_matrix, X: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(m,) Σ_i w_i (A X)_{ic}² for a CSR matrix A and a C-ordered (n, m) block X, without forming A X (an (n, m)
    temporary whose first touch costs as much as the product on a small cloud). Raises ``RuntimeError`` when the
    compiled loops are unavailable or fail (see :func:`available`)."""
    if not available():
        raise RuntimeError(_failure or "numba or qdldl is not installed, or numba's JIT is disabled")
    out = np.empty(X.shape[1])
    try:
        _compiled()[2](A.indptr, A.indices, A.data, np.ascontiguousarray(X, dtype=np.float64),
                       np.ascontiguousarray(w, dtype=np.float64), out)
    except Exception as exc:  # numba's import, typing or compilation
        disable(f"{type(exc).__name__}: {exc}")
        raise RuntimeError(f"compiled block product failed: {exc}") from exc
    return out


def _upper_csc(A: sp.csc_matrix) -> sp.csc_matrix:
    """The upper triangle (diagonal included) of a CSC matrix, from its arrays (cheaper than ``sp.triu``)."""
    n = A.shape[0]
    cols = np.repeat(np.arange(n, dtype=A.indices.dtype), np.diff(A.indptr))
    keep = A.indices <= cols
    indptr = np.zeros(n + 1, dtype=A.indptr.dtype)
    np.cumsum(np.bincount(cols[keep], minlength=n), out=indptr[1:])
    return sp.csc_matrix((A.data[keep], A.indices[keep], indptr), shape=A.shape)


class BlockLU:
    """The LDLᵀ factorisation of a symmetric positive definite sparse matrix A, solving (n, p) blocks.

    QDLDL factors Pᵀ A P = (I + L) D (I + L)ᵀ after an AMD ordering P. A is positive definite, so D > 0 and the
    substitutions work on the factor scaled as a Cholesky factor (I + L) D^{1/2}: the forward half Z of a solve
    is then an exact square root of the projected matrix (:meth:`forward_gram`). Raises ``RuntimeError`` when
    the compiled loops are unavailable (see :func:`available`) or A is not positive definite.
    """

    def __init__(self, A: sp.spmatrix) -> None:
        if not available():
            raise RuntimeError(_failure or "numba or qdldl is not installed, or numba's JIT is disabled")
        import qdldl

        A = A if sp.isspmatrix_csc(A) else sp.csc_matrix(A)
        try:
            lower, d, perm = qdldl.Solver(_upper_csc(A), upper=True).factors()
        except Exception as exc:  # QDLDL stops at a zero pivot
            raise RuntimeError(f"the LDLᵀ factorisation failed ({exc}); the matrix is not positive definite") from exc
        d = np.asarray(d, dtype=np.float64)
        if not (np.all(d > 0.0) and np.all(np.isfinite(d))):
            raise RuntimeError("the LDLᵀ factorisation has a pivot ≤ 0; the matrix is not positive definite")
        lower = sp.csc_matrix(lower)
        inv_root = 1.0 / np.sqrt(d)
        rows = lower.tocsr()
        # Forward over the rows of L (each value times its column's √d, as the rows of Z are stored scaled);
        # backward over its columns.
        self._factors = {np.dtype(np.float64): (rows.indptr, rows.indices, rows.data / inv_root[rows.indices],
                                                lower.indptr, lower.indices, lower.data, inv_root)}
        self._order = np.asarray(perm, dtype=np.int64)  # row i of the factors is row order[i] of A
        # The permuted block, kept between solves: one buffer sized for double, whose first half a single-precision
        # solve uses (a new block's first touch costs about as much as a solve at this size).
        self._work: np.ndarray | None = None
        self._gram: np.ndarray | None = None  # the last forward half's Gram matrix, when asked for
        self.n = A.shape[0]

    def _arrays(self, dtype: np.dtype) -> tuple:
        if dtype not in self._factors:
            rp, ri, rx, cp, ci, cx, s = self._factors[np.dtype(np.float64)]
            self._factors[dtype] = (rp, ri, rx.astype(dtype), cp, ci, cx.astype(dtype), s.astype(dtype))
        return self._factors[dtype]

    def forward_gram(self) -> np.ndarray:
        """Zᵀ Z for the forward half Z = D^{-1/2} (I + L)⁻¹ b' of the last solve made with ``gram=True`` (b' its
        scaled, permuted right-hand side): with Pᵀ A P = (I + L) D (I + L)ᵀ, that is b'ᵀ A⁻¹ b' = Xᵀ A X for the
        block X the solve returned, as an exact Gram matrix (a symmetric rank-k product, half a matrix product)."""
        if self._gram is None:
            raise RuntimeError("forward_gram needs a solve with gram=True first")
        G, self._gram = self._gram, None
        return G

    def solve(self, B: np.ndarray, out: np.ndarray | None = None, row: np.ndarray | None = None,
              col: np.ndarray | None = None, dtype: type = np.float64, gram: bool = False) -> np.ndarray:
        """A⁻¹ diag(row) B diag(col) for a C-ordered (n, p) block B (row, col: scalings, ones when None), written
        into ``out`` when given (same shape; may be B itself when of ``dtype``). ``dtype``: the precision of the
        substitutions and of a new ``out`` (float32 halves the memory traffic, for blocks that only have to span
        the right space). ``gram``: keep what :meth:`forward_gram` needs."""
        n, m = B.shape
        dtype = np.dtype(dtype)
        if self._work is None or self._work.shape[0] < n * m:
            self._work = np.empty(n * m)
        work = self._work.view(dtype)[: n * m].reshape(n, m)
        X = np.empty((n, m), dtype=dtype) if out is None else out
        row = np.ones(n) if row is None else np.ascontiguousarray(row, dtype=np.float64)
        col = np.ones(m) if col is None else np.ascontiguousarray(col, dtype=np.float64)
        rp, ri, rx, cp, ci, cx, inv_root = self._arrays(dtype)
        try:
            forward, backward, _ = _compiled()
            forward(rp, ri, rx, inv_root, self._order, np.ascontiguousarray(B), row, col, work)
            if gram:
                # The upper triangle of Zᵀ Z (Z.T is Fortran-ordered), mirrored; in double whatever the solve's dtype.
                G = dsyrk(1.0, work.T if work.dtype == np.float64 else work.T.astype(np.float64), trans=0, lower=0)
                self._gram = np.triu(G) + np.triu(G, 1).T
            else:
                self._gram = None
            backward(cp, ci, cx, inv_root, self._order, work, X)
        except Exception as exc:  # numba's import, typing or compilation
            disable(f"{type(exc).__name__}: {exc}")
            raise RuntimeError(f"compiled block solve failed: {exc}") from exc
        return X
