"""The wipe's force-motion policy: the §III sinusoid of its config, a policy file (``policy``), or a
policy object from Python, checked against what the wipe allows before the arm moves.

Reach: the wipe starts above a height field at (0, start_y_m) in the object frame with the tool's x
along the object's x and its y along the object's −y (``TOOL_DOWN``); a policy's offsets laid flat
on the object's footprint from there must stay on it (on a curved surface the tangent plane's
offsets cover less ground than that). Beside a cup's wall it starts at mid-height on the −y side,
x along the wall, y down it: u must stay within the wall's arc length, the height within the wall."""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np

from tactex.control.safety import MAX_FORCE_SET_POINT_N
from tactex.errors import ConfigError
from tactex.pointcloud.shapes import CylinderWallSurface, HeightFieldSurface
from tactex.sim.part import object_or_part
from tactex.tasks.policies import (
    ForceMotionPolicy,
    ForceRamp,
    PolicyLimits,
    SinusoidPolicy,
    check_policy,
    load_policy_file,
    sample_policy,
)
from tactex.tasks.runner import TOOL_DOWN

__all__ = ["POLICY_CALL_BUDGET_S", "check_policy_call_time", "check_sinusoid", "check_wipe_policy", "policy_segments",
           "wipe_limits", "wipe_policy"]

# ``cfg`` below is a ``tactex.tasks.wipe.WipeConfig`` (typed Any: wipe imports this module)


def wipe_limits(cfg: Any) -> PolicyLimits:
    """Speed, acceleration, force range and reach a wipe allows a policy."""
    surface = object_or_part(cfg.object_name, cfg.units).surface
    inside, hint, start = None, f"the {cfg.object_name}'s surface", ""
    if isinstance(surface, CylinderWallSurface):
        half_arc_m = np.deg2rad(min(surface.arc_deg, 360.0)) / 2 * surface.radius_m
        z0, top = 0.5 * surface.height_m, surface.height_m
        # the pad stands on its edge against the wall: its centre cannot come nearer the table than its radius
        bottom = cfg.scene().tool.pad_radius_m
        hint = (f"the {cfg.object_name}'s wall (its arc, and its height with the pad's centre at least the pad's "
                f"radius, {1e3 * bottom:.0f} mm, above the table)")

        def inside(u: np.ndarray, v: np.ndarray) -> np.ndarray:  # u along the wall, v down it
            z = z0 - np.asarray(v)
            return (np.abs(np.asarray(u)) <= half_arc_m) & (z >= bottom) & (z <= top)
    elif isinstance(surface, HeightFieldSurface):
        y0 = cfg.start_y_m
        start = f"--start-y-m moves it along the part's y, from {y0:g} m now"

        def inside(u: np.ndarray, v: np.ndarray) -> np.ndarray:
            return surface.inside(np.asarray(u), y0 - np.asarray(v))
    return PolicyLimits(max_speed_m_s=cfg.policy_max_speed_m_s, max_accel_m_s2=cfg.policy_max_accel_m_s2,
                        min_force_n=cfg.contact_threshold_n, max_force_n=MAX_FORCE_SET_POINT_N, inside=inside,
                        reach_hint=hint, start_hint=start)


def wipe_policy(cfg: Any, policy: ForceMotionPolicy | None = None) -> ForceMotionPolicy:
    """The policy a wipe runs: ``policy`` if given, else ``cfg.policy``'s file, else the §III
    sinusoid of ``cfg`` (amplitude_m, omega_rad_s, drift_m_s at force_n) for the whole run."""
    if policy is not None:
        return policy
    if cfg.policy:
        return load_policy_file(cfg.policy)
    return SinusoidPolicy(math.inf, ForceRamp(cfg.force_n, cfg.force_n), cfg.amplitude_m, cfg.omega_rad_s,
                          cfg.drift_m_s)


