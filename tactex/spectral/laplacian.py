"""The weak Laplacian L and lumped mass matrix M of a point cloud (TEC eq. 20), via robust_laplacian.

robust_laplacian (Sharp & Crane 2020) builds a tufted intrinsic Delaunay triangulation of the
k-nearest-neighbour graph, so L is symmetric, positive semi-definite, with non-negative
off-diagonal weights and zero row sums, and M is diagonal (Voronoi areas [m²]). The neighbour
count decides which parts of a cloud are connected (TEC §VI-D): few neighbours keep a scanned
ear apart from the head, many join them.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from tactex.errors import CloudError, ConfigError
from tactex.pointcloud.cloud import validate_points

__all__ = ["MIN_NEIGHBORS", "point_cloud_laplacian"]

#: robust_laplacian asserts on fewer (a point with 2 neighbours yields no triangle).
MIN_NEIGHBORS = 3


def _check_duplicates(points: np.ndarray, name: str) -> None:
    # A structured view makes np.unique compare whole rows in one sort.
    rows = np.ascontiguousarray(points).view(np.dtype((np.void, points.dtype.itemsize * 3))).ravel()
    uniq, first, counts = np.unique(rows, return_index=True, return_counts=True)
    if uniq.size != rows.size:
        dup = int(np.sum(counts - 1))
        example = points[first[np.argmax(counts > 1)]].tolist()
        raise CloudError(
            f"{name} holds {dup} duplicated point(s) (e.g. {example}); the Laplacian is undefined "
            "there. Remove them first with cloud.deduplicated() or a voxel filter"
        )


def point_cloud_laplacian(
    points: np.ndarray, n_neighbors: int = 30, mollify_factor: float = 1e-5
) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """Weak Laplacian and mass matrix of a point cloud.

    Args:
        points: (N, 3) positions [m]; finite, without duplicates, N > n_neighbors.
        n_neighbors: neighbours per point of the local triangulations (≥ 3); decides connectivity.
        mollify_factor: intrinsic mollification, relative to the mean edge length (robust_laplacian).

    Returns:
        (L, M): (N, N) CSR matrices; L [1] symmetric PSD with zero row sums, M diagonal [m²].
    """
    import robust_laplacian

    if isinstance(n_neighbors, bool) or not isinstance(n_neighbors, (int, np.integer)):
        raise ConfigError(f"n_neighbors must be an integer, got {n_neighbors!r}")
    if n_neighbors < MIN_NEIGHBORS:
        raise ConfigError(f"n_neighbors must be ≥ {MIN_NEIGHBORS}, got {n_neighbors} (the paper uses 30)")
    if not np.isfinite(mollify_factor) or mollify_factor < 0.0:
        raise ConfigError(f"mollify_factor must be a finite number ≥ 0, got {mollify_factor}")
    pts = validate_points(points, "points", min_points=1)
    n = pts.shape[0]
    if n < n_neighbors + 1:
        raise CloudError(
            f"the cloud holds {n} point(s) but a Laplacian with n_neighbors={n_neighbors} needs at least "
            f"{n_neighbors + 1}; use a denser cloud (smaller voxel size) or n_neighbors ≤ {max(n - 1, 0)}"
        )
    _check_duplicates(pts, "points")
    L, M = robust_laplacian.point_cloud_laplacian(
        pts, mollify_factor=float(mollify_factor), n_neighbors=int(n_neighbors)
    )
    L = sp.csr_matrix(L)
    M = sp.csr_matrix(M)
    if not (np.isfinite(L.data).all() and np.isfinite(M.data).all()):
        raise CloudError("robust_laplacian returned NaN/inf entries; check the cloud for degenerate clusters")
    if M.diagonal().min() <= 0.0:
        raise CloudError(
            "some points received no area in the mass matrix (isolated or degenerate points); "
            "remove outliers first (statistical outlier filter) or raise n_neighbors"
        )
    return L, M
