"""Sparse LU solves of a whole block of right-hand sides at once (small clouds' hierarchical eigensolver).

On a cloud of a few thousand points the hierarchical eigensolver factors L − σM once and solves it for
p ≈ 150 right-hand sides two or three times. SuperLU (scipy) factors such a matrix faster than CHOLMOD
through cholespy (whose nested-dissection ordering pays off only on large clouds), but SuperLU's own
solve treats the columns one at a time. Its factors are plain sparse triangles, so the two
substitutions here sweep them once for the whole (n, p) block, the p values of a row contiguous in
memory: one compiled loop (numba, the optional ``fast`` extra) that neither scipy nor cholespy offers
for a CPU block. Without numba, or if it fails, :func:`available` is False and the eigensolver keeps
cholespy.

numba compiles the loop on first use (about a second) and keeps the machine code in its cache (beside
this file when the folder is writable, else in a per-user folder).
"""

from __future__ import annotations

import importlib.util
import logging

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
from scipy.linalg.blas import dsyrk

__all__ = ["BlockLU", "available", "disable"]

_log = logging.getLogger(__name__)

_kernel = None  # the compiled substitutions, made on first use
_failure: str | None = None  # why they could not be made or run, once that failed in this process


def available() -> bool:
    """Whether the compiled block solve can be used: numba installed, its JIT enabled, nothing failed."""
    if _failure is not None or importlib.util.find_spec("numba") is None:
        return False
    from numba import config

    return not config.DISABLE_JIT


def disable(reason: str) -> None:
    """Stop using the compiled solve in this process (``reason`` is kept for the log)."""
    global _failure
    _failure = reason
    _log.warning("compiled block solve disabled: %s", reason)


def _forward(up, ui, ux, order, B, row, col, Z):  # pragma: no cover - runs compiled
    """Z ← Uᵀ⁻¹ (diag(row) B diag(col))[order] from the CSC arrays of U (upper triangular): its columns are the rows
    of Uᵀ. Z's dtype sets the arithmetic."""
    n, m = Z.shape
    for i in range(n):
        r = order[i]
        s = row[r]
        for c in range(m):
            Z[i, c] = B[r, c] * s * col[c]
        d = 1.0
        for jj in range(up[i], up[i + 1]):
            j = ui[jj]
            v = ux[jj]
            if j == i:
                d = v
            else:
                for c in range(m):
                    Z[i, c] -= v * Z[j, c]
        inv = 1.0 / d
        for c in range(m):
            Z[i, c] *= inv


def _backward(lp, li, lx, order, Z, X):  # pragma: no cover - runs compiled
    """X[order] ← Lᵀ⁻¹ Z, in place in Z, from the CSC arrays of L (unit lower triangular, its diagonal stored): its
    columns are the rows of Lᵀ."""
    n, m = Z.shape
    for i in range(n - 1, -1, -1):
        for jj in range(lp[i], lp[i + 1]):
            j = li[jj]
            if j != i:
                v = lx[jj]
                for c in range(m):
                    Z[i, c] -= v * Z[j, c]
        r = order[i]
        for c in range(m):
            X[r, c] = Z[i, c]


def _compiled():
    global _kernel
    if _kernel is None:
        from numba import njit

        _log.info("preparing the compiled block solve (numba compiles it once per machine, about a second)")
        _kernel = tuple(njit(cache=True, boundscheck=False)(fn) for fn in (_forward, _backward))
    return _kernel


