"""Hierarchical subspace iteration for the low spectrum of L φ = λ M φ on large clouds.

After Nasikun & Hildebrandt, "The Hierarchical Subspace Iteration Method for Laplace–Beltrami
Eigenproblems" (ACM TOG 2022): a hierarchy of nested function spaces, the eigenproblem solved
exactly on the coarsest, then refined from coarse to fine by shift-invert subspace iterations
with a sparse Cholesky factorisation on each level. Here:

- levels: the cloud voxelised at edges v_c/2^j (one representative point per voxel, the point
  nearest the voxel's centroid, so the levels are nested subsets), where the coarsest edge v_c leaves
  ``COARSE_POINTS_PER_VECTOR`` points per subspace vector and the finest is at least 1.5 h;
- prolongation P from a level to the next finer one: inverse-square-distance weights of the 4
  nearest coarse points (rows sum to 1, so constants are kept; a point that is itself a coarse
  point takes its own value). The coarse operators are Galerkin products Pᵀ L P and Pᵀ M P, so
  every level's space is a subspace of the finer one's;
- the coarsest problem (about two thousand points) is solved exactly, by dense LAPACK up to
  ``COARSE_DENSE_MAX_POINTS``;
- on each finer level one block iteration Y = (L − σM)⁻¹ M X (Θ − σ), all p right-hand sides in
  one sparse-Cholesky solve (cholespy, i.e. CHOLMOD), then Rayleigh–Ritz on span Y. The column
  scaling by Θ − σ only keeps Y's columns at unit size (the span is that of (L − σM)⁻¹ M X);
- on the finest level, iterations repeat until every wanted pair has η_k² ≤ ``tol``, with
  η_k = ‖L φ_k − θ_k M φ_k‖_{M⁻¹} / θ_k the relative residual: a Ritz value's relative error is
  about η_k² θ_k/δ_k (δ_k the gap to the unwanted spectrum), so ``tol`` bounds the relative
  eigenvalue error up to that gap factor (see ``bench/bench_large.py`` for measured errors);
- below ``SMALL_CLOUD_MAX_POINTS`` points (the papers' clouds), a single coarse level of
  ``SMALL_COARSE_POINTS_PER_VECTOR`` points per vector, solved densely, and a first fine iteration
  that applies the shift-invert operator ``SMALL_FINE_SOLVES`` times before its Rayleigh–Ritz step:
  at that size a solve of p right-hand sides costs less than the dense work around it (the coarse
  eigensolve, the projections), so a rougher, cheaper coarse space is refined by more solves
  instead. The factorisation is QDLDL's LDLᵀ and the block solves those of :mod:`tactex.spectral.block_lu`
  (numba) when available, all but the last in single precision, cholespy otherwise. Every (n, p) block of
  this route is written into a buffer it already has where it can: at this size a new block's first touch
  (page faults) costs about as much as the arithmetic on it.

The subspace holds p = k + max(k/2, 20) vectors: the extra ones make the k-th pair converge at
the rate λ_k / λ_{p+1} ≈ 2/3 per iteration on a surface (λ_k grows about linearly with k).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as la
import scipy.sparse as sp
import scipy.sparse.linalg as sla
from scipy.linalg.blas import dsyrk
from scipy.spatial import cKDTree

from tactex.errors import ConfigError, SpectralError
from tactex.spectral import block_lu
from tactex.spectral.exact import exact_eigenpairs

__all__ = [
    "COARSE_POINTS_PER_VECTOR",
    "DEFAULT_TOL",
    "MIN_VOXEL_SPACINGS",
    "SMALL_CLOUD_MAX_POINTS",
    "HierarchyInfo",
    "coarse_level_size",
    "fine_subspace_size",
    "hierarchical_eigenpairs",
    "subspace_size",
    "voxel_levels",
]

_log = logging.getLogger(__name__)

#: Default bound on the squared relative residual η² of every wanted pair (≈ relative eigenvalue error).
DEFAULT_TOL = 5e-3
#: The coarsest level holds about this many points per subspace vector. Its dense solve is cheap up to
#: ``COARSE_DENSE_MAX_POINTS``, and a well-resolved coarsest space spares intermediate levels, whose
#: denser Galerkin operators cost almost as much to factor and solve as the finest one.
COARSE_POINTS_PER_VECTOR = 7
#: The finest coarse level uses voxels of at least this many point spacings.
MIN_VOXEL_SPACINGS = 1.5
#: Neighbours of a fine point in the coarser level that its prolongation weights mix.
PROLONGATION_NEIGHBORS = 4
#: The coarsest level goes to dense LAPACK up to this size: p of its ~1000 pairs are wanted, a share at
#: which ARPACK's Lanczos costs more than the dense solve.
COARSE_DENSE_MAX_POINTS = 2500
#: Block iterations on the finest level before giving up.
MAX_ITERATIONS = 8
#: Below this many points the hierarchy is a single coarse level (``SMALL_COARSE_POINTS_PER_VECTOR`` points per
#: vector) and the cloud's first iteration makes ``SMALL_FINE_SOLVES`` solves before its Rayleigh–Ritz step: at a few
#: thousand points the cost is in dense work on p columns (the coarse eigensolve, the projections), not in the solves.
SMALL_CLOUD_MAX_POINTS = 10_000
#: Points per subspace vector of the single coarse level of a small cloud. The dense coarse eigensolve grows as its
#: cube; below 2.5 the coarse space can miss one of the wanted modes, which no later solve brings back.
SMALL_COARSE_POINTS_PER_VECTOR = 2.5
#: Shift-invert solves on a small cloud before its first Rayleigh–Ritz step (a solve costs less than refining a
#: larger coarse level would).
SMALL_FINE_SOLVES = 3
#: On a small cloud σ = −``SMALL_SHIFT_FRACTION`` θ_p (θ_p the largest coarse Ritz value): s solves in a row
#: multiply a column's null-space component by ((θ_p − σ)/(−σ))^s, which a shift near zero makes overflow the
#: block's conditioning; a shift far below θ_p hardly changes the convergence of the wanted pairs.
SMALL_SHIFT_FRACTION = 0.01
#: Small clouds factor with QDLDL and solve blocks with :mod:`tactex.spectral.block_lu` (the ``fast`` extra) when there.
SMALL_BLOCK_LU = True


@dataclass
class HierarchyInfo:
    """What a hierarchical solve did: level sizes (fine → coarse), iterations on the finest level,
    the largest squared relative residual η² reached, and seconds per phase."""

    level_points: list[int] = field(default_factory=list)
    subspace_size: int = 0
    fine_iterations: int = 0
    max_residual2: float = float("nan")
    seconds: dict[str, float] = field(default_factory=dict)


def subspace_size(k: int) -> int:
    """p = k + max(k/2, 20): the block size of the subspace iteration for k wanted pairs."""
    return k + max(k // 2, 20)


def fine_subspace_size(k: int) -> int:
    """p_fine = k + max(k/5, 20): the block size on the finest level, where the cost is (p solves, n p²
    products), and which starts from Ritz vectors already refined on the level below (see the module doc)."""
    return k + max(k // 5, 20)


def _voxel_keys(points: np.ndarray, voxel: float) -> np.ndarray:
    """(N,) one integer per voxel of edge ``voxel`` [m] (row-major, so they sort like the voxels' index rows;
    np.unique on rows is several times slower)."""
    key = np.floor((points - points.min(axis=0)) / voxel).astype(np.int64)
    extent = key.max(axis=0) + 1
    return (key[:, 0] * extent[1] + key[:, 1]) * extent[2] + key[:, 2]


def _voxel_representatives(points: np.ndarray, voxel: float) -> np.ndarray:
    """Sorted indices of one point per occupied voxel of edge ``voxel`` [m]: the one nearest the
    centroid of the voxel's points."""
    _, inv = np.unique(_voxel_keys(points, voxel), return_inverse=True)
    inv = inv.ravel()
    n = int(inv.max()) + 1
    count = np.bincount(inv, minlength=n).astype(np.float64)
    centroid = np.stack([np.bincount(inv, points[:, j], n) for j in range(3)], axis=1) / count[:, None]
    d2 = np.einsum("ij,ij->i", points - centroid[inv], points - centroid[inv])
    order = np.lexsort((d2, inv))
    first = order[np.r_[0, np.flatnonzero(np.diff(inv[order])) + 1]]
    return np.sort(first)


