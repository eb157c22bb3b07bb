"""What a cleaning run records: the per-tick log (force statistics, the time series, the phases, the
time breakdown) and the result it hands back, whole or cut short on a robot."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tactex.pointcloud.cloud import SurfaceCloud
from tactex.robots.loop import ControlLoop
from tactex.tasks.clean.config import CleanConfig
from tactex.tasks.clean.time_breakdown import TimeBreakdown
from tactex.tasks.clean_phases import CLEAN_PHASES
from tactex.tasks.recorder import Recorder
from tactex.tasks.robot import end_on_robot

__all__ = ["PHASES", "CleanResult", "Started", "TickLog"]

#: Phase codes recorded in the time series (shared with the report).
PHASES = CLEAN_PHASES
_PHASE_NAMES = {code: name for name, code in PHASES.items()}


@dataclass
class CleanResult:
    """What a cleaning run produced."""

    config: CleanConfig
    metrics: dict[str, Any]
    series: dict[str, np.ndarray]
    cloud: SurfaceCloud | None  # None: a run on a robot that stopped before its first capture
    fields: dict[str, np.ndarray]
    agent_path: np.ndarray
    tcp_path: np.ndarray
    events: list[Any] = field(default_factory=list)



class TickLog:
    """Per-tick bookkeeping: force statistics every tick, a time series at ``record_hz``."""

    def __init__(self, backend, cfg: CleanConfig) -> None:
        self.backend = backend
        self.truth = hasattr(backend, "dirt_remaining")  # a simulation knows the dirt; a real robot does not
        self.cfg = cfg
        self.rec = Recorder(every=max(1, round(1.0 / (cfg.record_hz * backend.dt))))
        self.t = 0.0  # time of the last tick [s]
        # every phase change as (t [s], phase id): the series samples at record_hz and misses short
        # phases (an approach of a few ms, a capture that takes no tick at all)
        self.phase_changes: list[tuple[float, int]] = [(0.0, PHASES["move"])]
        self.agent = np.full(3, np.nan)
        self.contact_ticks = 0
        self.within_ticks = 0
        self.over_2x_ticks = 0
        self.explore_contact_ticks = 0
        self.max_force = 0.0
        self.set_point = cfg.force_n
        self.time = TimeBreakdown(backend.dt, cfg.contact_threshold_n, self.truth)
        self.live = None  # the run's live page (--view, a LiveFeed) or None
        self.live_left = None  # () -> what the robot believes is left per cloud point, once there is a cloud

    def activity(self, phase: str, activity: str) -> None:
        """Enter a phase of the state machine (:data:`PHASES`) doing ``activity`` (time breakdown)."""
        self.phase = PHASES[phase]
        self.time.set_activity(activity)

    @property
    def phase(self) -> int:
        return self.phase_changes[-1][1]

    @phase.setter
    def phase(self, value: int) -> None:
        if value != self.phase_changes[-1][1]:
            self.phase_changes.append((self.t, int(value)))

    def __call__(self, state, reference, controller) -> None:
        self.t = float(state.t)
        f = state.wrench_tool
        fn = float(f[2])
        fmag = float(np.sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]))
        self.max_force = max(self.max_force, fmag)
        self.time.tick(fn)
        if fn >= self.cfg.contact_threshold_n and self.phase == PHASES["explore"]:
            self.contact_ticks += 1
            if abs(fn - self.set_point) <= 0.2 * self.set_point:
                self.within_ticks += 1
            if fn > 2.0 * self.set_point:
                self.over_2x_ticks += 1
        if self.rec.due():
            dirt = self.backend.dirt_remaining() if self.truth else np.nan
            self.time.dirt(dirt)
            self.rec.add(
                t=state.t, phase=self.phase, q=state.q, tcp=state.ee_position, agent=self.agent, force_z_n=fn,
                force_norm_n=fmag, set_point_n=self.set_point if self.phase == PHASES["explore"] else 0.0,
                pad_force_n=self.backend.pad_contact()[0] if self.truth else np.nan,
                dirt_remaining=dirt,
            )
        else:
            self.rec.add()
        if self.live is not None and self.live.due():
            self._show(state, fn)

    def _show(self, state, fn: float) -> None:
        """A snapshot for the live page (at most every :attr:`LiveFeed.period_s`)."""
        explore = self.phase == PHASES["explore"]
        dirt = self.backend.dirt_remaining() if self.truth else np.nan
        self.live.publish(
            self.t, phase=_PHASE_NAMES[self.phase], force_n=fn, set_point_n=self.set_point if explore else np.nan,
            tcp_m=state.ee_position, agent_m=self.agent, world_R_tool=state.ee_rotation,
            progress=self.t / self.cfg.budget_s, field=self.live_left() if self.live_left is not None else None,
            breakdown_s=self.time.seconds(), figures={"dirt left (simulation) [-]": dirt} if self.truth else {})



class Started:
    """What a :class:`~tactex.tasks.clean.program.CleanProgram` has started, for a run on a robot that stops
    outside the program's loop."""

    def __init__(self) -> None:
        self.log: TickLog | None = None
        self.loop: ControlLoop | None = None
        self.cloud: SurfaceCloud | None = None  # the given cloud, or the first capture once made
        self.camera = None  # the robot's camera (a RobotCapture) when the target comes from it
        self.t0 = time.perf_counter()

    def stopped(self, cfg: CleanConfig, exc: BaseException) -> CleanResult | None:
        """The run so far (torque control ended, ``aborted`` naming ``exc``, the series recorded), or
        None when nothing was recorded yet (a stop before the first capture keeps the moves to it, with no cloud)."""
        log, loop, cloud = self.log, self.loop, self.cloud
        if log is None or loop is None:
            return None
        series = log.rec.arrays()
        if not len(series.get("t", ())):
            return None
        aborted = end_on_robot(loop, exc)
        backend = loop.backend
        metrics = {
            "aborted": aborted,
            "partial": True,  # stopped before the program's end: aborted says why
            "robot": "franka",
            "sim_time_s": loop.t,
            "wall_time_s": time.perf_counter() - self.t0,
            "force_within_20pct_fraction": log.within_ticks / max(log.contact_ticks, 1),
            "max_contact_force_n": log.max_force,
            "contact_time_s": log.contact_ticks * backend.dt,
            "force_set_point_n": cfg.force_n,
            "baseline": cfg.baseline or "tactex",
            "object": cfg.object_name,
            "marking": "cloud" if cfg.cloud else (cfg.marking or "part"),
            "target_source": "cloud" if cfg.cloud else "camera",
            "n_points": 0 if cloud is None else len(cloud),
            "safety_events": len(loop.safety.events),
            "torque_rate_clip_ticks": loop.safety.counts.get("torque_rate_limit", 0),
            "phase_changes": [[t, p] for t, p in log.phase_changes],
            **backend.loop_metrics(),
            **(self.camera.metrics() if self.camera is not None else {}),
        }
        return CleanResult(config=cfg, metrics=metrics, series=series, cloud=cloud,
                           fields={} if cloud is None else {"target_initial": cloud.target.copy()},
                           agent_path=np.zeros((0, 3)),
                           tcp_path=series.get("tcp", np.zeros((0, 3))), events=list(loop.safety.events))

