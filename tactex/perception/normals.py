"""Per-point normals and surface variation ("curvature" in PCL) from local covariances.

For each point, the covariance Σ of its neighbourhood gives the normal (eigenvector of the
smallest eigenvalue λ0) and PCL's curvature λ0 / (λ0 + λ1 + λ2) — the same quantity as VA-UFIC
eq. 16, evaluated per point. Normals are flipped toward the viewpoint (the camera origin), as
PCL's ``flipNormalTowardsViewpoint`` does.

Two neighbourhoods:

- :func:`grid_normals` — organised (image-grid) points, neighbours in a (2r+1)² pixel window;
  window moments come from integral images (PCL's *IntegralImageNormalEstimation* idea), so the
  cost is independent of r. This is the fast path of the surface estimator.
- :func:`knn_normals` — any cloud, k nearest neighbours from a KD-tree (PCL *NormalEstimation*).

The smallest eigenpair of the batched 3×3 matrices is computed in closed form
(:func:`smallest_eigpairs`), which is several times faster than ``np.linalg.eigh`` on (N, 3, 3).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from tactex.errors import CloudError, ConfigError
from tactex.pointcloud.cloud import validate_points

__all__ = ["NormalField", "covariances_knn", "grid_normals", "knn_normals", "smallest_eigpairs"]


class NormalField(NamedTuple):
    """Per-point normals.

    Attributes:
        normals: (N, 3) unit normals oriented toward the viewpoint (NaN where ``ok`` is False).
        curvature: (N,) surface variation λ0 / tr Σ in [0, 1/3] (NaN where not ``ok``).
        ok: (N,) True where the neighbourhood was large and non-degenerate enough.
    """

    normals: np.ndarray
    curvature: np.ndarray
    ok: np.ndarray


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (N, 3) arrays (np.cross is several times slower on these)."""
    out = np.empty_like(a)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def smallest_eigpairs(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smallest eigenvalue and its unit eigenvector of symmetric 3×3 matrices, in closed form.

    Eigenvalues by the trigonometric solution of the characteristic cubic (O. K. Smith, 1961);
    the eigenvector as the longest cross product of two rows of Σ − λ0·I.

    Args:
        cov: (N, 3, 3) symmetric positive semi-definite matrices.

    Returns:
        (lam0 (N,), vec0 (N, 3), trace (N,)); ``vec0`` is NaN where the smallest eigenvalue is
        (numerically) repeated, i.e. the direction is undefined.
    """
    a00, a11, a22 = cov[:, 0, 0], cov[:, 1, 1], cov[:, 2, 2]
    a01, a02, a12 = cov[:, 0, 1], cov[:, 0, 2], cov[:, 1, 2]
    trace = a00 + a11 + a22
    q = trace / 3.0
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p2 = b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1
    p = np.sqrt(p2 / 6.0)
    safe_p = np.where(p > 0, p, 1.0)
    det = (
        b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02)
    ) / safe_p**3
    phi = np.arccos(np.clip(det / 2.0, -1.0, 1.0)) / 3.0
    lam0 = np.where(p > 0, q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0), q)
    lam0 = np.maximum(lam0, 0.0)
    m = cov - lam0[:, None, None] * np.eye(3)
    r0, r1, r2 = m[:, 0], m[:, 1], m[:, 2]
    crosses = np.stack([_cross(r0, r1), _cross(r0, r2), _cross(r1, r2)], axis=1)
    norms = np.linalg.norm(crosses, axis=2)
    best = np.argmax(norms, axis=1)
    idx = np.arange(cov.shape[0])
    vec = crosses[idx, best]
    nrm = norms[idx, best]
    # The cross products scale like (λ1 − λ0)(λ2 − λ0); relative to tr² that is tiny only when
    # λ0 is repeated (a line or an isotropic blob): no normal there.
    good = nrm > 1e-10 * np.maximum(trace, 1e-300) ** 2
    vec = np.where(good[:, None], vec / np.where(nrm > 0, nrm, 1.0)[:, None], np.nan)
    return lam0, vec, trace


def _finish(
    cov: np.ndarray, count: np.ndarray, points: np.ndarray, viewpoint: np.ndarray, min_count: int
) -> NormalField:
    lam0, vec, trace = smallest_eigpairs(cov)
    ok = (count >= min_count) & (trace > 0) & np.isfinite(vec).all(axis=1)
    flip = np.einsum("ij,ij->i", vec, viewpoint - points) < 0
    vec = np.where(flip[:, None], -vec, vec)
    curvature = np.where(ok, lam0 / np.where(trace > 0, trace, 1.0), np.nan)
    vec[~ok] = np.nan
    return NormalField(vec, curvature, ok)


def grid_normals(
    points_grid: np.ndarray,
    valid: np.ndarray,
    radius_px: int = 2,
    *,
    viewpoint: np.ndarray | None = None,
    min_count: int = 5,
) -> NormalField:
    """Normals of organised points from a (2r+1)² window of valid neighbours (integral images).

    Args:
        points_grid: (H, W, 3) points [m] on the image grid (any value where not valid).
        valid: (H, W) bool.
        radius_px: window half-width r in grid cells.
        viewpoint: (3,) point the normals face (default: the origin, i.e. the camera).
        min_count: fewest valid points in a window for a normal.

    Returns:
        A :class:`NormalField` over the valid cells, in ``np.nonzero(valid)`` order.
    """
    if points_grid.ndim != 3 or points_grid.shape[2] != 3 or valid.shape != points_grid.shape[:2]:
        raise CloudError(f"points_grid must be (H, W, 3) with valid (H, W), got {points_grid.shape}, {valid.shape}")
    if int(radius_px) != radius_px or radius_px < 1:
        raise ConfigError(f"radius_px must be a positive integer, got {radius_px!r}")
    vp = np.zeros(3) if viewpoint is None else np.asarray(viewpoint, dtype=np.float64)
    h, w = valid.shape
    vi, ui = np.nonzero(valid)
    pts = points_grid[vi, ui].astype(np.float64)
    if pts.shape[0] == 0:
        empty = np.empty((0, 3))
        return NormalField(empty, np.empty(0), np.empty(0, dtype=bool))
    # Centre on the mean so that the second moments do not cancel catastrophically.
    mean = pts.mean(axis=0)
    c = pts - mean
    x, y, z = c[:, 0], c[:, 1], c[:, 2]
    moments = np.zeros((h + 1, w + 1, 10))
    moments[vi + 1, ui + 1] = np.stack(
        [np.ones_like(x), x, y, z, x * x, x * y, x * z, y * y, y * z, z * z], axis=1
    )
    integral = moments.cumsum(axis=0).cumsum(axis=1)
    r = int(radius_px)
    top = np.clip(vi - r, 0, h)
    bot = np.clip(vi + r + 1, 0, h)
    lef = np.clip(ui - r, 0, w)
    rig = np.clip(ui + r + 1, 0, w)
    s = integral[bot, rig] - integral[top, rig] - integral[bot, lef] + integral[top, lef]
    n = s[:, 0]
    inv = 1.0 / np.maximum(n, 1.0)
    mx, my, mz = s[:, 1] * inv, s[:, 2] * inv, s[:, 3] * inv
    cov = np.empty((pts.shape[0], 3, 3))
    cov[:, 0, 0] = s[:, 4] * inv - mx * mx
    cov[:, 0, 1] = cov[:, 1, 0] = s[:, 5] * inv - mx * my
    cov[:, 0, 2] = cov[:, 2, 0] = s[:, 6] * inv - mx * mz
    cov[:, 1, 1] = s[:, 7] * inv - my * my
    cov[:, 1, 2] = cov[:, 2, 1] = s[:, 8] * inv - my * mz
    cov[:, 2, 2] = s[:, 9] * inv - mz * mz
    return _finish(cov, n, pts, vp, min_count)


def covariances_knn(points: np.ndarray, k: int, *, workers: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(covariances (N, 3, 3), neighbour indices (N, k+1) including the point itself)."""
    _, idx = cKDTree(points).query(points, k=k + 1, workers=workers)
    nb = points[idx]
    d = nb - nb.mean(axis=1, keepdims=True)
    return np.einsum("nki,nkj->nij", d, d) / (k + 1), idx


def knn_normals(
    points: np.ndarray, k: int = 16, *, viewpoint: np.ndarray | None = None, workers: int = 1
) -> NormalField:
    """PCL *NormalEstimation* with k nearest neighbours (the point itself included, as PCL does)."""
    if int(k) != k or k < 3:
        raise ConfigError(f"k must be an integer ≥ 3 (a plane needs 3 points), got {k!r}")
    pts = validate_points(points, min_points=int(k) + 1)
    vp = np.zeros(3) if viewpoint is None else np.asarray(viewpoint, dtype=np.float64)
    cov, _ = covariances_knn(pts, int(k), workers=workers)
    return _finish(cov, np.full(pts.shape[0], k + 1), pts, vp, 3)
