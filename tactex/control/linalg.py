"""Small dense solves on the 1 kHz path.

On a 7×7 system ``numpy.linalg.solve`` spends several times longer in its wrapper (type checks,
broadcasting set-up) than in LAPACK, and a control tick makes several such solves. :func:`solve`
calls LAPACK's ``dgesv`` (the routine numpy uses) directly: the same LU with partial pivoting, the same answer.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg.lapack import dgesv

__all__ = ["solve"]


def solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x with a·x = b for a square float64 ``a`` (n, n) and ``b`` (n,) or (n, k); ``a`` and ``b``
    are not modified. Raises numpy.linalg.LinAlgError when ``a`` is singular, as numpy does."""
    _lu, _piv, x, info = dgesv(a, b)
    if info != 0:
        raise np.linalg.LinAlgError("Singular matrix" if info > 0 else f"dgesv: illegal argument {-info}")
    return x
