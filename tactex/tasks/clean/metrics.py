"""The figures of a clean run (``metrics.json``), from its program's state at the end."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from tactex.tasks.clean.time_breakdown import time_to_fraction_removed

__all__ = ["clean_metrics"]


def clean_metrics(program: Any, series: dict[str, np.ndarray]) -> dict:
    """The run's figures; ``program``: the :class:`~tactex.tasks.clean.program.CleanProgram` that ran."""
    cfg, loop, log, legs_, ex = program.cfg, program.loop, program.log, program.legs, program.explorer
    contact = max(log.contact_ticks, 1)
    t95 = (time_to_fraction_removed(series["t"], series["dirt_remaining"], 0.95)
           if log.truth and len(series.get("t", ())) else None)
    metrics = {
        "dirt_removed_fraction": 1.0 - program.dirt(),
        # the shares count the normal force while exploring in contact; the maximum is the force
        # magnitude over every phase (a transit's or a sideways hit's too)
        "force_within_20pct_fraction": log.within_ticks / contact,
        "max_contact_force_n": log.max_force,
        "force_over_2x_ticks": log.over_2x_ticks,
        "contact_time_s": log.contact_ticks * program.backend.dt,
        "sim_time_s": loop.t,
        "explore_time_s": program.explore_time,
        # where the time went, and when 95 % of the marking was off (None: never, or no ground truth)
        "time_breakdown_s": log.time.seconds(),
        # the same up to the 95 % mark (None when it never came or the dirt is not known): the time to 95 % split
        "time_breakdown_to_95pct_s": log.time.seconds_to_mark(),
        "time_to_95pct_s": t95,
        # [s] the least time any method could take (tactex.tasks.clean.bound), its parts, and this run over it
        "ideal_time_s": program.bound.time_s,
        "ideal_time_parts_s": program.bound.parts_s(),
        "dirty_area_m2": program.bound.dirty_area_m2,
        "time_to_95pct_over_ideal": None if t95 is None else t95 / program.bound.time_s,
        "vision_updates": program.vision_updates,
        "island_relocations": program.island_moves,
        # far joint moves from low over the object that went up to the capture posture first
        # (motion.LOW_MOVE_MAX_JOINT_RAD)
        "moves_via_capture": program.moves_via_capture,
        # far moves that went up, then backed off along the tool axis (out from a cup's wall) instead
        "moves_backed_off": program.moves_backed_off,
        "island_strokes": program.n_strokes,
        # what the first leg in contact was and why (legs._first_leg: a stroke, a planned sweep or the explorer)
        "first_leg": program.first_leg_choice,
        # [m] slid along the planned first sweep (0: none, or its touch-down was out of reach) and its slide to
        # the goal as the wear model predicted it when planned (0: none planned)
        "first_sweep_m": 0.0 if program.first_sweep is None else program.first_sweep.path.path_length,
        "first_sweep_planned_m": 0.0 if program.first_plan is None else program.first_plan.length_m,
        "contact_transfers": program.n_transfers,
        "vision_update_times_s": program.vision_times,
        "phase_changes": [[t, p] for t, p in log.phase_changes],
        "vision_remaining_fraction": program.remaining_seen,
        "basis_time_s": program.basis_s,
        "start_plan_time_s": program.start_plan_s,  # [s] wall clock: choosing the first touch-down (IK per candidate)
        "n_eigen": 0 if program.basis is None else program.basis.n_eigen,
        "eigensolver": "" if program.basis is None else program.basis.eigensolver,
        "wall_time_s": time.perf_counter() - program.wall0,
        "n_points": len(program.cloud),
        "n_target_initial": program.n_target0,
        "agent_path_length_m": legs_.path_m + float(program.path.path_length),
        "air_path_length_m": legs_.air_m + (float(ex.air_path_length) if ex is not None else 0.0),
        "relocations": legs_.relocations + len(program.path.relocations),
        "keep_out_points": int(program.keep_out.sum()) if program.keep_out is not None else 0,
        "keep_out_contacts": legs_.keep_out_contacts + (int(ex.keep_out_contacts) if ex is not None else 0),
        "target_near_keep_out": program.near_keep_out,
        "force_set_point_n": cfg.force_n,
        "baseline": cfg.baseline or "tactex",
        "object": cfg.object_name,
        # with --cloud the dirt is its target (simulated too); a part file's own marking is "part"
        "marking": "cloud" if cfg.cloud else (cfg.marking or "part"),
        "safety_events": len(loop.safety.events),
        # per kind: events (force_limit: one per retreat), ticks for nan_wrench and the torque and rate limits
        "safety_counts": dict(loop.safety.counts),
        "safety_limits": {"max_contact_force_n": loop.safety.limits.max_contact_force,
                          "tau_rate_max_n_m_s": loop.safety.limits.tau_rate_max},
        # every tick the torque-rate limiter changed the command (an event marks only where a run of them starts)
        "torque_rate_clip_ticks": loop.safety.counts.get("torque_rate_limit", 0),
        "ergodicity": program.ergodicity,
        "robot": "franka" if program.robot is not None else "sim",
        "target_source": "cloud" if program.given is not None else "camera",
        # [kg] the tool's weight the robot's load setting misses, from the load check (None: not made), and
        # whether it was compensated
        "load_error_kg": None if program.load_error is None else program.load_error.mass_kg,
        "load_error_compensated": program.load_error is not None and program.load_error.accepted,
        "aborted": program.aborted,
        "partial": bool(program.aborted),  # the program stopped before its end (Ctrl-C or the robot): aborted says why
    }
    if program.robot is not None:
        metrics.update(program.backend.loop_metrics())
        # the captures with the robot's camera (frames read and processed while torque control paused)
        metrics.update(program.camera.metrics() if program.camera is not None else {"camera": "none", "captures": 0})
    return metrics
