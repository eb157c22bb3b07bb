"""The surface normal where the tool axis meets a segment, from a quadric fitted to it.

PCA (:mod:`tactex.perception.pca`) gives the normal of a segment's best plane, which on a curved part is
the normal near the segment's centroid. The wrist camera sees the surface around the pad, not under it,
and from one side: on a cylinder of a few centimetres' radius the centroid lies millimetres to centimetres
off the tool axis, where the normal is degrees to tens of degrees from the one under the tool. A controller
re-orienting to that normal turns the tool away from the contact's normal, its pressing force then pushes
the tool round the part, the camera's view moves with it, and the tool rolls off the wall. Fitting
w = a u² + b uv + c v² + d u + e v + f in the PCA frame (u, v along e1, e2, w along the normal) and taking
the fitted surface's normal where the tool axis crosses it removes that offset; on a plane the fit is the
plane and the normal PCA's.
"""

from __future__ import annotations

import numpy as np

from tactex.perception.pca import SegmentPca

__all__ = ["MIN_POINTS", "normal_at_axis"]

#: Fewest segment points for the six-parameter fit.
MIN_POINTS = 12
#: The fitted normal is refused (PCA's kept) when it is this far from PCA's [rad]: a fit that far off is
#: fitting noise or a second surface, not the curvature of one.
MAX_TURN_RAD = np.radians(35.0)


def normal_at_axis(points: np.ndarray, pca: SegmentPca, axis_origin: np.ndarray, axis_dir: np.ndarray
                   ) -> np.ndarray:
    """The unit outward normal (the side of ``pca.normal``) of the quadric fitted to ``points`` (N, 3) where
    the line ``axis_origin + s·axis_dir`` crosses it, all in one frame; ``pca.normal`` when the segment is
    too small, the axis runs along the surface, or the fit is degenerate or implausible. The crossing is
    clamped to the segment's extent: the fit is not extrapolated."""
    pts = np.asarray(points, dtype=np.float64)
    normal, e1, e2, c = pca.normal, pca.e1, pca.e2, pca.centroid
    across = float(np.asarray(axis_dir, dtype=np.float64) @ normal)
    if pts.shape[0] < MIN_POINTS or abs(across) < 0.2:
        return normal
    d = pts - c
    u, v, w = d @ e1, d @ e2, d @ normal
    design = np.column_stack([u * u, u * v, v * v, u, v, np.ones_like(u)])
    coef, _, rank, _ = np.linalg.lstsq(design, w, rcond=None)
    if rank < 6 or not np.isfinite(coef).all():
        return normal
    a, b, cc, du, dv, _ = coef.tolist()
    origin, direction = np.asarray(axis_origin, dtype=np.float64), np.asarray(axis_dir, dtype=np.float64)
    hit = origin - float((origin - c) @ normal) / across * direction  # the axis meets the PCA plane
    u0 = float(np.clip((hit - c) @ e1, u.min(), u.max()))
    v0 = float(np.clip((hit - c) @ e2, v.min(), v.max()))
    gu, gv = 2.0 * a * u0 + b * v0 + du, b * u0 + 2.0 * cc * v0 + dv
    fitted = normal - gu * e1 - gv * e2
    fitted /= np.linalg.norm(fitted)
    if float(fitted @ normal) < np.cos(MAX_TURN_RAD):
        return normal
    return fitted
