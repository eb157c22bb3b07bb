"""The n_K smallest pairs of the generalised eigenproblem L φ = λ M φ (TEC eq. 20).

M is diagonal, so the problem is solved in the symmetric standard form A = S L S with
S = M^{-1/2} (A w = λ w, φ = S w); the eigenvectors come out M-orthonormal (Φᵀ M Φ = I).
Small problems go to dense LAPACK; large ones to ARPACK in shift-invert mode around a small
negative shift (A − σI is then positive definite), with our own sparse LU so that the
factorisation is done once with a symmetric fill-reducing ordering. That is the exact reference
(``solver="arpack"``, the authors' method). ``solver="hierarchical"`` is the faster hierarchical
subspace iteration of :mod:`tactex.spectral.hierarchy` for large clouds (it needs the points);
``"auto"`` picks it from ``HIERARCHICAL_MIN_POINTS`` points on (the papers' clouds included).
"""

from __future__ import annotations

import contextlib
import functools

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from tactex.errors import ConfigError, SpectralError
from tactex.spectral.hierarchy import DEFAULT_TOL, HierarchyInfo, hierarchical_eigenpairs

__all__ = [
    "DENSE_MAX_POINTS",
    "EIGENSOLVERS",
    "HIERARCHICAL_MIN_POINTS",
    "check_eigensolver",
    "lanczos_basis_size",
    "laplace_eigenpairs",
    "resolve_eigensolver",
]

#: The eigensolver choices (``--eigensolver``): the exact reference, the hierarchical one, or by size.
EIGENSOLVERS = ("auto", "arpack", "hierarchical")
#: From this many points on, ``auto`` takes the hierarchical solver: from there on it beats the exact path on
#: every cloud it can coarsen (the papers' clouds included; docs/large_surfaces.md), to within ``eigen_tol``.
#: On a cloud too small for a coarse level with the subspace asked for, it falls back to the exact path.
HIERARCHICAL_MIN_POINTS = 1_000

#: Below this many points dense LAPACK beats ARPACK and never fails to converge.
DENSE_MAX_POINTS = 800
#: Largest problem sent to dense LAPACK when n_K is too close to N for ARPACK (N² doubles of memory).
DENSE_LIMIT_POINTS = 4000


@functools.cache
def _blas_controller() -> object | None:
    # Inspecting the loaded libraries costs ~1 ms, more than a small dense solve: done once.
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:  # optional: without it the solver runs with the default thread count
        return None
    return ThreadpoolController()


def _single_threaded_blas() -> contextlib.AbstractContextManager:
    """The solvers' BLAS calls are small (N × ncv mat-vecs, ≤ 800² dense): two OpenBLAS threads gain
    ~10 % on an idle 2-core machine but spin against any other busy process (2–7× slower under load)."""
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

    Whatever ncv, Lanczos needs ≈ 2.3–2.5 k operator applications before the k-th pair converges,
    and a looser tolerance hardly helps (k = 100 on the bunny: 226 applications at tol = 1e-3, 251
    at machine precision; the pairs converge together, late). What ncv sets is the
    orthogonalisation work, O(n ncv²) per sweep, which costs more than the sparse solves. Measured
    on the TEC clouds (1.5k–6k points, k = 100 and 200): ncv ≈ 1.5 k is 5–20 % faster than the
    usual 2 k + 1; 1.25 k restarts too often, 2 k + 1 and more orthogonalise against too many vectors.
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


def check_eigensolver(solver: object, tol: object) -> None:
    """Raise :class:`ConfigError` unless ``solver`` is one of :data:`EIGENSOLVERS` and 0 < ``tol`` < 1."""
    if solver not in EIGENSOLVERS:
        raise ConfigError(f"--eigensolver must be one of {', '.join(EIGENSOLVERS)}, got {solver!r}")
    if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not 0.0 < float(tol) < 1.0:
        raise ConfigError(f"--eigen-tol must be a number in (0, 1), got {tol!r} (default {DEFAULT_TOL:g})")


def resolve_eigensolver(solver: str, n_points: int) -> str:
    """The solver that ``solver`` (one of :data:`EIGENSOLVERS`) means for a cloud of ``n_points``."""
    if solver not in EIGENSOLVERS:
        raise ConfigError(f"--eigensolver must be one of {', '.join(EIGENSOLVERS)}, got {solver!r}")
    if solver == "auto":
        return "hierarchical" if n_points >= HIERARCHICAL_MIN_POINTS else "arpack"
    return solver


def laplace_eigenpairs(
    L: sp.spmatrix,
    M: sp.spmatrix | np.ndarray,
    k: int,
    seed: int = 0,
    *,
    solver: str = "arpack",
    tol: float = DEFAULT_TOL,
    points: np.ndarray | None = None,
    spacing: float | None = None,
    info: HierarchyInfo | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The k smallest eigenpairs of L φ = λ M φ for a diagonal mass matrix M.

    Args:
        L: (N, N) symmetric PSD weak Laplacian.
        M: (N, N) diagonal mass matrix [m²], or its (N,) diagonal.
        k: number of pairs, 1 ≤ k < N.
        seed: start vector of the Krylov iteration (results are reproducible).
        solver: "arpack" (exact), "hierarchical" (needs ``points`` and ``spacing``) or "auto".
        tol: the hierarchical solver's bound on each pair's squared relative residual (≈ relative
            eigenvalue error); ARPACK always runs to machine precision.
        points: (N, 3) positions [m] of the cloud (hierarchical solver only).
        spacing: mean spacing h [m] of the points (hierarchical solver only).
        info: filled by the hierarchical solver with its levels, iterations and timings.

    Returns:
        (evals, evecs): (k,) ascending eigenvalues [1/m²] clipped at 0, (N, k) M-orthonormal vectors.
    """
    mass = np.asarray(M.diagonal() if sp.issparse(M) else M, dtype=np.float64).ravel()
    n = L.shape[0]
    if not 1 <= k < n:
        raise SpectralError(f"n_eigen must satisfy 1 ≤ n_eigen < {n} (the number of points), got {k}")
    solver = resolve_eigensolver(solver, n)
    if solver == "hierarchical":
        if points is None or spacing is None:
            raise ConfigError("the hierarchical eigensolver needs the cloud's points and spacing; "
                              "use --eigensolver arpack for a bare matrix")
        with _single_threaded_blas():
            pairs = hierarchical_eigenpairs(L, mass, k, np.asarray(points, dtype=np.float64), float(spacing),
                                            tol=tol, seed=seed, info=info)
        if pairs is not None:  # None: too few points for a coarser level, the exact path below is as fast
            evals, evecs = pairs
            return _canonical(evals, evecs, None)
    A, s = _symmetric_form(L, mass)
    dense = n <= DENSE_MAX_POINTS or (2 * k + 1 >= n and n <= DENSE_LIMIT_POINTS)
    if not dense and k >= n - 1:
        raise SpectralError(
            f"n_eigen={k} on {n} points is too close to the full spectrum for the sparse solver "
            f"(and too large for a dense one); use n_eigen ≤ {n // 2}"
        )
    with _single_threaded_blas():
        evals, W = _dense(A, k) if dense else _shift_invert(A, k, seed)
    return _canonical(evals, W, s)


def _canonical(evals: np.ndarray, W: np.ndarray, s: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
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
