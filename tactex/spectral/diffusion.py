"""Heat diffusion on a cloud: spectral acceleration (TEC eq. 19) and implicit Euler as the reference.

Both integrate u̇ = −M⁻¹ L u over one step δt = α h² (eq. 21) with zero-flux (Neumann) boundaries,
so both preserve the integral ∫u = 1ᵀ M u. The spectral step costs O(N K) per call; the
implicit one a sparse triangular solve (exact, no truncation of the spectrum, but first order in δt).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from tactex.errors import ConfigError, InputError
from tactex.spectral.basis import LaplaceBasis

__all__ = ["ImplicitDiffusion", "SpectralDiffusion", "diffusion_timestep"]


def _positive(value: float, name: str, unit: str, allow_zero: bool = False) -> float:
    v = float(value)
    if not np.isfinite(v) or v < 0.0 or (v == 0.0 and not allow_zero):
        bound = "≥ 0" if allow_zero else "> 0"
        raise ConfigError(f"{name} must be a finite number {bound}{unit}, got {value}")
    return v


def diffusion_timestep(alpha: float, spacing: float) -> float:
    """δt = α h² [m²] (TEC eq. 21): α [1] sets local (small) vs global (large) exploration, h [m]."""
    return _positive(alpha, "alpha", "") * _positive(spacing, "spacing", " [m]") ** 2


def _check_field(u: np.ndarray, n: int) -> np.ndarray:
    arr = np.asarray(u, dtype=np.float64)
    if arr.ndim not in (1, 2) or arr.shape[0] != n:
        raise InputError(f"the field to diffuse must have shape ({n},) or ({n}, B), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise InputError("the field to diffuse holds NaN/inf values")
    return arr


class SpectralDiffusion:
    """One diffusion step in the truncated eigenbasis: u' = Φ (e^{−λ δt} ⊙ Φᵀ M u) (TEC eq. 19).

    Args:
        basis: the cloud's Laplace basis.
        dt: time step δt [m²] (the Laplacian is in 1/m², so δt = α h² carries m²), ≥ 0.
    """

    def __init__(self, basis: LaplaceBasis, dt: float) -> None:
        self.basis = basis
        self.dt = _positive(dt, "dt", " [m²]", allow_zero=True)
        self.decay = np.exp(-basis.evals * self.dt)
        # Φᵀ M precomputed once: a step is then two dense mat-vecs.
        self._analysis = np.ascontiguousarray((basis.evecs * basis.mass[:, None]).T)
        self._synthesis = np.ascontiguousarray(basis.evecs)

    @classmethod
    def from_alpha(cls, basis: LaplaceBasis, alpha: float) -> SpectralDiffusion:
        """The step δt = α h² with h the basis spacing (TEC eq. 21)."""
        return cls(basis, diffusion_timestep(alpha, basis.spacing))

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """Diffuse u (N,) or (N, B) by one step; returns a new array."""
        arr = _check_field(u, self.basis.n_points)
        coeffs = self._analysis @ arr
        coeffs *= self.decay if arr.ndim == 1 else self.decay[:, None]
        return self._synthesis @ coeffs


class ImplicitDiffusion:
    """One implicit-Euler diffusion step u' = (M + δt L)⁻¹ M u, factorised once (sparse LU).

    With ``substeps`` = n the step δt is split into n implicit steps of δt/n, which converges to
    the exact flow e^{−δt M⁻¹L} u as n grows (the reference the spectral step is tested against).

    Args:
        L: (N, N) weak Laplacian.
        M: (N, N) diagonal mass matrix [m²] or its (N,) diagonal.
        dt: time step δt [m²], ≥ 0.
        substeps: implicit sub-steps per call, ≥ 1.
    """

    def __init__(self, L: sp.spmatrix, M: sp.spmatrix | np.ndarray, dt: float, substeps: int = 1) -> None:
        self.dt = _positive(dt, "dt", " [m²]", allow_zero=True)
        if isinstance(substeps, bool) or not isinstance(substeps, (int, np.integer)) or substeps < 1:
            raise ConfigError(f"substeps must be an integer ≥ 1, got {substeps!r}")
        self.substeps = int(substeps)
        mass = np.asarray(M.diagonal() if sp.issparse(M) else M, dtype=np.float64).ravel()
        n = L.shape[0]
        if L.shape != (n, n) or mass.shape != (n,):
            raise InputError(f"L must be square and M match it, got L {L.shape} and M diagonal {mass.shape}")
        self.mass = mass
        self._lu = sla.splu(sp.csc_matrix(sp.diags(mass) + (self.dt / self.substeps) * L))

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """Diffuse u (N,) or (N, B) by one step; returns a new array."""
        arr = _check_field(u, self.mass.shape[0])
        mass = self.mass if arr.ndim == 1 else self.mass[:, None]
        for _ in range(self.substeps):
            arr = self._lu.solve(np.asfortranarray(mass * arr))
        return arr
