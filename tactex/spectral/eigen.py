"""The n_K smallest pairs of the generalised eigenproblem L φ = λ M φ (TEC eq. 20), by the solver
the user picks: the exact reference (``solver="arpack"``, :mod:`tactex.spectral.exact`, the
authors' method) or the faster hierarchical subspace iteration of :mod:`tactex.spectral.hierarchy`
for large clouds (it needs the points); ``"auto"`` picks it from ``HIERARCHICAL_MIN_POINTS``
points on (the papers' clouds included).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp

from tactex.errors import ConfigError
from tactex.spectral.exact import canonical_pairs, check_pair_count, exact_eigenpairs, single_threaded_blas
from tactex.spectral.hierarchy import DEFAULT_TOL, HierarchyInfo, hierarchical_eigenpairs

__all__ = [
    "EIGENSOLVERS",
    "HIERARCHICAL_MIN_POINTS",
    "check_eigensolver",
    "laplace_eigenpairs",
    "resolve_eigensolver",
]

#: The eigensolver choices (``--eigensolver``): the exact reference, the hierarchical one, or by size.
EIGENSOLVERS = ("auto", "arpack", "hierarchical")
#: From this many points on, ``auto`` takes the hierarchical solver: from there on it beats the exact path on
#: every cloud it can coarsen (the papers' clouds included; docs/large_surfaces.md), to within ``eigen_tol``.
#: On a cloud too small for a coarse level with the subspace asked for, it falls back to the exact path.
HIERARCHICAL_MIN_POINTS = 1_000


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
    progress: Callable[[str], None] | None = None,
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
        progress: called with one-line messages during the hierarchical solve (levels, iterations).

    Returns:
        (evals, evecs): (k,) ascending eigenvalues [1/m²] clipped at 0, (N, k) M-orthonormal vectors.
    """
    mass = np.asarray(M.diagonal() if sp.issparse(M) else M, dtype=np.float64).ravel()
    n = L.shape[0]
    check_pair_count(k, n)
    solver = resolve_eigensolver(solver, n)
    if solver == "hierarchical":
        if points is None or spacing is None:
            raise ConfigError("the hierarchical eigensolver needs the cloud's points and spacing; "
                              "use --eigensolver arpack for a bare matrix")
        with single_threaded_blas():
            pairs = hierarchical_eigenpairs(L, mass, k, np.asarray(points, dtype=np.float64), float(spacing),
                                            tol=tol, seed=seed, info=info, progress=progress)
        if pairs is not None:  # None: too few points for a coarser level, the exact path below is as fast
            evals, evecs = pairs
            return canonical_pairs(evals, evecs, None)
    return exact_eigenpairs(L, mass, k, seed)
