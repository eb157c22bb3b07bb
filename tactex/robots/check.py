"""``tactex robot check``: is this robot reachable, set up as tactex expects, and does the link hold 1 kHz?

Like libfranka's ``communication_test`` it runs a torque loop for a while and counts the cycles the
robot reports lost (its ``Duration`` between two states) and the lowest
``control_command_success_rate``; unlike it, the loop holds the current posture with tactex's joint
impedance behind the safety layer (not zero torque, which lets an arm with a misdeclared load
drift), so the arm stays where it is. ``bare`` holds with seven floats per tick instead
(:meth:`LibfrankaBackend.bare_hold`): the link's floor. ``dry_run`` only reads states and never starts
torque control.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tactex.control import joint_kernels
from tactex.errors import ConfigError, RobotError, SensorFault
from tactex.robots.libfranka_backend import FrankaConfig, LibfrankaBackend, _col_major, connecting_line, flange_T_tcp
from tactex.sim.tool import ToolGeometry

__all__ = ["LINK_MAX_LOST_FRACTION", "LINK_MIN_SUCCESS_RATE", "CheckResult", "check_robot", "link_verdict",
           "lost_fraction"]

#: The link holds 1 kHz when the robot loses at most this share of cycles ...
LINK_MAX_LOST_FRACTION = 0.001
#: ... and its command success rate never drops below this (libfranka aborts motions well below it).
LINK_MIN_SUCCESS_RATE = 0.95
#: Our compute per tick must stay below this at p99.9 [µs]: the rest of the 0.5 ms budget is the network's.
COMPUTE_BUDGET_US = 300.0


@dataclass
class CheckResult:
    """What the check found; ``ok`` is the verdict, ``problems`` says why not."""

    ok: bool
    info: dict[str, Any] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def lost_fraction(metrics: dict[str, Any]) -> float:
    """The share of the link's cycles that were lost, from ``loop_metrics()``."""
    lost = metrics["lost_cycles"]
    return lost / (max(1, metrics["loop_ticks"]) + lost)


def link_verdict(metrics: dict[str, Any], duration_s: float, max_lost_fraction: float = LINK_MAX_LOST_FRACTION,
                 min_success_rate: float = LINK_MIN_SUCCESS_RATE) -> tuple[list[str], list[str]]:
    """Problems and warnings from a link test's ``loop_metrics()`` over ``duration_s`` [s].

    A problem fails the check: more than ``max_lost_fraction`` of the cycles lost, or a command
    success rate below ``min_success_rate``. Our compute above :data:`COMPUTE_BUDGET_US`
    at p99.9 is only a warning: the link may still hold, with less margin.
    """
    problems: list[str] = []
    warnings: list[str] = []
    lost, share = metrics["lost_cycles"], lost_fraction(metrics)
    if share > max_lost_fraction:
        problems.append(f"{lost} cycles lost in {duration_s:g} s ({100 * share:.2f} %, "
                        f"allowed {100 * max_lost_fraction:.2g} %): the link would not hold 1 kHz")
    if metrics["min_command_success_rate"] < min_success_rate:
        problems.append(f"command success rate fell to {metrics['min_command_success_rate']:.3f} "
                        f"(needs ≥ {min_success_rate:g}): commands came late")
    if metrics["loop_compute_us"]["p99.9"] > COMPUTE_BUDGET_US:
        warnings.append(f"our compute per tick reached {metrics['loop_compute_us']['p99.9']:.0f} µs at p99.9 "
                        f"(budget {COMPUTE_BUDGET_US:.0f}): a busy or unpinned CPU (docs/real_robot.md)")
    return problems, warnings


