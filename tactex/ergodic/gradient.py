"""Gradient of a field sampled around the agent: weighted cubic fit on the tangent plane (eq. 32–33).

The field values at the neighbours are heights over their projections (u, v) on the tangent
plane; a bivariate cubic fitted by weighted least squares gives the gradient analytically. The
monomial order is fixed by :data:`CUBIC_EXPONENTS`; :func:`cubic_gradient` differentiates every
term (the authors' released code drops terms of ∂/∂v, which a finite-difference test exposes).
"""

from __future__ import annotations

import numpy as np

from tactex.errors import InputError

__all__ = ["CUBIC_EXPONENTS", "cubic_features", "cubic_gradient", "cubic_value", "fit_cubic"]

#: (i, j) of the monomials u^i v^j, in coefficient order.
CUBIC_EXPONENTS = ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2), (3, 0), (2, 1), (1, 2), (0, 3))
_I = np.array([e[0] for e in CUBIC_EXPONENTS])
_J = np.array([e[1] for e in CUBIC_EXPONENTS])
_DEG = _I + _J
#: Ridge relative to the trace of the normal matrix: keeps a rank-deficient fit (collinear or
#: fewer than 10 neighbours) finite without biasing a well-posed one beyond ~1e-12.
RIDGE_RTOL = 1e-12
#: Relative Cholesky pivot below which the source's weighted plane fit is rank-deficient (collinear points).
PLANE_PIVOT_RTOL = 1e-10


def cubic_features(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Monomials u^i v^j of :data:`CUBIC_EXPONENTS`, shape (n, 10)."""
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    u2, v2 = u * u, v * v
    return np.stack([np.ones_like(u), u, v, u2, u * v, v2, u2 * u, u2 * v, u * v2, v2 * v], axis=-1)


def fit_cubic(uv: np.ndarray, values: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Coefficients (10,) of the cubic minimising Σ w_i (f(u_i, v_i) − y_i)² (eq. 32).

    Solved in coordinates scaled by the largest |(u, v)| (the monomials span six orders of
    magnitude at millimetre scale otherwise) and mapped back, with a tiny ridge so that a
    degenerate design still returns finite coefficients.
    """
    uv = np.asarray(uv, dtype=np.float64)
    y = np.asarray(values, dtype=np.float64)
    if uv.ndim != 2 or uv.shape[1] != 2 or y.shape != (uv.shape[0],):
        raise InputError(f"fit_cubic needs uv (n, 2) and values (n,), got {uv.shape} and {y.shape}")
    w = np.ones(uv.shape[0]) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != y.shape or not (np.all(np.isfinite(w)) and np.all(w >= 0)):
        raise InputError("fit_cubic weights must be finite, ≥ 0 and of shape (n,)")
    return _fit_cubic(uv, y, w)


def _fit_cubic(uv: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    scale = float(np.max(np.abs(uv))) if uv.size else 1.0
    if scale == 0.0:
        scale = 1.0
    x = cubic_features(uv[:, 0] / scale, uv[:, 1] / scale)
    xw = x * w[:, None]
    a = xw.T @ x
    b = xw.T @ y
    a[np.diag_indices(10)] += RIDGE_RTOL * (np.trace(a) + 1e-300)
    coef = np.linalg.solve(a, b)
    return coef / scale**_DEG


def cubic_value(coef: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """f(u, v) for coefficients ``coef`` (10,)."""
    return cubic_features(u, v) @ np.asarray(coef)


def cubic_gradient(coef: np.ndarray, u: np.ndarray | float, v: np.ndarray | float) -> np.ndarray:
    """Analytic (∂f/∂u, ∂f/∂v) at (u, v); shape (..., 2)."""
    c = np.asarray(coef, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    du = c[1] + 2 * c[3] * u + c[4] * v + 3 * c[6] * u * u + 2 * c[7] * u * v + c[8] * v * v
    dv = c[2] + c[4] * u + 2 * c[5] * v + c[7] * u * u + 2 * c[8] * u * v + 3 * c[9] * v * v
    return np.stack([du, dv], axis=-1)
