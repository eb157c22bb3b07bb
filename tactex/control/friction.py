"""Tangential contact-force compensation from the wrist F/T sensor (wiping, VA-UFIC §III).

A pad sliding on a surface with Coulomb friction μ under a pressing force f_n is held back by
μ·f_n against its velocity. A compliance controller of translational stiffness K then lags its
moving set point by μ·f_n / K: 0.4 · 15 N / 1000 N/m = 6 mm with Table I's K_max — more than the
tracking target, and K_max is already the paper's bound, so stiffer is not an option.

The sensor sees that force directly: ``wrench_tool[:2]`` is the tangential force the tool exerts
on the surface, equal and opposite to the friction on the tool. Feeding it forward,

    f_comp = ρ_align · g · sat_{μ_max·f_n}( LP_fc( [f_x, f_y] ) ),

cancels the friction the controller would otherwise fight with its spring, without guessing μ or
the friction direction (a model μ̂·f_n·v̂_d feed-forward is wrong in both whenever the pad sticks,
turns or crosses a slope). Its parts and why:

* LP_fc: first-order low-pass of the measured force (sensor noise; the friction direction turns at
  the policy's 2 rad/s, so a 10 Hz cut-off lags it by ~2°).
* sat: the compensation never exceeds the Coulomb cone μ_max·f_n of the measured normal force, so
  it vanishes with the contact and no tangential measurement (a collision, a bias) is amplified
  beyond what friction could be.
* ρ_align: it scales with the variable stiffness (eq. 19, K_C,t = ρ_align R K_max,t Rᵀ): while the
  contact monitor makes the robot compliant the tool must yield to the surface, not push through.
* g ≤ 1: a measured-force feedback of unit gain is, while the pad sticks, an integrator of the
  spring force (it ramps until the pad breaks away); g < 1 bounds that loop's DC gain to g/(1−g).

The wrench is active (it pushes along the motion, ẋᵀf_comp > 0 while sliding), so VA-UFIC applies
it through the impedance tank's port (``VaUficController(port_feedforward=...)``): the tank pays
for it and the valve σ_i shuts it off when the tank runs low, like the damping feed-forward.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tactex.config import param
from tactex.control.state import RobotState
from tactex.errors import ConfigError, ControllerFault

__all__ = ["FrictionCompensator", "FrictionCompensatorParams"]


@dataclass(frozen=True)
class FrictionCompensatorParams:
    """Measured tangential-force compensation (see the module docstring)."""

    gain: float = param(0.9, "fraction g of the measured tangential contact force fed forward, 0 ≤ g ≤ 1 [-]")
    cutoff_hz: float = param(10.0, "first-order low-pass cut-off on the measured tangential force [Hz]")
    mu_max: float = param(1.0, "Coulomb-cone bound: |f_comp| ≤ μ_max · measured normal force [-]")
    max_force_n: float = param(20.0, "absolute bound on |f_comp| [N]")

    def __post_init__(self) -> None:
        if not (math.isfinite(self.gain) and 0.0 <= self.gain <= 1.0):
            raise ConfigError(f"FrictionCompensatorParams.gain must lie in [0, 1], got {self.gain!r}")
        for name in ("cutoff_hz", "mu_max", "max_force_n"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f"FrictionCompensatorParams.{name} must be a finite number > 0, got {v!r}")


class FrictionCompensator:
    """Tool-frame compensation wrench [N] from the measured tangential contact force.

    Call :meth:`wrench_tool` once per control tick; it is the ``port_feedforward`` hook of
    :class:`~tactex.control.va_ufic.VaUficController`.
    """

    def __init__(self, params: FrictionCompensatorParams | None = None) -> None:
        self.params = params or FrictionCompensatorParams()
        self._f = (0.0, 0.0)  # low-passed tangential force, tool frame [N]
        self._a, self._a_dt = 0.0, float("nan")  # the filter's gain and the period it was made for
        self._started = False
        self._last = (0.0,) * 6

    def reset(self) -> None:
        self._f = (0.0, 0.0)
        self._started = False
        self._last = (0.0,) * 6

    @property
    def last(self) -> np.ndarray:
        """(6,) the last compensation wrench [N, N·m] (tool frame)."""
        return np.array(self._last)

    def wrench_tool(self, state: RobotState, rho_align: float, dt: float) -> tuple[float, ...]:
        """The wrench in the tool frame [N, N·m], ``(f_x, f_y, 0, 0, 0, 0)`` as six Python floats.

        ``rho_align`` ∈ [0, 1] scales it (eq. 19); ``dt`` [s] is the tick period.
        """
        fx, fy, fz, _, _, _ = state.wrench_tool.tolist()
        if not (math.isfinite(fx) and math.isfinite(fy) and math.isfinite(fz)):
            raise ControllerFault(f"friction compensation got a non-finite measured force {state.wrench_tool[:3]!r}")
        if not (math.isfinite(rho_align) and 0.0 <= rho_align <= 1.0):
            raise ControllerFault(f"friction compensation needs ρ_align in [0, 1], got {rho_align!r}")
        if not (math.isfinite(dt) and dt > 0):
            raise ControllerFault(f"friction compensation needs a tick period dt > 0 [s], got {dt!r}")
        p = self.params
        # the filter state as Python floats: at 1 kHz, numpy indexing on a 2-vector costs more than the sums
        if self._started:
            if dt != self._a_dt:
                self._a, self._a_dt = 1.0 - math.exp(-2.0 * math.pi * p.cutoff_hz * dt), dt
            a = self._a
            f0, f1 = self._f
            f0, f1 = f0 + a * (fx - f0), f1 + a * (fy - f1)
        else:  # start from the first measurement, not from zero (no artificial transient)
            f0, f1 = fx, fy
            self._started = True
        self._f = (f0, f1)
        bound = min(p.max_force_n, p.mu_max * max(fz, 0.0))
        mag = math.hypot(f0, f1)
        scale = p.gain * rho_align * (min(1.0, bound / mag) if mag > 0.0 else 0.0)
        out = (scale * f0, scale * f1, 0.0, 0.0, 0.0, 0.0)
        self._last = out
        return out
