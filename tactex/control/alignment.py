"""Contact-alignment monitor and shaping functions of VA-UFIC §II-B (eq. 17–21, 30).

Pure functions plus one small integrator, so every case of the piecewise definitions is testable.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["AlignmentShaper", "alignment_coefficient", "contact_alignment", "force_shaping", "rho_align_rate"]


def contact_alignment(
    wrench_tool: np.ndarray, pose_error_tool: np.ndarray, theta_rad: float, curvature: float,
    alpha: float, xi: float, gamma: float,
) -> float:
    """C of eq. 17: α·|f_ext^eeᵀ x̃^ee| + ξ·θ + γ·l_s (each term ≥ 0).

    The printed eq. 17 has unbalanced bars; every term is a non-negative magnitude, so we read it
    as the sum of the three absolute contributions (tactile error [N·m], orientation error [rad],
    curvature [-]).
    """
    w, e = wrench_tool, pose_error_tool  # 6 numbers each; Python floats on the 1 kHz path
    tactile = w[0] * e[0] + w[1] * e[1] + w[2] * e[2] + w[3] * e[3] + w[4] * e[4] + w[5] * e[5]
    return alpha * abs(float(tactile)) + xi * abs(theta_rad) + gamma * abs(curvature)


def alignment_coefficient(c: float, c_margin: float) -> float:
    """h = 1 − C / C_m (eq. 18): positive while the contact is aligned within the margin."""
    return 1.0 - c / c_margin


def rho_align_rate(rho_align: float, h: float, rho_min: float) -> float:
    """ρ̇_align of eq. 20 with ρ = h·ρ_align + ρ_min (eq. 21) [1/s]."""
    rho = h * rho_align + rho_min
    # conditional expressions instead of min/max (1 kHz path); they pick the same value, NaN included
    if rho_align >= 1.0:
        return 0.0 if 0.0 < rho else rho  # min(rho, 0)
    if rho_align <= 0.0:
        return 0.0 if 0.0 > rho else rho  # max(rho, 0)
    return rho


class AlignmentShaper:
    """Integrates eq. 20 from ρ_align(0) = 0, keeping ρ_align in [0, 1]."""

    def __init__(self, rho_min: float = 0.001, rho0: float = 0.0) -> None:
        self.rho_min = float(rho_min)
        self.rho0 = float(rho0)
        self.rho = float(rho0)

    def reset(self) -> None:
        self.rho = self.rho0

    def step(self, h: float, dt: float) -> float:
        rho = self.rho + dt * rho_align_rate(self.rho, h, self.rho_min)
        rho = rho if rho > 0.0 else 0.0  # min(1, max(0, ·)) as conditionals (1 kHz path), a NaN gives 0 there too
        self.rho = rho if rho < 1.0 else 1.0
        return self.rho


def force_shaping(wrench_des_tool: np.ndarray, pose_error_tool: np.ndarray, delta_c: float) -> float:
    """ρ_frc of eq. 30: 1 while f_dᵀx̃ ≤ 0; a cosine fade over 0 < x̃_z ≤ δ_c; else 0.

    x̃ = x − x_d in the tool frame: x̃_z > 0 means the tool went past the desired pose along its
    axis without meeting the expected resistance (contact lost or surface further away).
    """
    w, e = wrench_des_tool, pose_error_tool  # 6 numbers each; Python floats on the 1 kHz path
    if w[0] * e[0] + w[1] * e[1] + w[2] * e[2] + w[3] * e[3] + w[4] * e[4] + w[5] * e[5] <= 0.0:
        return 1.0
    ez = float(pose_error_tool[2])
    if 0.0 < ez <= delta_c:
        return 0.5 * (1.0 + math.cos(math.pi * ez / delta_c))
    return 0.0
