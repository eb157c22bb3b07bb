"""Checking a policy against what the task allows, before the arm moves.

Sampled every ``dt_s`` over the policy: what ``at`` returns (a :class:`PolicyPoint` of finite floats, and no
exception), the speed and acceleration in the tangent plane against the task's limits (the speed both as the
policy's rates say and as its offsets move: the offsets move the reference, the rates feed its velocity, and
the two must agree), the force set point within [contact threshold, safety maximum] (a samples file's own
values, with their line), the velocity at each join (a jump there must be blended: ``blend_s``), and the path
within the object's reach (a predicate on the offsets). The first violation is raised as one line naming the
segment and the field to change. How long a call takes is measured and returned: ``at`` runs in the
robot's 1 ms cycle."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tactex.errors import ConfigError
from tactex.tasks.policies.base import ForceMotionPolicy, PolicySegment, point_problem
from tactex.tasks.policies.sequence import PolicySequence

__all__ = ["PolicyLimits", "check_policy", "sample_policy"]

#: A velocity change at a join above this, unblended, is refused [m/s].
MAX_JOIN_JUMP_M_S = 0.01
#: A policy's offset at t = 0 may be this far from (0, 0) [m]: the reach is checked from the start pose.
START_TOLERANCE_M = 1e-4
#: The policy's rates may differ from how fast its offsets move by this share of the speed limit, plus
#: MAX_JOIN_JUMP_M_S (a join's allowed jump, which a central difference halves) [-].
RATE_AGREEMENT = 0.1


@dataclass(frozen=True)
class PolicyLimits:
    """What a task allows a policy: in-plane speed [m/s] and acceleration [m/s²], the force set
    point's range [N], and optionally ``inside(u, v) -> bool array`` for the offsets [m] it can reach."""

    max_speed_m_s: float
    max_accel_m_s2: float
    min_force_n: float
    max_force_n: float
    inside: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    reach_hint: str = "the object"
    #: how the start is moved, if it can be (e.g. an option), for the reach refusal
    start_hint: str = ""


def sample_policy(policy: ForceMotionPolicy, horizon_s: float, dt_s: float = 0.002) -> dict[str, np.ndarray]:
    """The policy every ``dt_s`` [s] over [0, horizon_s]: t, u, v, du, dv, force, segment, and ``call_s``, the
    99th percentile of one call's wall time [s] (the loop meets the slow calls, not the mean). A call that
    raises, or returns anything but a :class:`PolicyPoint` of finite floats, is a :class:`ConfigError` naming
    the time."""
    t = np.arange(0.0, horizon_s + 0.5 * dt_s, dt_s)
    rows = []
    took = np.empty(len(t))
    clock = time.perf_counter
    for k, x in enumerate(t.tolist()):
        t0 = clock()
        try:
            point = policy.at(x)
        except Exception as exc:
            raise ConfigError(f"the policy's at({x:.3f}) raised {type(exc).__name__}: {exc}") from exc
        took[k] = clock() - t0
        if (problem := point_problem(point)) is not None:
            raise ConfigError(f"at t = {x:.3f} s the policy's {problem}")
        rows.append(point)
    call_s = float(np.percentile(took, 99))
    pts = np.array(rows, dtype=float)
    return {"t": t, "u": pts[:, 0], "v": pts[:, 1], "du": pts[:, 2], "dv": pts[:, 3], "force": pts[:, 4],
            "segment": np.array([policy.segment_index(float(x)) for x in t]), "call_s": call_s}


def _segments(policy: ForceMotionPolicy) -> list[PolicySegment]:
    if isinstance(policy, PolicySequence):
        return policy.segments
    return [policy] if isinstance(policy, PolicySegment) else []


def _name(policy: ForceMotionPolicy, k: int) -> str:
    segs = _segments(policy)
    kind = segs[k].kind if k < len(segs) else type(policy).__name__
    return f"segment {k + 1} ({kind})"


