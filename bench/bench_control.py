"""Controller tick time (incl. safety layer and tanks): median and 99th percentile per controller.

States are synthetic but realistic in shape (7 joints, random full-rank Jacobian, a pressing
wrench with noise, a slowly moving reference, a SurfaceEstimate for VA-UFIC); only the call
``SafetyLayer(controller).torque(state, reference)`` is timed.

``tick_us_*`` is the compute time of a tick, measured with the thread's CPU clock
(CLOCK_THREAD_CPUTIME_ID), so that time the scheduler gives to other processes on a shared
machine does not count; ``wall_us_*`` is the wall-clock time of the same ticks, for reference.
"""

from __future__ import annotations

import os
import time

import numpy as np

from tactex.control import (
    CartesianImpedanceController,
    GaLineForceController,
    LineForceReference,
    PoseForceReference,
    RobotState,
    SafetyLayer,
    UficController,
    VaUficController,
)
from tactex.geometry import exp_so3
from tactex.perception.estimate import SurfaceEstimate

TARGETS = {f"control.{name}.tick_us_median": ("<=", 100.0)
           for name in ("ga_line_force", "ufic", "va_ufic", "cartesian_impedance")}

_DOWN = np.diag([1.0, -1.0, -1.0])


def _states(n: int, seed: int = 0) -> list[RobotState]:
    rng = np.random.default_rng(seed)
    jac = rng.normal(size=(6, 7)) * 0.3
    out = []
    for k in range(n):
        t = k * 1e-3
        rot = exp_so3(np.array([0.05 * np.sin(t), 0.03 * np.cos(t), 0.0])) @ _DOWN
        out.append(RobotState(
            t=t, q=np.array([0.0, 0.0, 0.0, -1.5, 0.0, 1.8, 0.0]) + 0.01 * rng.normal(size=7),
            dq=0.01 * rng.normal(size=7), tau_measured=np.zeros(7),
            ee_position=np.array([0.5 + 0.01 * np.sin(t), 0.0, 0.1]), ee_rotation=rot,
            ee_twist=0.01 * rng.normal(size=6), jacobian=jac + 0.01 * rng.normal(size=(6, 7)),
            mass_matrix=np.eye(7), coriolis=np.zeros(7), gravity=np.zeros(7),
            wrench_tool=np.array([0.0, 0.0, 10.0, 0.0, 0.0, 0.0]) + 0.2 * rng.normal(size=6),
        ))
    return out


def _time(ctrl, states, refs, repeats: int) -> tuple[np.ndarray, np.ndarray]:
    """(CPU µs, wall µs) per tick."""
    ctrl.reset(states[0])
    for s, r in zip(states[:200], refs[:200], strict=True):  # warm-up
        ctrl.torque(s, r)
    ctrl.reset(states[0])
    cpu, wall = [], []
    cpu_clock, wall_clock = time.thread_time_ns, time.perf_counter_ns
    for _ in range(repeats):
        for s, r in zip(states, refs, strict=True):
            w0 = wall_clock()
            c0 = cpu_clock()
            ctrl.torque(s, r)
            c1 = cpu_clock()
            w1 = wall_clock()
            cpu.append(c1 - c0)
            wall.append(w1 - w0)
        ctrl.reset(states[0])
    return np.asarray(cpu, dtype=float) / 1e3, np.asarray(wall, dtype=float) / 1e3


def run(args) -> dict:
    n = 500 if getattr(args, "quick", False) else 3000
    repeats = 1 if getattr(args, "quick", False) else 3
    states = _states(n)
    line_refs = [LineForceReference(np.array([0.5 + 0.01 * np.sin(s.t), 0.0, 0.1]), np.array([0.0, 0.05, 1.0]), 10.0)
                 for s in states]
    f15 = np.array([0.0, 0.0, 15.0, 0.0, 0.0, 0.0])
    pose_refs = [PoseForceReference(np.array([0.5, 0.01 * np.sin(2 * s.t), 0.1]), _DOWN, f15) for s in states]
    va_refs = []
    est = None
    for s in states:
        if est is None or s.t - est.timestamp > 1 / 30:
            normal = np.array([0.0, 0.1, 1.0]) / np.hypot(0.1, 1.0)
            est = SurfaceEstimate(valid=True, timestamp=s.t, normal_world=normal, curvature=0.01, theta_rad=0.1)
        va_refs.append(PoseForceReference(np.array([0.5, 0.01 * np.sin(2 * s.t), 0.1]), _DOWN, f15, surface=est))
    cases = {
        "ga_line_force": (GaLineForceController(), line_refs),
        "ufic": (UficController(), pose_refs),
        "va_ufic": (VaUficController(), va_refs),
        "cartesian_impedance": (CartesianImpedanceController(), pose_refs),
    }
    out = {}
    for name, (ctrl, refs) in cases.items():
        cpu, wall = _time(SafetyLayer(ctrl), states, refs, repeats)
        out[name] = {"tick_us_median": float(np.median(cpu)), "tick_us_p99": float(np.percentile(cpu, 99)),
                     "wall_us_median": float(np.median(wall)), "wall_us_p99": float(np.percentile(wall, 99)),
                     "ticks": int(cpu.size)}
        print(f"   {name}: median {out[name]['tick_us_median']:.1f} µs, p99 {out[name]['tick_us_p99']:.1f} µs (CPU)")
    out["load_average_1min"] = float(os.getloadavg()[0])
    return {"control": out}
