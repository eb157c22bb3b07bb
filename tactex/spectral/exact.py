"""The exact eigensolver of L φ = λ M φ (TEC eq. 20) for a diagonal M: the reference the
hierarchical solver is measured against, and the solve of its coarsest level.

M is diagonal, so the problem is solved in the symmetric standard form A = S L S with
S = M^{-1/2} (A w = λ w, φ = S w); the eigenvectors come out M-orthonormal (Φᵀ M Φ = I).
Small problems go to dense LAPACK; large ones to ARPACK in shift-invert mode around a small
negative shift (A − σI is then positive definite), with our own sparse LU so that the
factorisation is done once with a symmetric fill-reducing ordering (the authors' method).
"""

from __future__ import annotations

import contextlib
import functools

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from tactex.errors import SpectralError

__all__ = [
    "DENSE_LIMIT_POINTS",
    "DENSE_MAX_POINTS",
    "canonical_pairs",
    "check_pair_count",
    "exact_eigenpairs",
    "lanczos_basis_size",
    "single_threaded_blas",
]

#: Below this many points dense LAPACK beats ARPACK and never fails to converge.
DENSE_MAX_POINTS = 800
#: Largest problem sent to dense LAPACK when n_K is too close to N for ARPACK (N² doubles of memory).
DENSE_LIMIT_POINTS = 4000


@functools.cache
def _blas_controller() -> object | None:
    # Inspecting the loaded libraries can cost more than a small dense solve: done once per process.
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:  # optional: without it the solver runs with the default thread count
        return None
    return ThreadpoolController()


def single_threaded_blas() -> contextlib.AbstractContextManager:
    """The solvers' BLAS calls are small (N × ncv mat-vecs, small dense blocks): a second OpenBLAS
    thread gains little on an idle machine and spins against any other busy process, which makes
    the solve several times slower under load."""
    controller = _blas_controller()
    if controller is None:
        return contextlib.nullcontext()
    return controller.limit(limits=1, user_api="blas")


def _symmetric_form(L: sp.spmatrix, mass: np.ndarray) -> tuple[sp.csc_matrix, np.ndarray]:
    s = 1.0 / np.sqrt(mass)
    A = sp.csc_matrix(L.multiply(s[:, None]).multiply(s[None, :]))
    # Round-off of the scaling breaks exact symmetry; ARPACK's Lanczos assumes it.
    A = (A + A.T) * 0.5
    return sp.csc_matrix(A), s


def _dense(A: sp.spmatrix, k: int) -> tuple[np.ndarray, np.ndarray]:
    evals, W = la.eigh(A.toarray(), subset_by_index=[0, k - 1])
    return evals, W


def lanczos_basis_size(k: int, n: int) -> int:
    """ARPACK's Krylov basis size ncv for k pairs of an n × n problem (k < ncv ≤ n).

    Whatever ncv, Lanczos needs about 2.5 k operator applications before the k-th pair converges,
    and a looser tolerance hardly helps (the pairs converge together, late). What ncv sets is the
    orthogonalisation work, O(n ncv²) per sweep, which costs more than the sparse solves: ncv ≈ 1.5 k
    balances it against the implicit restarts, which multiply as ncv approaches k; the usual
    2 k + 1 orthogonalises against more vectors than the convergence needs.
    """
    return min(n, max(int(1.5 * k) + 1, 20))


def _shift_invert(A: sp.csc_matrix, k: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    n = A.shape[0]
    # A shift far below λ_2 yet large against round-off keeps A − σI well conditioned.
    sigma = -1e-6 * float(np.mean(A.diagonal()))
    # A − σI is symmetric positive definite: no pivoting is needed, so a symmetric minimum-degree
    # ordering kept on the diagonal works like a sparse Cholesky (⅓ less fill, faster solves than COLAMD).
    lu = sla.splu(
        sp.csc_matrix(A - sigma * sp.identity(n, format="csc")),
        permc_spec="MMD_AT_PLUS_A",
        diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )
    op = sla.LinearOperator(A.shape, matvec=lu.solve, dtype=np.float64)
    v0 = np.random.default_rng(seed).standard_normal(n)
    ncv = lanczos_basis_size(k, n)
    try:
        evals, W = sla.eigsh(A, k, sigma=sigma, OPinv=op, which="LM", v0=v0, ncv=ncv)
    except sla.ArpackNoConvergence as exc:
        raise SpectralError(
            f"the eigensolver did not converge for n_eigen={k} on {n} points ({exc}); "
            "try a smaller n_eigen or check the cloud for disconnected fragments"
        ) from exc
    return evals, W


def check_pair_count(k: int, n: int) -> None:
    """Raise :class:`SpectralError` unless 1 ≤ ``k`` < ``n`` (the number of points)."""
    if not 1 <= k < n:
        raise SpectralError(f"n_eigen must satisfy 1 ≤ n_eigen < {n} (the number of points), got {k}")


def exact_eigenpairs(L: sp.spmatrix, mass: np.ndarray, k: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The k smallest pairs of L φ = λ M φ, M = diag(``mass``), to machine precision.

    Args:
        L: (N, N) symmetric PSD weak Laplacian.
        mass: (N,) lumped mass [m²].
        k: number of pairs, 1 ≤ k < N.
        seed: start vector of the Krylov iteration (results are reproducible).

    Returns:
        (evals, evecs): (k,) ascending eigenvalues [1/m²] clipped at 0, (N, k) M-orthonormal vectors.
    """
    n = L.shape[0]
    check_pair_count(k, n)
    A, s = _symmetric_form(L, mass)
    dense = n <= DENSE_MAX_POINTS or (2 * k + 1 >= n and n <= DENSE_LIMIT_POINTS)
    if not dense and k >= n - 1:
        raise SpectralError(
            f"n_eigen={k} on {n} points is too close to the full spectrum for the sparse solver "
            f"(and too large for a dense one); use n_eigen ≤ {n // 2}"
        )
    with single_threaded_blas():
        evals, W = _dense(A, k) if dense else _shift_invert(A, k, seed)
    return canonical_pairs(evals, W, s)


def canonical_pairs(evals: np.ndarray, W: np.ndarray, s: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Ascending pairs, φ = s ⊙ w (s None: φ = w), the largest-magnitude entry of each vector positive
    (reproducible output), eigenvalues clipped at 0 (the null space comes out at ±1e-12; L is PSD).

    W is the solver's own array and is scaled in place: on large clouds an (N, K) copy is tens of
    megabytes, whose first touch is not free.
    """
    order = np.argsort(evals, kind="stable")
    evals = evals[order]
    W = np.ascontiguousarray(W if np.array_equal(order, np.arange(order.size)) else W[:, order])
    top, bottom = W.max(axis=0), -W.min(axis=0)
    flip = np.where(top > bottom, 1.0, -1.0)
    tied = np.flatnonzero(top == bottom)
    if tied.size:  # the sign of the first entry of largest magnitude (argmax/argmin return first occurrences)
        flip[tied] = np.where(W[:, tied].argmax(axis=0) <= W[:, tied].argmin(axis=0), 1.0, -1.0)
    W *= flip[None, :]
    if s is not None:
        W *= s[:, None]
    return np.clip(evals, 0.0, None), W