def _prolongation(fine: np.ndarray, coarse: np.ndarray, voxel: float) -> sp.csr_matrix:
    """(n_fine, n_coarse) interpolation: normalised 1/(d² + ε²) weights of the nearest coarse points."""
    k = min(PROLONGATION_NEIGHBORS, coarse.shape[0])
    d, j = cKDTree(coarse).query(fine, k=k)
    d, j = d.reshape(len(fine), k), j.reshape(len(fine), k)
    w = 1.0 / (d**2 + (1e-3 * voxel) ** 2)
    w /= w.sum(axis=1, keepdims=True)
    indptr = np.arange(0, k * len(fine) + 1, k)
    return sp.csr_matrix((w.ravel(), j.ravel(), indptr), shape=(len(fine), len(coarse)))


def voxel_levels(points: np.ndarray, spacing: float, coarse_points: int,
                 single: bool = False) -> list[tuple[np.ndarray, sp.csr_matrix]]:
    """The coarse levels below the cloud: [(indices into the next finer level, prolongation)], fine → coarse.

    The coarsest level is the cloud voxelised at the edge v_c that leaves about ``coarse_points`` points
    (v_c ≈ h √(N / coarse_points) on a surface, corrected once by the count it gives); the finer ones use
    v_c/2, v_c/4, … down to ``MIN_VOXEL_SPACINGS`` h, each level choosing among the points of the one above
    it. ``single``: only the coarsest level, prolonged straight to the cloud. An empty list: the cloud is too
    small for a hierarchy.
    """
    n = points.shape[0]
    voxel = spacing * np.sqrt(n / coarse_points)
    if voxel < MIN_VOXEL_SPACINGS * spacing:
        return []
    voxel *= np.sqrt(np.unique(_voxel_keys(points, voxel)).size / coarse_points)
    edges = []
    while voxel >= MIN_VOXEL_SPACINGS * spacing:
        edges.append(voxel)
        voxel /= 2.0
        if single:
            break
    out: list[tuple[np.ndarray, sp.csr_matrix]] = []
    current = points
    for edge in reversed(edges):
        idx = _voxel_representatives(current, edge)
        if idx.size >= current.shape[0]:
            continue
        coarse = current[idx]
        out.append((idx, _prolongation(current, coarse, edge)))
        current = coarse
    return out


