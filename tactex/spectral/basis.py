"""The Laplace eigenbasis of a surface cloud (TEC eq. 20), built once per cloud and cached."""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from tactex.errors import CacheError, CloudError, ConfigError, SpectralError
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.spectral.cache import basis_key, default_cache_dir, load_arrays, save_arrays
from tactex.spectral.cache_store import cache_cap_bytes, enforce_cap, mark_used
from tactex.spectral.eigen import check_eigensolver, laplace_eigenpairs, resolve_eigensolver
from tactex.spectral.hierarchy import DEFAULT_TOL
from tactex.spectral.laplacian import point_cloud_laplacian

__all__ = ["LaplaceBasis", "build_basis", "compute_basis", "load_basis", "save_basis"]


@dataclass(frozen=True, eq=False)
class LaplaceBasis:
    """Weak Laplacian, mass matrix and the n_K smallest Laplace–Beltrami eigenpairs of a cloud.

    Attributes:
        L: (N, N) CSR weak Laplacian [1], symmetric PSD, zero row sums.
        M: (N, N) CSR diagonal mass matrix [m²] (Voronoi areas).
        mass: (N,) diagonal of M [m²].
        evals: (K,) eigenvalues λ_k [1/m²], ascending, ≥ 0.
        evecs: (N, K) eigenvectors Φ [1/m], M-orthonormal: Φᵀ M Φ = I.
        spacing: mean spacing h between neighbouring points [m] (from the cloud).
        n_neighbors: neighbour count the Laplacian was built with.
        key: content hash of the points and parameters (the cache file name).
        mollify_factor: robust_laplacian's mollification.
        n_components: connected parts of the cloud as the Laplacian sees them (TEC §VI-D).
        eigensolver: the solver that computed the pairs ("arpack" exact, or "hierarchical").
        eigen_tol: the hierarchical solver's tolerance on η² (0 for ARPACK, exact).
        from_cache: True when the basis was read from a cache file rather than computed.
    """

    L: sp.csr_matrix
    M: sp.csr_matrix
    mass: np.ndarray
    evals: np.ndarray
    evecs: np.ndarray
    spacing: float
    n_neighbors: int
    key: str
    mollify_factor: float = 1e-5
    n_components: int = 1
    eigensolver: str = "arpack"
    eigen_tol: float = 0.0
    from_cache: bool = False

    def __post_init__(self) -> None:
        for name in ("mass", "evals", "evecs"):
            getattr(self, name).setflags(write=False)

    @property
    def n_points(self) -> int:
        """N, the number of points."""
        return int(self.evecs.shape[0])

    @property
    def n_eigen(self) -> int:
        """K, the number of eigenpairs."""
        return int(self.evecs.shape[1])

    def component_labels(self) -> np.ndarray:
        """Connected part (N,) of each point as the Laplacian links them (0 … n_components−1)."""
        return _component_labels(self.L)[1]

    def project(self, u: np.ndarray) -> np.ndarray:
        """Spectral coefficients Φᵀ M u of a field u (N,) or (N, B)."""
        return self.evecs.T @ (self.mass[:, None] * u if u.ndim == 2 else self.mass * u)

    def reconstruct(self, coefficients: np.ndarray) -> np.ndarray:
        """The field Φ c on the points from spectral coefficients c (K,) or (K, B)."""
        return self.evecs @ coefficients