def _shape_field(policy: ForceMotionPolicy, k: int) -> str:
    segs = _segments(policy)
    fields = segs[k].fields if k < len(segs) else ()
    return "/".join(fields[:2]) or "the path"


def _speed_fix(policy: ForceMotionPolicy, k: int) -> str:
    """What to change for a segment too fast: a kind's duration, or a samples file's times."""
    segs = _segments(policy)
    if k < len(segs) and segs[k].kind == "samples":
        return "spread its samples over more time (t_s) or make its path shorter (u_m, v_m)"
    return f"lengthen duration_s or shorten {_shape_field(policy, k)}"


def _check_sample_forces(policy: ForceMotionPolicy, limits: PolicyLimits, horizon_s: float) -> None:
    """A samples file's own force values within ``horizon_s`` [s] of the policy, with their line (the sampled
    check would quote interpolated ones)."""
    starts = policy.segment_starts_s
    for k, seg in enumerate(_segments(policy)):
        samples = getattr(seg, "samples", None) if seg.kind == "samples" else None
        if samples is None:
            continue
        t, f = np.asarray(samples)[:, 0], np.asarray(samples)[:, 3]
        runs = starts[k] + (t - t[0]) <= horizon_s + 1e-9  # the samples the run reaches
        bad = np.flatnonzero(runs & ((f < limits.min_force_n - 1e-9) | (f > limits.max_force_n + 1e-9)))
        if bad.size:
            i = int(bad[0])
            where = f"file '{seg.source}' " if getattr(seg, "source", "") else ""
            line = getattr(seg, "lines", np.arange(2, len(f) + 2))[i]
            raise ConfigError(f"{_name(policy, k)}: {where}line {line}: force_n = {f[i]:g} N is outside "
                              f"[{limits.min_force_n:g}, {limits.max_force_n:g}] N (the contact threshold and the "
                              "safety maximum)")