def check_robot(config: FrankaConfig, duration_s: float = 10.0, tool: ToolGeometry | None = None,
                note=None, max_lost_fraction: float = LINK_MAX_LOST_FRACTION,
                min_success_rate: float = LINK_MIN_SUCCESS_RATE, bare: bool = False) -> CheckResult:
    """Connect, report the robot's set-up and state, run the link test for ``duration_s`` [s].

    ``bare``: the link test holds with :meth:`LibfrankaBackend.bare_hold` (Franka's example joint
    impedance in 7 Python floats) instead of tactex's joint controller behind the safety layer: the
    link's floor, to tell the PC and network's share of a failure from tactex's.

    The link fails when more than ``max_lost_fraction`` [0, 1) of its cycles are lost or the command
    success rate falls below ``min_success_rate`` [0, 1] (see :func:`link_verdict`).
    """
    if not 0.0 <= max_lost_fraction < 1.0:
        raise ConfigError(f"the allowed share of lost cycles must be in [0, 1), got {max_lost_fraction}")
    if not 0.0 <= min_success_rate <= 1.0:
        raise ConfigError(f"the lowest command success rate must be in [0, 1], got {min_success_rate}")
    if bare and config.dry_run:
        raise ConfigError("--bare holds the arm with torques: it cannot run in a dry run (drop --dry-run)")
    tool = tool or ToolGeometry()
    if note is not None:
        note(connecting_line(config.robot_ip))
    t0 = time.perf_counter()
    backend = LibfrankaBackend(config, tool=tool)
    info: dict[str, Any] = {"robot_ip": config.robot_ip, "connect_s": time.perf_counter() - t0}
    problems: list[str] = []
    warnings: list[str] = []
    latency = backend.cpu_latency  # read before close releases it
    latency_held, latency_text, latency_denied = latency.held, latency.description, latency.permission_denied
    try:
        fs = backend._franka_state
        state = backend.state()
        f_T_ee = _col_major(fs.F_T_EE, 4, 4)
        info.update({
            "robot_mode": str(fs.robot_mode),
            "current_errors": str(fs.current_errors) if bool(fs.current_errors) else "",
            "q_rad": state.q.tolist(),
            "tcp_position_m": state.ee_position.tolist(),
            "tcp_offset_error_m": float(np.abs(f_T_ee - flange_T_tcp(tool)).max()),
            "load_mass_kg": float(fs.m_load),
            "mass_matrix_diag": np.diag(state.mass_matrix).tolist(),
            "gravity_n_m": state.gravity.tolist(),
            "wrench_tool": state.wrench_tool.tolist(),
            "wrench_source": backend.wrench.name,
        })
        if info["current_errors"]:
            problems.append(f"the robot reports errors: {info['current_errors']} (clear them in Desk)")
        if info["tcp_offset_error_m"] > 1e-6:
            problems.append("the robot did not take the tool's end-effector frame (set_EE)")
        if not np.isfinite(state.wrench_tool).all():
            problems.append("the wrench source gives no finite reading")
        if note is not None:
            doing = "reading" if config.dry_run else "holding (bare)" if bare else "holding"
            note(f"connected in {info['connect_s'] * 1e3:.0f} ms; {doing} for {duration_s:g} s")
        info["bare"] = bare
        try:
            if bare:
                backend.bare_hold(duration_s)
            else:
                from tactex.robots.loop import ControlLoop

                ControlLoop(backend).hold(duration_s)
        except (RobotError, SensorFault) as exc:
            problems.append(str(exc))
        m = backend.loop_metrics()
        info.update(m)
        # the last state read, also when the hold ended early
        q_drift = float(np.abs(np.asarray(backend._franka_state.q) - state.q).max())
        info["q_drift_rad"] = q_drift
        info["lost_fraction"] = lost_fraction(m)
        info["max_lost_fraction"] = max_lost_fraction
        link_problems, link_warnings = link_verdict(m, duration_s, max_lost_fraction, min_success_rate)
        problems += link_problems
        warnings += link_warnings
    finally:
        backend.close()
    if config.cpu_latency_us >= 0 and not latency_held:
        fix = ("let your user write /dev/cpu_dma_latency (docs/real_robot.md, CPU idle states)" if latency_denied
               else "this system offers no PM QoS device; limit idle states in the BIOS or with the kernel's "
                    "idle= / processor.max_cstate= options instead")
        warnings.append(f"{latency_text}: each wait for the robot may end with an idle-exit delay; {fix}")
    if joint_kernels.kernels() is None:
        warnings.append("the controllers' compiled kernels are not available (install the fast extra: numba): "
                        "every contact tick then does its joint-space algebra in numpy, slower")
    return CheckResult(ok=not problems, info=info, problems=problems, warnings=warnings)