def _check_n_eigen(n_eigen: object, n_points: int) -> int:
    if isinstance(n_eigen, bool) or not isinstance(n_eigen, (int, np.integer)):
        raise ConfigError(f"n_eigen must be an integer, got {n_eigen!r}")
    k = int(n_eigen)
    if k < 1:
        raise ConfigError(f"n_eigen must be ≥ 1, got {k} (the paper uses 100–200)")
    if k >= n_points:
        if n_points < 3:
            raise SpectralError(
                f"the cloud has only {n_points} point(s): too few for a Laplace basis; use a denser cloud "
                "(smaller voxel size)"
            )
        suggestion = max(1, min(200, n_points // 2))
        raise SpectralError(
            f"n_eigen={k} eigenpairs requested but the cloud has only {n_points} points: ask for fewer than "
            f"{n_points} (e.g. {suggestion}), or use a denser cloud (smaller voxel size)"
        )
    return k


def _component_labels(L: sp.spmatrix) -> tuple[int, np.ndarray]:
    # The diagonal only adds self-loops, which join nothing; stored zeros would count as edges.
    graph = sp.csr_matrix(L)
    if not graph.data.all():
        graph = graph.copy()
        graph.eliminate_zeros()
    n, labels = connected_components(graph, directed=False)
    return int(n), labels


def _count_components(L: sp.csr_matrix) -> int:
    return _component_labels(L)[0]


def compute_basis(
    points: np.ndarray, spacing: float, n_eigen: int, n_neighbors: int, mollify_factor: float, key: str,
    eigensolver: str = "arpack", eigen_tol: float = DEFAULT_TOL, progress: Callable[[str], None] | None = None,
) -> LaplaceBasis:
    """Build a basis without any caching (see :func:`build_basis`); ``progress`` gets a line per phase."""
    say = progress or (lambda msg: None)
    say(f"basis: Laplacian of {len(points)} points ...")
    t0 = time.perf_counter()
    L, M = point_cloud_laplacian(points, n_neighbors=n_neighbors, mollify_factor=mollify_factor)
    mass = M.diagonal().copy()
    solver = resolve_eigensolver(eigensolver, len(points))
    say(f"basis: Laplacian {time.perf_counter() - t0:.1f} s; {n_eigen} eigenpairs ({solver} eigensolver) ...")
    evals, evecs = laplace_eigenpairs(L, mass, n_eigen, solver=solver, tol=eigen_tol, points=points, spacing=spacing,
                                      progress=progress)
    return LaplaceBasis(
        L=L,
        M=M,
        mass=mass,
        evals=evals,
        evecs=evecs,
        spacing=float(spacing),
        n_neighbors=int(n_neighbors),
        key=key,
        mollify_factor=float(mollify_factor),
        n_components=_count_components(L),
        eigensolver=solver,
        eigen_tol=float(eigen_tol) if solver == "hierarchical" else 0.0,
    )


def save_basis(basis: LaplaceBasis, path: str | Path) -> Path:
    """Write a basis to an ``.npz`` file (no pickle)."""
    p = Path(path)
    save_arrays(
        p,
        basis.L,
        {
            "mass": basis.mass,
            "evals": basis.evals,
            "evecs": basis.evecs,
            "spacing": np.asarray(basis.spacing),
            "n_neighbors": np.asarray(basis.n_neighbors),
            "mollify_factor": np.asarray(basis.mollify_factor),
            "n_components": np.asarray(basis.n_components),
            "eigensolver": np.asarray(basis.eigensolver),
            "eigen_tol": np.asarray(basis.eigen_tol),
            "key": np.asarray(basis.key),
        },
    )
    return p


def load_basis(path: str | Path, expected_key: str | None = None) -> LaplaceBasis:
    """Read a basis written by :func:`save_basis`.

    Raises:
        CacheError: the file is unreadable, inconsistent, holds NaN, or its key differs from
            ``expected_key`` (it describes other points or parameters).
    """
    p = Path(path)
    L, a = load_arrays(p)
    try:
        key = str(a["key"])
        mass, evals, evecs = (np.asarray(a[n], dtype=np.float64) for n in ("mass", "evals", "evecs"))
        n = mass.shape[0]
        ok_shapes = mass.ndim == 1 and evals.ndim == 1 and evecs.shape == (n, evals.shape[0]) and L.shape == (n, n)
        if not ok_shapes:
            raise CacheError(
                f"basis cache file '{p}' has inconsistent shapes: mass {mass.shape}, evals {evals.shape}, "
                f"evecs {evecs.shape}, L {L.shape}; delete it"
            )
        if not all(np.isfinite(x).all() for x in (mass, evals, evecs, L.data)):
            raise CacheError(f"basis cache file '{p}' holds NaN/inf values; delete it")
        basis = LaplaceBasis(
            L=L,
            M=sp.diags(mass, format="csr"),
            mass=mass,
            evals=evals,
            evecs=evecs,
            spacing=float(a["spacing"]),
            n_neighbors=int(a["n_neighbors"]),
            key=key,
            mollify_factor=float(a["mollify_factor"]),
            n_components=int(a["n_components"]),
            eigensolver=str(a["eigensolver"]),
            eigen_tol=float(a["eigen_tol"]),
            from_cache=True,
        )
    except KeyError as exc:
        raise CacheError(f"basis cache file '{p}' lacks the array {exc}; delete it") from exc
    if expected_key is not None and key != expected_key:
        raise CacheError(f"basis cache file '{p}' describes other points or parameters (key {key[:12]}…)")
    return basis


def build_basis(
    cloud: SurfaceCloud,
    n_eigen: int = 200,
    n_neighbors: int = 30,
    cache_dir: str | Path | None = None,
    *,
    cache: bool = True,
    mollify_factor: float = 1e-5,
    eigensolver: str = "auto",
    eigen_tol: float = DEFAULT_TOL,
    progress: Callable[[str], None] | None = None,
) -> LaplaceBasis:
    """The Laplace basis of ``cloud``: L, M and the ``n_eigen`` smallest eigenpairs (TEC eq. 20).

    Args:
        cloud: the surface; its spacing becomes the basis spacing h [m].
        n_eigen: number of eigenpairs n_K, 1 ≤ n_K < N (TEC §VI-B: 100 is a good trade-off).
        n_neighbors: neighbour count of the Laplacian; decides which parts are connected.
        cache_dir: where basis files live; None → ``$TACTEX_CACHE_DIR`` or ``~/.cache/tactex/basis``.
        cache: False computes without reading or writing any file.
        mollify_factor: robust_laplacian's intrinsic mollification.
        eigensolver: "arpack" (exact shift-invert Lanczos, the authors' method), "hierarchical"
            (hierarchical subspace iteration, several times faster on large clouds) or "auto"
            (hierarchical from ``HIERARCHICAL_MIN_POINTS`` points on). Part of the cache key.
        eigen_tol: the hierarchical solver's bound on each pair's squared relative residual
            (≈ relative eigenvalue error), in (0, 1). Part of the cache key.
        progress: called with a line per phase of a computed basis (Laplacian, eigensolver levels and
            iterations); a basis read from the cache says nothing.

    A corrupt or mismatching cache file is reported with a ``RuntimeWarning``, recomputed and
    overwritten (use :func:`load_basis` to get a :class:`CacheError` instead). The folder is capped at
    ``$TACTEX_CACHE_MAX_GB`` (:mod:`tactex.spectral.cache_store`): a file read becomes the most recently
    used one, and after a file is written the least recently used go until the folder fits again.
    """
    if not isinstance(cloud, SurfaceCloud):
        raise CloudError(f"build_basis needs a SurfaceCloud, got {type(cloud).__name__}")
    k = _check_n_eigen(n_eigen, len(cloud))
    check_eigensolver(eigensolver, eigen_tol)
    solver = resolve_eigensolver(eigensolver, len(cloud))
    tol = float(eigen_tol) if solver == "hierarchical" else 0.0
    key = basis_key(cloud.points, k, n_neighbors, mollify_factor, cloud.spacing, solver, tol)
    path = None
    if cache:
        cap = cache_cap_bytes()  # a bad $TACTEX_CACHE_MAX_GB is said before the work, not after it
        path = Path(cache_dir).expanduser() if cache_dir is not None else default_cache_dir()
        path = path / f"{key}.npz"
        if path.is_file():
            try:
                basis = load_basis(path, expected_key=key)
                if basis.n_points == len(cloud) and basis.n_eigen == k:
                    mark_used(path)
                    return basis
                raise CacheError(f"basis cache file '{path}' has {basis.n_points}×{basis.n_eigen} vectors")
            except CacheError as exc:
                warnings.warn(f"{exc}; recomputing the basis", RuntimeWarning, stacklevel=2)
    basis = compute_basis(cloud.points, cloud.spacing, k, n_neighbors, mollify_factor, key, solver, eigen_tol,
                          progress=progress)
    if path is not None:
        try:
            save_basis(basis, path)
            removed = enforce_cap(path.parent, cap, keep=path)
        except OSError as exc:
            warnings.warn(f"could not write the basis cache '{path}': {exc}", RuntimeWarning, stacklevel=2)
        else:
            if any(e.path.resolve() == path.resolve() for e in removed):
                warnings.warn(f"the basis ({removed[-1].size_bytes / 1e9:.2f} GB) is larger than the cache's cap "
                              f"({cap / 1e9:.2f} GB) and was not kept; raise TACTEX_CACHE_MAX_GB to keep it",
                              RuntimeWarning, stacklevel=2)
    return basis
