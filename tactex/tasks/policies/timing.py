"""Time scalings shared by the policy kinds: a minimum-jerk ramp from rest to rest, and a polyline
followed leg by leg with one."""

from __future__ import annotations

import bisect
import itertools
import math

__all__ = ["min_jerk", "polyline_at"]


def min_jerk(tau: float) -> tuple[float, float]:
    """The minimum-jerk ramp s(τ) = 10τ³ − 15τ⁴ + 6τ⁵ on τ ∈ [0, 1] and ds/dτ; zero rate and
    acceleration at both ends, so segments built on it join without a jump."""
    tau = min(max(tau, 0.0), 1.0)
    t2 = tau * tau
    return t2 * tau * (10.0 - 15.0 * tau + 6.0 * t2), 30.0 * t2 * (1.0 - tau) ** 2


def polyline_at(points: list[tuple[float, float]], duration_s: float,
                t_s: float) -> tuple[float, float, float, float]:
    """Offset u, v [m] and rate [m/s] at ``t_s`` [s] along ``points`` (the first is (0, 0)), each leg
    a minimum-jerk ramp whose share of ``duration_s`` is its share of the length: the tool stops at
    each corner, so the path has no velocity jump."""
    lengths = [math.dist(a, b) for a, b in itertools.pairwise(points)]
    total = sum(lengths)
    if total <= 0.0:
        return points[0][0], points[0][1], 0.0, 0.0
    ends, acc = [], 0.0
    for length in lengths:
        acc += length
        ends.append(duration_s * acc / total)
    i = min(bisect.bisect_left(ends, t_s), len(lengths) - 1)
    t0 = ends[i - 1] if i else 0.0
    span = ends[i] - t0
    if span <= 0.0:
        return points[i + 1][0], points[i + 1][1], 0.0, 0.0
    s, ds = min_jerk((t_s - t0) / span)
    (ax, ay), (bx, by) = points[i], points[i + 1]
    dx, dy = bx - ax, by - ay
    return ax + s * dx, ay + s * dy, ds * dx / span, ds * dy / span