def check_policy(policy: ForceMotionPolicy, limits: PolicyLimits, horizon_s: float | None = None,
                 dt_s: float = 0.002) -> float:
    """Raise a :class:`ConfigError` on the first thing the task does not allow (module docstring); else return
    the 99th percentile of the wall time of one call of the policy's ``at`` [s]."""
    horizon = policy.duration_s if horizon_s is None else min(horizon_s, policy.duration_s)
    if not math.isfinite(horizon) or horizon <= 0:
        raise ConfigError(f"the policy needs a finite, positive duration to be checked, got {horizon!r} s")
    _check_sample_forces(policy, limits, horizon)
    s = sample_policy(policy, horizon, dt_s)
    seg = s["segment"]
    f = s["force"]
    bad = np.flatnonzero(~np.isfinite(f) | (f < limits.min_force_n - 1e-9) | (f > limits.max_force_n + 1e-9))
    if bad.size:
        i = int(bad[0])
        raise ConfigError(f"{_name(policy, seg[i])}: force_n = {f[i]:g} N at t = {s['t'][i]:.2f} s is outside "
                          f"[{limits.min_force_n:g}, {limits.max_force_n:g}] N (the contact threshold and the "
                          "safety maximum)")
    if not (np.all(np.isfinite(s["u"])) and np.all(np.isfinite(s["v"]))
            and np.all(np.isfinite(s["du"])) and np.all(np.isfinite(s["dv"]))):
        i = int(np.flatnonzero(~np.isfinite(s["u"] + s["v"] + s["du"] + s["dv"]))[0])
        raise ConfigError(f"{_name(policy, seg[i])}: the path is not a finite number at t = {s['t'][i]:.2f} s")
    if math.hypot(s["u"][0], s["v"][0]) > START_TOLERANCE_M:
        raise ConfigError(f"{_name(policy, seg[0])}: at t = 0 the policy's offset is u, v = {1e3 * s['u'][0]:.1f}, "
                          f"{1e3 * s['v'][0]:.1f} mm: offsets are from where the policy starts, (0, 0) at t = 0 "
                          "(subtract its first point)")
    if isinstance(policy, PolicySequence) and policy.blend_s == 0.0:
        for k, (a, b) in enumerate(zip(policy.segments[:-1], policy.segments[1:], strict=True), start=1):
            ea, sb = a.at(a.duration_s), b.at(0.0)
            jump = math.hypot(sb.du_m_s - ea.du_m_s, sb.dv_m_s - ea.dv_m_s)
            if jump > MAX_JOIN_JUMP_M_S:
                raise ConfigError(f"{_name(policy, k)}: duration_s: its velocity jumps by {jump:.3f} m/s from the "
                                  f"segment before (more than {MAX_JOIN_JUMP_M_S:g}); set blend_s > 0 at the top of "
                                  "the file to blend the join")
    speed = np.hypot(s["du"], s["dv"])
    bad = np.flatnonzero(speed > limits.max_speed_m_s)
    if bad.size:
        i = int(bad[0])
        raise ConfigError(f"{_name(policy, seg[i])}: duration_s: speed {speed[i]:.3f} m/s at t = {s['t'][i]:.2f} s "
                          f"exceeds the task's {limits.max_speed_m_s:g} m/s; {_speed_fix(policy, seg[i])}")
    if len(s["t"]) > 1:
        # the offsets move the reference: how fast they move, and whether the rates say the same
        moved_u, moved_v = np.gradient(s["u"], dt_s), np.gradient(s["v"], dt_s)
        moved = np.hypot(moved_u, moved_v)
        bad = np.flatnonzero(moved > limits.max_speed_m_s)
        if bad.size:
            i = int(bad[0])
            raise ConfigError(f"{_name(policy, seg[i])}: its offsets u, v move at {moved[i]:.3f} m/s at t = "
                              f"{s['t'][i]:.2f} s (a jump, or a path faster than its rates say), over the task's "
                              f"{limits.max_speed_m_s:g} m/s; {_speed_fix(policy, seg[i])}")
        gap = np.hypot(moved_u - s["du"], moved_v - s["dv"])
        bad = np.flatnonzero(gap > RATE_AGREEMENT * limits.max_speed_m_s + MAX_JOIN_JUMP_M_S)
        if bad.size:
            i = int(bad[0])
            raise ConfigError(f"{_name(policy, seg[i])}: at t = {s['t'][i]:.2f} s its rates du, dv = "
                              f"{s['du'][i]:.3f}, {s['dv'][i]:.3f} m/s are not how its offsets move "
                              f"({moved_u[i]:.3f}, {moved_v[i]:.3f} m/s): at() must return the rates of its own path")
    acc = np.hypot(np.gradient(s["du"], dt_s), np.gradient(s["dv"], dt_s))
    bad = np.flatnonzero(acc > limits.max_accel_m_s2)
    if bad.size:
        i = int(bad[0])
        near_join = isinstance(policy, PolicySequence) and any(
            abs(s["t"][i] - t0) <= 0.5 * policy.blend_s + 2 * dt_s for t0 in policy.segment_starts_s[1:])
        fix = "lengthen blend_s" if near_join else f"lengthen duration_s or shorten {_shape_field(policy, seg[i])}"
        raise ConfigError(f"{_name(policy, seg[i])}: {'blend_s' if near_join else 'duration_s'}: acceleration "
                          f"{acc[i]:.2f} m/s² at t = {s['t'][i]:.2f} s exceeds the task's "
                          f"{limits.max_accel_m_s2:g} m/s²; {fix}")
    if limits.inside is not None:
        ok = np.asarray(limits.inside(s["u"], s["v"]), dtype=bool)
        if not np.all(ok):
            i = int(np.flatnonzero(~ok)[0])
            raise ConfigError(f"{_name(policy, seg[i])}: {_shape_field(policy, seg[i])}: the path leaves "
                              f"{limits.reach_hint} at t = {s['t'][i]:.2f} s (offset u, v = {1e3 * s['u'][i]:.0f}, "
                              f"{1e3 * s['v'][i]:.0f} mm from the start); make it smaller or move the start"
                              + (f" ({limits.start_hint})" if limits.start_hint else ""))
    return float(s["call_s"])
