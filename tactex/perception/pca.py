"""PCA of a surface segment: n_s^c, e1, e2, local curvature l_s and orientation error θ.

VA-UFIC §II-B: the eigenvectors of the segment covariance Σ = [e1; e2; n_s^c] (eigenvalues
λ1 ≥ λ2 ≥ λ3) give the long edge e1, the short edge e2 and the normal n_s^c; the local
curvature is ``l_s = |λ3 / tr Σ|`` (eq. 16), 0 for a plane and at most 1/3.

Sign conventions (the paper leaves them open; PCA eigenvectors have no sign):

- ``normal`` points out of the surface, toward the camera (n·(camera − centroid) > 0);
- (e1, e2, normal) is right-handed: e2 = normal × e1;
- θ (eq. 15) is the angle between the tool axis z_tool and the *inward* normal −n_s, so that an
  aligned tool (z_tool = −n_s, pressing into the surface) has θ = 0. With the paper's camera
  (its z axis along the tool axis, n = [0, 0, 1] in eq. 14) this is eq. 15,
  θ = |acos(n_s^cᵀ n)|, with n_s^c taken as the inward normal.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from tactex.errors import CloudError

__all__ = ["SegmentPca", "local_curvature", "orientation_error", "segment_pca"]


class SegmentPca(NamedTuple):
    """PCA of one segment, in the frame of the input points.

    Attributes:
        centroid: (3,) [m].
        normal: (3,) unit n_s (smallest-variance direction), toward the viewpoint.
        e1: (3,) unit long-edge direction (largest variance).
        e2: (3,) unit short-edge direction, e2 = normal × e1.
        eigenvalues: (3,) λ1 ≥ λ2 ≥ λ3 of Σ [m²].
        curvature: l_s = |λ3 / tr Σ| (eq. 16).
    """

    centroid: np.ndarray
    normal: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    eigenvalues: np.ndarray
    curvature: float


def local_curvature(eigenvalues: np.ndarray) -> float:
    """Eq. 16: l_s = |λ3 / tr Σ| with λ3 the smallest eigenvalue."""
    lam = np.asarray(eigenvalues, dtype=np.float64)
    tr = float(lam.sum())
    if not tr > 0:
        raise CloudError(f"the covariance has trace {tr}; the segment has no extent")
    return abs(float(lam.min()) / tr)


def segment_pca(points: np.ndarray, viewpoint: np.ndarray | None = None) -> SegmentPca:
    """PCA of a segment's points (N ≥ 3, not all collinear); Σ is normalised by N (as PCL)."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 3:
        raise CloudError(f"segment PCA needs (N ≥ 3, 3) points, got shape {pts.shape}")
    if not np.isfinite(pts).all():
        raise CloudError("segment points hold NaN/inf")
    centroid = pts.mean(axis=0)
    d = pts - centroid
    cov = np.einsum("ni,nj->ij", d, d) / pts.shape[0]  # not BLAS: no thread pool for a 3×3 result
    lam, vec = np.linalg.eigh(cov)  # ascending
    if not lam[1] > 1e-12 * max(lam[2], 1e-300):
        raise CloudError("segment points are collinear (or coincide): no normal is defined")
    normal, e1 = vec[:, 0], vec[:, 2]
    vp = np.zeros(3) if viewpoint is None else np.asarray(viewpoint, dtype=np.float64)
    if normal @ (vp - centroid) < 0:
        normal = -normal
    e2 = np.cross(normal, e1)
    return SegmentPca(centroid, normal, e1, e2, lam[::-1].copy(), local_curvature(lam))


def orientation_error(normal: np.ndarray, tool_axis: np.ndarray) -> float:
    """Eq. 15: θ = acos(−n_s · z_tool) [rad] in [0, π]; both unit vectors in the same frame,
    n_s pointing out of the surface (θ = 0 when the tool presses straight into it)."""
    c = float(np.clip(-np.dot(normal, tool_axis), -1.0, 1.0))
    return float(abs(np.arccos(c)))
