"""Joint-space damping applied implicitly over one control period, so that it cannot ring at 1 kHz.

An explicit damping torque −B·q̇ computed from the state at the start of a tick and held for the
tick's dt is a forward-Euler step of M·q̈ = −B·q̇. On any motion mode whose inertia m is below
B·dt/2 that step overshoots: q̇ changes sign every tick and grows, a 500 Hz chatter that only the
torque-rate limiter (or a reflex on a real arm) stops. The Franka's wrist is such a mode: the
rotation about the flange axis has ~0.005 kg·m² with a tool, so 10 N·m·s/rad (TEC's angular
damping) gives B·dt/m ≈ 2.

The implicit (backward-Euler) form B_dt = M (M + dt·B)⁻¹ B is the series combination of B with
M/dt: it equals B on heavy modes, never exceeds M/dt on light ones, and stays symmetric positive
semi-definite, so it is as passive as B.
"""

from __future__ import annotations

import numpy as np

from tactex.control.linalg import solve

__all__ = ["implicit_damping_torque", "latency_shaped_torque"]


def implicit_damping_torque(mass_matrix: np.ndarray, damping: np.ndarray, dq: np.ndarray, dt: float) -> np.ndarray:
    """−B_dt·q̇ [N·m] for joint inertia ``mass_matrix`` (n, n) [kg·m²], joint-space damping ``damping``
    (n, n) [N·m·s/rad], joint velocity ``dq`` (n,) [rad/s] and control period ``dt`` [s]."""
    m = mass_matrix
    return -(m @ solve(m + dt * damping, damping @ dq))


def latency_shaped_torque(mass_matrix: np.ndarray, tau: np.ndarray, damping: np.ndarray,
                          stiffness: np.ndarray | None, horizon_s: float) -> np.ndarray:
    """M (M + h·B + h²·K)⁻¹ τ [N·m]: an impedance torque ``tau`` = −K·e − B·q̇ + … computed from the
    state at the start of a tick, made safe for a command that acts only one or two ticks later.

    This is the implicit ("stable PD") form of the impedance over a horizon h = ``horizon_s`` [s]:
    on a mode of inertia m, stiffness k and damping b it acts as the gains k·m/(m + h·b + h²·k) and
    b·m/(m + h·b + h²·k), so dt·b_eff/m ≤ dt/h and dt²·k_eff/m ≤ (dt/h)², whatever b and k are. With a
    command delay of d ticks the loop v⁺ = v − g·v₋d is stable only for g < 2 sin(π/(2(2d+1))) (1 for
    d = 1, 0.618 for d = 2); h = 3·dt caps g at 1/3. On heavy modes (m ≫ h·b, h²·k) the torque is τ
    unchanged; the matrix is invertible, so the torque vanishes only where τ does (the
    equilibria stay). ``mass_matrix``, ``damping``, ``stiffness``: (n, n) [kg·m², N·m·s/rad,
    N·m/rad]; ``stiffness`` None for none.
    """
    a = mass_matrix + horizon_s * damping
    if stiffness is not None:
        a = a + (horizon_s * horizon_s) * stiffness
    return mass_matrix @ solve(a, tau)