def check_wipe_policy(cfg: Any, policy: ForceMotionPolicy) -> float:
    """Refuse (one-line :class:`ConfigError`) a policy the wipe does not allow: see :func:`wipe_limits`.
    The surface must be a height field (the wipe starts above it, tool down). Returns the wall time of one
    call of the policy's ``at``, its 99th percentile [s]."""
    if not isinstance(policy, ForceMotionPolicy):
        raise ConfigError(f"policy must be a ForceMotionPolicy (tactex.tasks.policies), got {type(policy).__name__}")
    if not isinstance(object_or_part(cfg.object_name, cfg.units).surface, (HeightFieldSurface, CylinderWallSurface)):
        raise ConfigError(f"a policy wipe starts above a height-field surface or beside a cup's wall; "
                          f"'{cfg.object_name}' is neither")
    return check_policy(policy, wipe_limits(cfg), horizon_s=cfg.duration_s)


#: A policy's ``at`` may take this long per call [s]: the wipe calls it at every tick of the robot's 1 ms
#: cycle, beside the controller, whose whole answer must come within a few hundred microseconds.
POLICY_CALL_BUDGET_S = 2e-4


def check_policy_call_time(call_s: float, robot: bool) -> None:
    """A policy whose ``at`` takes more than :data:`POLICY_CALL_BUDGET_S` per call (``call_s`` [s], the 99th
    percentile the check measured): refused for a robot, whose cycle it would break; a warning in simulation,
    which it only slows."""
    if call_s <= POLICY_CALL_BUDGET_S:
        return
    text = (f"the policy takes {1e3 * call_s:.2f} ms per call of at() (99th percentile); the wipe calls it at every "
            f"1 ms tick of the robot's cycle, beside the controller: keep it under {1e3 * POLICY_CALL_BUDGET_S:g} ms "
            "(compute what you can before the run)")
    if robot:
        raise ConfigError(text)
    warnings.warn(text, stacklevel=3)


#: The sinusoid's path is checked against the part every this often [s] (a circle of omega 2 rad/s: every 1.1 deg).
REACH_STEP_S = 0.01


def check_sinusoid(cfg: Any) -> None:
    """Refuse (one-line :class:`ConfigError`, naming the options) the §III sinusoid of ``cfg`` when it presses less
    than the contact threshold, or is faster, accelerates harder or reaches further within ``cfg.duration_s`` than
    the wipe allows a policy file
    (:func:`wipe_limits`; the reach only on a height field or a cup's wall, where it is known). Its in-plane
    speed peaks at amplitude·ω + drift [m/s], its acceleration at amplitude·ω² [m/s²]."""
    if cfg.force_n < cfg.contact_threshold_n:
        raise ConfigError(f"--force-n {cfg.force_n:g} N is below --contact-threshold-n {cfg.contact_threshold_n:g} N: "
                          "the wipe would press less than what it counts as contact; raise --force-n")
    a, w, d = float(cfg.amplitude_m), float(cfg.omega_rad_s), float(cfg.drift_m_s)
    shape = f"--amplitude-m {a:g} --omega-rad-s {w:g} --drift-m-s {d:g}"
    speed, accel = a * w + d, a * w * w
    if speed > cfg.policy_max_speed_m_s:
        raise ConfigError(f"the sinusoid ({shape}) slides at up to {speed:.3f} m/s (amplitude·ω + drift), over "
                          f"--policy-max-speed-m-s {cfg.policy_max_speed_m_s:g}; lower --omega-rad-s, --amplitude-m or "
                          "--drift-m-s (metres and m/s: 0.04 is 40 mm)")
    if accel > cfg.policy_max_accel_m_s2:
        raise ConfigError(f"the sinusoid ({shape}) accelerates at {accel:.2f} m/s² (amplitude·ω²), over "
                          f"--policy-max-accel-m-s2 {cfg.policy_max_accel_m_s2:g}; lower --omega-rad-s or "
                          "--amplitude-m")
    surface = object_or_part(cfg.object_name, cfg.units).surface
    if not isinstance(surface, (HeightFieldSurface, CylinderWallSurface)):
        return
    limits = wipe_limits(cfg)
    s = sample_policy(wipe_policy(cfg), float(cfg.duration_s), REACH_STEP_S)
    t, u, v = s["t"], s["u"], s["v"]
    ok = np.asarray(limits.inside(u, v), dtype=bool)
    if np.all(ok):
        return
    i = int(np.flatnonzero(~ok)[0])
    fix = "make it smaller or shorten the run (--duration-s)"
    if isinstance(surface, HeightFieldSurface):
        # the nearest start along the object's y (centimetre steps) from which the whole path stays on it
        starts = np.round(np.arange(-0.5, 0.5, 0.01), 2)
        for y0 in starts[np.argsort(np.abs(starts - cfg.start_y_m), kind="stable")]:
            if np.all(surface.inside(u, y0 - v)):
                fix = f"start at --start-y-m {y0:g} (the whole path fits there), or {fix}"
                break
    start = f" from --start-y-m {cfg.start_y_m:g}" if isinstance(surface, HeightFieldSurface) else ""
    raise ConfigError(f"the sinusoid ({shape}) leaves {limits.reach_hint} at t = {t[i]:.2f} s of --duration-s "
                      f"{cfg.duration_s:g}{start} (offset u, v = {1e3 * u[i]:.0f}, {1e3 * v[i]:.0f} mm from the "
                      f"start); {fix}")


