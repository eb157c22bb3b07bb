"""``tactex robot check``: is this robot reachable, set up as tactex expects, and does the link hold 1 kHz?

Like libfranka's ``communication_test`` it runs a torque loop for a while and counts the cycles the
robot reports lost (its ``Duration`` between two states) and the lowest
``control_command_success_rate``; unlike it, the loop holds the current posture with tactex's joint
impedance behind the safety layer (not zero torque, which lets an arm with a misdeclared load
drift), so the arm stays where it is. ``dry_run`` only reads states and never starts torque control.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tactex.errors import RobotError, SensorFault
from tactex.robots.libfranka_backend import FrankaConfig, LibfrankaBackend, _col_major, flange_T_tcp
from tactex.sim.tool import ToolGeometry

__all__ = ["LINK_MAX_LOST_FRACTION", "LINK_MIN_SUCCESS_RATE", "CheckResult", "check_robot"]

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


def check_robot(config: FrankaConfig, duration_s: float = 10.0, tool: ToolGeometry | None = None,
                note=None) -> CheckResult:
    """Connect, report the robot's set-up and state, run the link test for ``duration_s`` [s]."""
    tool = tool or ToolGeometry()
    t0 = time.perf_counter()
    backend = LibfrankaBackend(config, tool=tool)
    info: dict[str, Any] = {"robot_ip": config.robot_ip, "connect_s": time.perf_counter() - t0}
    problems: list[str] = []
    warnings: list[str] = []
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
            note(f"connected in {info['connect_s'] * 1e3:.0f} ms; {'reading' if config.dry_run else 'holding'} "
                 f"for {duration_s:g} s")
        from tactex.tasks.runner import ControlLoop

        loop = ControlLoop(backend)
        try:
            loop.hold(duration_s)
        except (RobotError, SensorFault) as exc:
            problems.append(str(exc))
        m = backend.loop_metrics()
        info.update(m)
        q_drift = float(np.abs(loop.state.q - state.q).max())
        info["q_drift_rad"] = q_drift
        ticks = max(1, m["loop_ticks"])
        lost_fraction = m["lost_cycles"] / (ticks + m["lost_cycles"])
        info["lost_fraction"] = lost_fraction
        if lost_fraction > LINK_MAX_LOST_FRACTION:
            problems.append(f"{m['lost_cycles']} cycles lost in {duration_s:g} s ({100 * lost_fraction:.2f} %, "
                            f"allowed {100 * LINK_MAX_LOST_FRACTION:.1f} %): the link would not hold 1 kHz")
        if m["min_command_success_rate"] < LINK_MIN_SUCCESS_RATE:
            problems.append(f"command success rate fell to {m['min_command_success_rate']:.3f} "
                            f"(needs ≥ {LINK_MIN_SUCCESS_RATE})")
        if m["loop_compute_us"]["p99.9"] > COMPUTE_BUDGET_US:
            warnings.append(f"our compute per tick reached {m['loop_compute_us']['p99.9']:.0f} µs at p99.9 "
                            f"(budget {COMPUTE_BUDGET_US:.0f}): a busy or unpinned CPU (docs/real_robot.md)")
    finally:
        backend.close()
    return CheckResult(ok=not problems, info=info, problems=problems, warnings=warnings)
