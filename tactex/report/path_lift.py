"""A path on a surface lifted off it for a WebGL page, so that the cloud's markers do not hide it.

plotly draws a 3-D scene with a depth test, and a marker is a square sprite at the depth of its centre:
a line lying on the surface is covered by every marker whose centre is a little nearer the eye, that
is by most of the markers beside it on an oblique view, and a path over a dense cloud disappears.
Lifted along the surface normal by a fraction of the cloud's size (a few pixels at the first view),
the line is nearer the eye than the markers around it from any view of that side of the surface.

Where the cloud carries no normals (a scan from a file with x, y, z only) they are estimated from the
path point's nearest cloud points, which does not tell the two sides of the surface apart: the path
is then drawn on both sides, one copy in front whichever side is looked at.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["LIFT_SHARE", "NORMAL_NEIGHBOURS", "lift_path"]

#: The lift as a share of the cloud's bounding-box diagonal: at the first view (the whole cloud in
#: ~1000 px) 0.5 % is ~5 px, more than a marker's and the line's half widths together.
LIFT_SHARE = 0.005
#: Cloud points whose principal axes give a path point's normal where the cloud has none.
NORMAL_NEIGHBOURS = 16


def _fitted_normals(points: np.ndarray, tree: cKDTree, path: np.ndarray) -> np.ndarray:
    """(T, 3) unit normals of the cloud at each path point, unoriented: the least principal axis of
    its :data:`NORMAL_NEIGHBOURS` nearest cloud points."""
    k = min(NORMAL_NEIGHBOURS, points.shape[0])
    if k < 3:  # too few points to span a plane: lift along z
        return np.tile([0.0, 0.0, 1.0], (path.shape[0], 1))
    _, idx = tree.query(path, k=k)
    near = points[idx.reshape(path.shape[0], k)]
    near = near - near.mean(axis=1, keepdims=True)
    _, _, vt = np.linalg.svd(near, full_matrices=False)
    return vt[:, -1, :]


def lift_path(path: np.ndarray, points: np.ndarray, normals: np.ndarray | None,
              lift_m: float | None = None) -> np.ndarray:
    """The path (T, 3) [m] moved off the cloud's surface by ``lift_m`` [m] along its normal.

    Args:
        path: the path's points [m]; NaN rows (breaks between pieces) stay NaN.
        points: (N, 3) the cloud [m].
        normals: (N, 3) the cloud's oriented unit normals, or None: the path is then lifted to both
            sides, as two copies with a NaN row between them (2T + 1 rows).
        lift_m: the lift [m]; None → :data:`LIFT_SHARE` of the cloud's bounding-box diagonal.
    """
    if lift_m is None:
        lift_m = LIFT_SHARE * float(np.linalg.norm(np.ptp(points, axis=0)))
    ok = np.isfinite(path).all(axis=1)
    tree = cKDTree(points)
    n = np.zeros_like(path)
    if normals is not None:
        _, idx = tree.query(path[ok])
        n[ok] = normals[idx]
        return path + lift_m * n
    n[ok] = _fitted_normals(points, tree, path[ok])
    return np.vstack([path + lift_m * n, np.full((1, 3), np.nan), path - lift_m * n])
