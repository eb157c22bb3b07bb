"""``sinusoid``: VA-UFIC §III-A's wiping policy, the default of ``tactex wipe``.

    x_d(t) = [A sin ωt, A (cos ωt − 1) − d t] m in the tool frame,

a circle of radius A [m] at ω [rad/s] drifting along the tool's −y at d [m/s]."""

from __future__ import annotations

import math

from tactex.tasks.policies.base import ForceRamp, PolicySegment

__all__ = ["SinusoidPolicy", "sinusoid_xy"]


def sinusoid_xy(t: float, amplitude_m: float, omega: float, drift_m_s: float) -> tuple[float, float, float, float]:
    """The policy's non-zero components as Python floats (the wipe evaluates it every tick):
    x_d's x and y [m], then its rate's x and y [m/s]; both have z = 0."""
    s, c = math.sin(omega * t), math.cos(omega * t)
    return (amplitude_m * s, amplitude_m * (c - 1.0) - drift_m_s * t,
            amplitude_m * omega * c, -amplitude_m * omega * s - drift_m_s)


class SinusoidPolicy(PolicySegment):
    """The §III sinusoid; ``duration_s`` may be ``math.inf`` (the task's duration ends it)."""

    kind = "sinusoid"
    fields = ("amplitude_m", "omega_rad_s", "drift_m_s")

    def __init__(self, duration_s: float, force: ForceRamp, amplitude_m: float = 0.04, omega_rad_s: float = 2.0,
                 drift_m_s: float = 0.005) -> None:
        super().__init__(duration_s, force)
        self.amplitude_m, self.omega_rad_s, self.drift_m_s = amplitude_m, omega_rad_s, drift_m_s

    def path(self, t_s: float) -> tuple[float, float, float, float]:
        return sinusoid_xy(t_s, self.amplitude_m, self.omega_rad_s, self.drift_m_s)