def coarse_level_size(p: int, n: int) -> int:
    """Points of the coarsest level for a subspace of p vectors on a cloud of n points.

    ``COARSE_POINTS_PER_VECTOR`` p while that fits the dense solve, else max(``COARSE_DENSE_MAX_POINTS``, 2p);
    at most n/4 (one halving of the spacing) but at least 2p, since the dense solve's cubic cost outgrows what
    a coarsest level closer to the cloud saves. Below ``SMALL_CLOUD_MAX_POINTS`` points:
    ``SMALL_COARSE_POINTS_PER_VECTOR`` p, with the same bounds.
    """
    if n < SMALL_CLOUD_MAX_POINTS:
        return max(min(int(SMALL_COARSE_POINTS_PER_VECTOR * p), n // 4), 2 * p)
    wanted = COARSE_POINTS_PER_VECTOR * p
    size = wanted if wanted <= COARSE_DENSE_MAX_POINTS else max(COARSE_DENSE_MAX_POINTS, 2 * p)
    return max(min(size, n // 4), 2 * p)


class _Factor:
    """A sparse Cholesky factorisation of an SPD matrix, solving many right-hand sides at once.

    cholespy (CHOLMOD, simplicial LLᵀ) solves a block of p right-hand sides ~4× faster than SuperLU's
    column-by-column solve on 60k points; SuperLU with a symmetric ordering is the fallback when the
    wheel is missing on a platform. ``block`` (small clouds): QDLDL's LDLᵀ factors (AMD ordering) with the
    compiled block substitutions of :mod:`tactex.spectral.block_lu` when the ``fast`` extra is there,
    cholespy otherwise; at a few thousand points QDLDL factors faster than CHOLMOD's nested-dissection route
    and the compiled substitutions solve a block faster than cholespy.
    """

    def __init__(self, A: sp.spmatrix, block: bool = False) -> None:
        if A.format != "csc":
            A = sp.csc_matrix(A)
        A.sum_duplicates()
        self.n = A.shape[0]
        self._block = None
        self._A = None
        if block and block_lu.available():
            try:
                self._block = block_lu.BlockLU(A)
                self._A = A  # for cholespy, should the compiled solve fail
                return
            except RuntimeError:  # a pivot ≤ 0: cholespy reports what is wrong with A
                self._block = None
        self._init_cholmod(A)

    def _init_cholmod(self, A: sp.csc_matrix) -> None:
        try:
            import cholespy
        except ImportError:  # pragma: no cover - cholespy is a dependency; other platforms may lack a wheel
            self._chol = None
            self._lu = sla.splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
            return
        self._chol = cholespy.CholeskySolverD(
            self.n, A.indptr.astype(np.int32), A.indices.astype(np.int32), A.data.astype(np.float64),
            cholespy.MatrixType.CSC,
        )

    @property
    def block_solve(self) -> bool:
        """Whether the compiled block solve is in use (it makes :meth:`forward_gram`)."""
        return self._block is not None

    def forward_gram(self, Y: np.ndarray) -> np.ndarray | None:
        """Yᵀ (L − σM) Y for the block Y of the last solve (made with ``gram=True``): as an exact Gram matrix when
        the compiled block solve made it (:meth:`block_lu.BlockLU.forward_gram`); from the matrix itself when that
        solve failed on the way (its caller may have let the right-hand side go); None for cholespy alone."""
        if self._block is not None:
            return self._block.forward_gram()
        if self._A is not None:
            return Y.T @ (self._A @ Y)
        return None

    def solve(self, B: np.ndarray, out: np.ndarray | None = None, row: np.ndarray | None = None,
              col: np.ndarray | None = None, dtype: type = np.float64, gram: bool = False) -> np.ndarray:
        """(L − σM)⁻¹ diag(row) B diag(col) for a C-ordered (n, p) block B (row, col: optional scalings), written
        into ``out`` when given (same shape; with scalings it may be B itself). ``dtype``: the precision of the
        compiled block solve and of a new ``out`` (CHOLMOD solves in double and rounds to it). ``gram``: keep
        what :meth:`forward_gram` needs."""
        if self._block is not None:
            try:
                return self._block.solve(B, out=out, row=row, col=col, dtype=dtype, gram=gram)
            except RuntimeError:  # numba failed (logged once by block_lu): CHOLMOD from now on
                self._block = None
                self._init_cholmod(self._A)
        if row is not None or col is not None:
            B = B * (1.0 if row is None else row[:, None]) * (1.0 if col is None else col[None, :])
        if self._chol is None:  # pragma: no cover
            X = self._lu.solve(np.asfortranarray(B, dtype=np.float64))
        else:
            B = np.ascontiguousarray(B, dtype=np.float64)
            X = np.empty_like(B) if out is None or out.dtype != np.float64 else out
            self._chol.solve(B, X)
        if out is None:
            return X.astype(dtype, copy=False)
        if X is not out:
            out[...] = X
        return out


def _shifted(Lf: sp.csr_matrix, mf: np.ndarray, sigma: float) -> sp.csc_matrix:
    """L − σ diag(mf) in the CSC form the factorisations take, made from L's CSR arrays: L is symmetric, so they
    are its CSC arrays too, and the shift only changes the stored diagonal (one entry per row of a Laplacian or
    its Galerkin products; else the general sparse sum)."""
    n = Lf.shape[0]
    Lf.sum_duplicates()
    diag = np.flatnonzero(Lf.indices == np.repeat(np.arange(n, dtype=Lf.indices.dtype), np.diff(Lf.indptr)))
    if diag.size != n:
        return sp.csc_matrix(Lf - sigma * sp.diags(mf))
    data = Lf.data.copy()
    data[diag] -= sigma * mf
    return sp.csc_matrix((data, Lf.indices, Lf.indptr), shape=Lf.shape)


def _single_view(X: np.ndarray) -> np.ndarray | None:
    """A C-ordered float32 array of X's shape in the first half of the memory of X; None unless X is a C-ordered
    float64 array."""
    if X.dtype != np.float64 or not X.flags.c_contiguous:
        return None
    return X.reshape(-1).view(np.float32)[: X.size].reshape(X.shape)


def _refine(factor: _Factor, mass: np.ndarray, X: np.ndarray, theta: np.ndarray, sigma: float,
            out: np.ndarray | None = None, solves: int = 1,
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """One block shift-invert iteration from X and Rayleigh–Ritz on its image (M = diag(mass)).

    ``solves`` > 1 applies the scaled shift-invert operator that many times before the Rayleigh–Ritz step (the
    span is that of as many plain iterations; only the conditioning of the block differs, see
    ``SMALL_SHIFT_FRACTION``).

    Returns (θ, Q, Y, spare): the Ritz values and vectors Y Q of span Y, Y = (L − σM)⁻¹ M X D. X itself is
    overwritten and handed back as ``spare``, an (n, p) buffer for the caller's Y Q (None when the last solve
    wrote Y into X); Y goes into ``out`` when given. On large clouds each (n, p) block is a hundred megabytes
    or more, whose first touch can cost as much as a matrix product, so the iteration lives in two buffers.

    The projected stiffness is Yᵀ L Y = Yᵀ M X D + σ Yᵀ M Y, so L itself is never applied to the block;
    Yᵀ M Y is a symmetric rank-k product (half a matrix product). With the compiled block solve, Yᵀ (L − σM) Y
    is one too, from the last solve's forward half (:meth:`_Factor.forward_gram`), and the product with the
    previous block is not formed.
    """
    scale = np.maximum(theta - sigma, 1e-300)[None, :]
    if solves == 1:
        X *= mass[:, None]
        X *= scale
        Y = factor.solve(X, out=out)
        A = Y.T @ X
    else:
        # The solves scale their right-hand sides themselves. All but the last run in single precision: they only
        # have to bring the block's span towards the wanted space, and the last solve's relation
        # (L − σM) Y = M Y_prev D, on which the projection below rests, holds in double for whatever Y_prev is.
        # With the block solve the single-precision block lives in the first half of X's memory: a solve reads its
        # right-hand side before it writes its result, X is not needed after it, and neither is that block once the
        # last solve (written into X) has made the projected stiffness from its forward half.
        prev = factor.solve(X, out=_single_view(X) if factor.block_solve else None, row=mass, col=scale[0],
                            dtype=np.float32)
        for _ in range(solves - 2):
            prev = factor.solve(prev, out=prev, row=mass, col=scale[0], dtype=np.float32)
        Y = factor.solve(prev, out=X if out is None else out, row=mass, col=scale[0], gram=True)
        A = factor.forward_gram(Y)  # Yᵀ (L − σM) Y from the solve's forward half (block solve only)
        if A is None:
            X = np.multiply(prev, mass[:, None], out=np.empty(Y.shape))
            A = Y.T @ X  # Yᵀ M Y_prev, the last solve's right-hand side M Y_prev D without D
            A *= scale
        else:
            X = None  # no spare block: the caller makes one only if it iterates again
        del prev
    root_mass = np.sqrt(mass)[:, None]
    if X is None:  # M^{1/2} Y in place and back (to within an ulp), rather than a new block's first touch
        root = np.multiply(Y, root_mass, out=Y)
    else:
        root = np.multiply(Y, root_mass, out=X)
    B = dsyrk(1.0, root.T, trans=0, lower=0)  # upper triangle of rootᵀ root (root.T is Fortran-ordered)
    if X is None:
        np.divide(Y, root_mass, out=Y)
    B = np.triu(B) + np.triu(B, 1).T
    A += sigma * B
    A = 0.5 * (A + A.T)
    try:
        theta, Q = la.eigh(A, B, check_finite=False)
    except la.LinAlgError as exc:
        raise SpectralError(
            f"the hierarchical eigensolver lost the rank of its subspace ({exc}); use --eigensolver arpack"
        ) from exc
    return theta, Q, Y, X


def _relative_residual2(L: sp.spmatrix, mass: np.ndarray, theta: np.ndarray, X: np.ndarray,
                        compiled: bool = False) -> np.ndarray:
    """η_k² = ‖L φ_k − θ_k M φ_k‖²_{M⁻¹} / θ_k² for Ritz pairs (θ floored at 1e-3 θ_max: the null space has
    θ ≈ 0).

    Ritz vectors are M-orthonormal with φ_kᵀ L φ_k = θ_k, so the numerator is ‖L φ_k‖²_{M⁻¹} − θ_k²: one
    product with L and no (n, k) temporaries besides it (``compiled``, with :func:`block_lu.product_norms2`:
    none at all). Its cancellation costs ~1e-16 relative, far below any tolerance in (0, 1).
    """
    norms2 = None
    if compiled and block_lu.available() and sp.isspmatrix_csr(L):
        try:
            norms2 = block_lu.product_norms2(L, X, 1.0 / mass)
        except RuntimeError:  # numba failed (logged once by block_lu)
            norms2 = None
    if norms2 is None:
        R = L @ X
        R *= (1.0 / np.sqrt(mass))[:, None]
        norms2 = np.einsum("ij,ij->j", R, R)
    num = np.maximum(norms2 - theta**2, 0.0)
    den = np.maximum(np.abs(theta), 1e-3 * float(np.max(np.abs(theta)))) ** 2
    return num / den


def hierarchical_eigenpairs(
    L: sp.spmatrix,
    mass: np.ndarray,
    k: int,
    points: np.ndarray,
    spacing: float,
    tol: float = DEFAULT_TOL,
    seed: int = 0,
    info: HierarchyInfo | None = None,
    progress: Callable[[str], None] | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """The k smallest pairs of L φ = λ M φ (M = diag(mass)) by hierarchical subspace iteration.

    Args:
        L: (N, N) symmetric PSD weak Laplacian of ``points``.
        mass: (N,) lumped mass [m²].
        k: wanted pairs.
        points: (N, 3) positions [m] the hierarchy is built from.
        spacing: mean point spacing h [m]; the first coarse level uses voxels of 2h.
        tol: bound on η² (≈ relative eigenvalue error) of every wanted pair on the finest level, in (0, 1).
        seed: start vector of the exact solve on the coarsest level.
        info: filled with what the solve did, when given.
        progress: called with a line per level and per iteration on the finest one (a large cloud takes minutes).

    Returns:
        (evals (k,), evecs (N, k)) M-orthonormal, unsorted signs; or None when the cloud is too small for a
        coarser level (the caller then solves exactly).
    """
    if not (isinstance(tol, (float, int)) and 0.0 < float(tol) < 1.0):
        raise ConfigError(f"eigen_tol must be a number in (0, 1), got {tol!r} (e.g. 5e-3)")
    if not (np.isfinite(spacing) and spacing > 0.0):
        raise ConfigError(f"the hierarchical eigensolver needs the point spacing h > 0 [m], got {spacing!r}")
    info = info if info is not None else HierarchyInfo()
    n = L.shape[0]
    small = n < SMALL_CLOUD_MAX_POINTS
    p = subspace_size(k)
    t0 = time.perf_counter()
    levels = voxel_levels(points, spacing, coarse_level_size(p, n), single=small)
    while levels and levels[-1][0].size < 2 * p:  # a voxel count below the estimate: too few for p vectors
        levels.pop()
    if not levels:
        return None
    # Guard vectors are dropped on the finest level only when the vectors reaching it were refined below.
    p_fine = min(p, fine_subspace_size(k)) if len(levels) >= 2 else p
    L = sp.csr_matrix(L)
    ops: list[tuple[sp.csr_matrix, np.ndarray]] = [(L, mass)]
    for _, P in levels:
        Lf, mf = ops[-1]
        PT = sp.csr_matrix(P.T)
        # Lumped Pᵀ M P: its row sums, Pᵀ (M P 1) = Pᵀ mf since P's rows sum to 1.
        ops.append((sp.csr_matrix(PT @ Lf @ P), PT @ mf))
    info.level_points = [n] + [len(idx) for idx, _ in levels]
    info.subspace_size = p
    info.seconds["hierarchy"] = time.perf_counter() - t0
    say = progress or (lambda msg: None)
    say(f"eigensolver: {len(levels) + 1} levels of {', '.join(str(m) for m in info.level_points)} points, "
        f"{p} vectors; the coarsest solved exactly ...")

    t0 = time.perf_counter()
    Lc, mc = ops[-1]
    if Lc.shape[0] <= COARSE_DENSE_MAX_POINTS:
        # Single precision: these vectors only start the refinement, which works in double.
        # S Lc S (S = Mc^{-1/2}), symmetrised, formed densely: the sparse products cost more at this size.
        scale = 1.0 / np.sqrt(mc)
        A = Lc.toarray()
        A *= scale[:, None]
        A *= scale[None, :]
        A = (0.5 * (A + A.T)).astype(np.float32)
        # Divide and conquer computes every pair but beats the subset driver while p is a large share of them.
        subset = {"subset_by_index": [0, p - 1]} if 4 * p < A.shape[0] else {"driver": "evd"}
        theta, W = la.eigh(A, check_finite=False, **subset)
        theta, W = theta[:p].astype(np.float64), W[:, :p]
        X = scale[:, None] * W.astype(np.float64)
    else:
        theta, X = exact_eigenpairs(Lc, mc, p, seed=seed)
    info.seconds["coarsest"] = time.perf_counter() - t0
    # A shift below the spectrum keeps L − σM positive definite whatever the null space.
    sigma = -1e-6 * float(np.mean(L.diagonal() / mass))
    if small:
        sigma = min(sigma, -SMALL_SHIFT_FRACTION * float(theta[-1]))
    t_factor = t_iter = 0.0
    for level in range(len(levels) - 1, -1, -1):
        if level == 0:
            X, theta = X[:, :p_fine], theta[:p_fine]
        X = levels[level][1] @ X
        Lf, mf = ops[level]
        say(f"eigensolver: level {len(levels) - level + 1} of {len(levels) + 1} ({Lf.shape[0]} points): factor and "
            "refine ...")
        t0 = time.perf_counter()
        factor = _Factor(_shifted(Lf, mf, sigma), block=small and SMALL_BLOCK_LU)
        t1 = time.perf_counter()
        theta, Q, Y, spare = _refine(factor, mf, X, theta, sigma, solves=SMALL_FINE_SOLVES if small else 1)
        if level > 0:
            X = np.matmul(Y, Q, out=spare)
        else:
            for it in range(1, MAX_ITERATIONS + 1):
                # The wanted vectors first: when they have converged the other p − k are never formed.
                Xk = Y @ Q[:, :k]
                eta2 = _relative_residual2(L, mass, theta[:k], Xk, compiled=small and SMALL_BLOCK_LU)
                info.fine_iterations = it
                info.max_residual2 = float(eta2.max())
                say(f"eigensolver: iteration {it}: largest η² {info.max_residual2:.1e} (done at ≤ {tol:g})")
                _log.debug("hierarchical eigensolver: iteration %d, max η² %.2e", it, info.max_residual2)
                if info.max_residual2 <= tol:
                    X = Xk
                    break
                if it == MAX_ITERATIONS:
                    raise SpectralError(
                        f"the hierarchical eigensolver did not reach eigen_tol={tol:g} in {MAX_ITERATIONS} "
                        f"iterations (max η² {info.max_residual2:.2e}); raise --eigen-tol or use --eigensolver arpack"
                    )
                del Xk
                X = np.matmul(Y, Q, out=spare)
                theta, Q, Y, spare = _refine(factor, mf, X, theta, sigma, out=Y)
        del Y, spare
        t_factor += t1 - t0
        t_iter += time.perf_counter() - t1
        del factor
    info.seconds["factor"] = t_factor
    info.seconds["iterations"] = t_iter
    return theta[:k], X