class BlockLU:
    """SuperLU's factorisation of a symmetric positive definite sparse matrix A, solving (n, p) blocks.

    The ordering is symmetric (minimum degree on Aᵀ + A) and no pivoting is done: A is positive definite,
    so the factorisation works like a sparse Cholesky. The substitutions run over SuperLU's CSC factors as
    they come: Pᵀ L U P = A = Aᵀ = Pᵀ Uᵀ Lᵀ P, and the columns of U and L are the rows of Uᵀ and Lᵀ, so no
    factor is converted or copied. Raises ``RuntimeError`` when the compiled loop is unavailable (see
    :func:`available`).
    """

    def __init__(self, A: sp.spmatrix) -> None:
        if not available():
            raise RuntimeError(_failure or "numba is not installed or its JIT is disabled")
        lu = sla.splu(A if sp.isspmatrix_csc(A) else sp.csc_matrix(A), permc_spec="MMD_AT_PLUS_A",
                      diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        if not np.array_equal(lu.perm_r, lu.perm_c):  # pivoting happened: A is not positive definite
            raise RuntimeError("SuperLU pivoted off the diagonal; the matrix is not positive definite")
        upper, lower = lu.U, lu.L
        self._pivots = upper.diagonal()  # D of A's permuted LDLᵀ = L U (U = D Lᵀ): positive, A being definite
        self._factors = {np.dtype(np.float64): (upper.indptr, upper.indices, upper.data,
                                                lower.indptr, lower.indices, lower.data)}
        # Pr A Pc = L U with Pr = Pc (symmetric mode, no pivoting): row i of the factors is row order[i] of A.
        self._order = np.argsort(lu.perm_r)
        self._work: dict[np.dtype, np.ndarray] = {}  # the permuted block per dtype, kept between solves
        self._gram: np.ndarray | None = None  # √D times the last forward half, when asked for
        self.n = A.shape[0]

    def _arrays(self, dtype: np.dtype) -> tuple:
        if dtype not in self._factors:
            up, ui, ux, lp, li, lx = self._factors[np.dtype(np.float64)]
            self._factors[dtype] = (up, ui, ux.astype(dtype), lp, li, lx.astype(dtype))
        return self._factors[dtype]

    def forward_gram(self) -> np.ndarray:
        """Zᵀ D Z for the forward half Z = Uᵀ⁻¹ b' of the last solve made with ``gram=True`` (b' its scaled,
        permuted right-hand side): with A = Pᵀ L D Lᵀ P (U = D Lᵀ), that is b'ᵀ A⁻¹ b' = Xᵀ A X for the block X
        the solve returned, as an exact Gram matrix (a symmetric rank-k product, half a matrix product)."""
        if self._gram is None:
            raise RuntimeError("forward_gram needs a solve with gram=True first")
        G = dsyrk(1.0, self._gram.T, trans=0, lower=0)  # upper triangle; the transpose is Fortran-ordered
        self._gram = None
        return np.triu(G) + np.triu(G, 1).T

    def solve(self, B: np.ndarray, out: np.ndarray | None = None, row: np.ndarray | None = None,
              col: np.ndarray | None = None, dtype: type = np.float64, gram: bool = False) -> np.ndarray:
        """A⁻¹ diag(row) B diag(col) for a C-ordered (n, p) block B (row, col: scalings, ones when None), written
        into ``out`` when given (same shape; may be B itself when of ``dtype``). ``dtype``: the precision of the
        substitutions and of a new ``out`` (float32 halves the memory traffic, for blocks that only have to span
        the right space). ``gram``: keep what :meth:`forward_gram` needs."""
        n, m = B.shape
        dtype = np.dtype(dtype)
        work = self._work.get(dtype)
        if work is None or work.shape != B.shape:
            work = self._work[dtype] = np.empty((n, m), dtype=dtype)
        X = np.empty((n, m), dtype=dtype) if out is None else out
        row = np.ones(n) if row is None else np.ascontiguousarray(row, dtype=np.float64)
        col = np.ones(m) if col is None else np.ascontiguousarray(col, dtype=np.float64)
        up, ui, ux, lp, li, lx = self._arrays(dtype)
        try:
            forward, backward = _compiled()
            forward(up, ui, ux, self._order, np.ascontiguousarray(B), row, col, work)
            self._gram = np.multiply(work, np.sqrt(self._pivots)[:, None], dtype=np.float64) if gram else None
            backward(lp, li, lx, self._order, work, X)
        except Exception as exc:  # numba's import, typing or compilation
            disable(f"{type(exc).__name__}: {exc}")
            raise RuntimeError(f"compiled block solve failed: {exc}") from exc
        return X