def policy_segments(policy: ForceMotionPolicy, run_s: float, log: Any) -> list[dict]:
    """Per segment of ``policy`` that started within ``run_s`` [s]: its kind and times [s], and over its
    contact ticks (the wipe's log: forces, force_sets, segments, aligned_errors, aligned_segments) the
    force MAE against the policy's own set point [N], the highest force over the set point [-], and
    the aligned motion MAE per base axis [m]."""
    kinds = [getattr(s, "kind", "") for s in getattr(policy, "segments", [policy])]
    starts = [t for t in policy.segment_starts_s if t < run_s]
    f, f_set, seg = np.asarray(log.forces), np.asarray(log.force_sets), np.asarray(log.segments, dtype=int)
    err, seg_al = np.asarray(log.aligned_errors).reshape(-1, 3), np.asarray(log.aligned_segments, dtype=int)
    out = []
    for k, t0 in enumerate(starts):
        t1 = starts[k + 1] if k + 1 < len(starts) else run_s
        mask, mask_al = seg == k, seg_al == k
        e = err[mask_al]
        out.append({
            "kind": kinds[k] if k < len(kinds) else "", "start_s": t0, "end_s": t1,
            "contact_ticks": int(mask.sum()),
            "force_mae_n": float(np.mean(np.abs(f[mask] - f_set[mask]))) if mask.any() else float("nan"),
            "max_force_over_set_point": float(np.max(f[mask] / f_set[mask])) if mask.any() else float("nan"),
            "motion_mae_m": np.mean(np.abs(e), axis=0).tolist() if len(e) else [float("nan")] * 3,
        })
    return out


#: The tool facing a cup's wall from its −y side: x along the wall's tangent (world x), y down the wall,
#: z into the wall (object frame).
TOOL_AT_WALL = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def _rot_x(deg: float) -> np.ndarray:
    a = np.deg2rad(deg)
    return np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])


def wipe_start_pose(cfg: Any, surface: Any, obj_pos: np.ndarray, obj_rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The wipe's start [m, rotation]: ``start_height_m`` off the surface, out of contact, the tool
    tilted ``start_tilt_deg`` about the world x axis from the surface's normal. Above a height field at
    (0, start_y_m) with the tool pointing down; beside a cup's wall, facing it from its −y side at
    mid-height, the tool horizontal."""
    if isinstance(surface, CylinderWallSurface):
        point = np.array([0.0, -surface.radius_m, 0.5 * surface.height_m])
        p_start = obj_pos + obj_rot @ (point + np.array([0.0, -cfg.start_height_m, 0.0]))
        return p_start, _rot_x(cfg.start_tilt_deg) @ obj_rot @ TOOL_AT_WALL
    z_surf = float(surface.project(np.array([[0.0, cfg.start_y_m, 0.0]]))[0][0, 2])
    p_start = obj_pos + obj_rot @ np.array([0.0, cfg.start_y_m, z_surf]) + np.array([0.0, 0.0, cfg.start_height_m])
    return p_start, _rot_x(cfg.start_tilt_deg) @ TOOL_DOWN
