"""Exploration metrics: normalised ergodicity (TEC eq. 48) and the coverage residual.

* :func:`normalized_ergodicity` — eq. 48, ε = ‖max(p̂ − ĉ, 0)‖₂ / N(p̂), with target and coverage
  normalised to unit integral (∫ f = Σ m_i f_i with the mass-matrix diagonal m, or plain sums
  without it). The paper's ``∫p`` in the denominator is 1 after that normalisation, which would
  leave ε in units of 1/√points; ``normalize="l2"`` (default) divides by ‖p̂‖₂ instead so that
  ε = 1 before any coverage and 0 when the coverage covers the target (the scale of the paper's
  figures); ``normalize="integral"`` is the literal form.
* :func:`coverage_residual` — what the authors' released code reports:
  ‖max(p̂ − c̃, 0)‖₂ / ‖p̂‖₂ with p̂ the target normalised to unit sum and c̃ the accumulated,
  un-normalised footprint sum. A point touched once by the footprint has c̃ ≥ φ(r_a) ≫ p̂_i, so
  for a uniform target this is √(share of target points never inside an agent's footprint).
"""

from __future__ import annotations

import numpy as np

from tactex.errors import ExplorationError, InputError

__all__ = ["coverage_residual", "normalized_ergodicity"]


def _as_field(name: str, value: np.ndarray, n: int | None = None) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 1 or (n is not None and arr.shape[0] != n):
        raise InputError(f"{name} must have shape ({n if n is not None else 'N'},), got {arr.shape}")
    if not np.all(np.isfinite(arr)) or (arr.size and arr.min() < 0):
        raise InputError(f"{name} must be finite and ≥ 0")
    return arr


def normalized_ergodicity(
    target: np.ndarray, coverage: np.ndarray, mass: np.ndarray | None = None, normalize: str = "l2"
) -> float:
    """Eq. 48 for a target (N,) and a coverage (N,) (any scale; both are normalised here)."""
    p = _as_field("target", target)
    c = _as_field("coverage", coverage, p.shape[0])
    m = np.ones_like(p) if mass is None else _as_field("mass", mass, p.shape[0])
    pint = float(m @ p)
    if pint <= 0:
        raise ExplorationError("the target has no mass: eq. 48 is undefined; give a target with p > 0 somewhere")
    p_hat = p / pint
    cint = float(m @ c)
    c_hat = c / cint if cint > 0 else np.zeros_like(c)
    err = float(np.linalg.norm(np.maximum(p_hat - c_hat, 0.0)))
    if normalize == "l2":
        return err / float(np.linalg.norm(p_hat))
    if normalize == "integral":
        return err / float(m @ p_hat)
    raise InputError(f"normalize must be 'l2' or 'integral', got {normalize!r}")


def coverage_residual(target: np.ndarray, footprint_sum: np.ndarray) -> float:
    """‖max(p̂ − c̃, 0)‖₂ / ‖p̂‖₂ with p̂ = target / Σ target and c̃ the raw footprint sum."""
    p = _as_field("target", target)
    c = _as_field("footprint_sum", footprint_sum, p.shape[0])
    total = float(p.sum())
    if total <= 0:
        raise ExplorationError("the target has no mass: the coverage residual is undefined")
    p_hat = p / total
    return float(np.linalg.norm(np.maximum(p_hat - c, 0.0)) / np.linalg.norm(p_hat))
