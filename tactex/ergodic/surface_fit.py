"""The explorer's local surface: the agent projected on a fitted sphere or plane (TEC eq. 23–29).

:func:`tactex.geometry.fit.fit_sphere_or_plane` fits the patch; here the agent's point is projected
onto it with the normal on the agent's side (eq. 27–28), the tangent plane gets its orthonormal
basis (eq. 29), and the raw source's plane slope is solved. The per-step cases (sphere, plane) run on
Python floats through the float rules the compiled step shares (:mod:`.compiled_step`): three
numbers do not pay numpy's per-call overhead.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from tactex.ergodic.compiled_step import plane_slope, project_floats, tangent_floats
from tactex.ergodic.gradient import PLANE_PIVOT_RTOL
from tactex.geometry.fit import SurfacePatch, fit_sphere_or_plane

__all__ = ["PATCH_KINDS", "normal_at", "plane_slope_checked", "project_local", "project_on_patch", "tangent_basis",
           "tangent_matrix", "tangent_matrix_0uv"]

#: The patch kinds :func:`~tactex.ergodic.compiled_step.project_floats` takes, by its code.
PATCH_KINDS = {"sphere": 0, "plane": 1}


def tangent_matrix(n: np.ndarray | tuple) -> np.ndarray:
    """(3, 2) orthonormal tangent basis [t_u, t_v] with (t_u, t_v, n) right-handed (n an array or 3 floats)."""
    return tangent_matrix_0uv(n)[:, 1:]


def tangent_matrix_0uv(n: np.ndarray | tuple) -> np.ndarray:
    """(3, 3) [0, t_u, t_v]: :func:`tangent_matrix` after a zero column (offsets · it = rows (0, u, v))."""
    a0, a1, a2, b0, b1, b2 = tangent_floats(*(n if isinstance(n, tuple) else n.tolist()))
    return np.array([[0.0, a0, b0], [0.0, a1, b1], [0.0, a2, b2]])


def tangent_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tangent basis (t_u, t_v) of the unit normal n (3,), two (3,) arrays."""
    t = tangent_matrix(n)
    return t[:, 0].copy(), t[:, 1].copy()


def plane_slope_checked(a00: float, a01: float, a02: float, a11: float, a12: float, a22: float,
                        b0: float, b1: float, b2: float) -> tuple[float, float] | None:
    """:func:`~tactex.ergodic.compiled_step.plane_slope` (c_u, c_v), or None when the block is not positive
    definite (collinear points)."""
    ok, c_u, c_v = plane_slope(a00, a01, a02, a11, a12, a22, b0, b1, b2, PLANE_PIVOT_RTOL)
    return (c_u, c_v) if ok else None


def project_on_patch(patch: SurfacePatch, x: tuple, ref: tuple) -> tuple[tuple, tuple]:
    """:func:`project_local` on Python floats: x and ref are 3-tuples, so are the point and normal.

    Sphere and plane (the per-step cases) in Python floats (:func:`~tactex.ergodic.compiled_step.project_floats`,
    which the compiled step shares): three numbers do not pay numpy's per-call overhead; the other
    kinds, and a point at a sphere's centre, go through :meth:`SurfacePatch.project`.
    """
    kind = PATCH_KINDS.get(patch.kind)
    if kind is not None:
        ok, p0, p1, p2, n0, n1, n2 = project_floats(
            kind, *patch.center.tolist(), patch.radius, *patch.direction.tolist(), *x, *ref
        )
        if ok:
            return (p0, p1, p2), (n0, n1, n2)
    refa = np.array(ref)
    p, n = patch.project(np.array(x), refa)
    return tuple(p.tolist()), tuple((n if float(n @ refa) >= 0.0 else -n).tolist())


def project_local(patch: SurfacePatch, x: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest point of the patch to x and the unit normal there, oriented along ``ref``."""
    p, n = project_on_patch(patch, tuple(x.tolist()), tuple(ref.tolist()))
    return np.array(p), np.array(n)


def normal_at(points: np.ndarray, tree: cKDTree, n_neighbors: int, x: np.ndarray,
              ref: np.ndarray) -> np.ndarray:
    """Unit normal (3,) at x [m] of the patch fitted to its ``n_neighbors`` nearest cloud points, along ``ref``."""
    nb = tree.query(x, k=n_neighbors)[1]
    return project_local(fit_sphere_or_plane(points[nb], validate=False), x, ref)[1]
