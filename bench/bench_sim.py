"""Simulation speed: a 20 s wiping episode on the VA-UFIC sine panel with 1 kHz torque control
(a Cartesian impedance with a 15 N force feed-forward, tracking the VA-UFIC wiping trajectory),
F/T sensing every tick, dirt removal, and the 160×120 wrist camera at 30 Hz (ray cast).

The episode runs twice: with the camera ray cast in the control loop (``sim.realtime_factor_inprocess``)
and with ``SceneConfig(camera_worker=True)`` (``sim.realtime_factor``, the target): the frames are
ray cast by a worker process on the machine's second core while the physics runs on, and each
frame arrives one frame period (33 ms) after its exposure instead of at once — the same frames
and the same episode as in process with ``camera_latency_s`` = one period. The CPU figures count
both processes (the worker's CPU time over the episode, read from /proc); the worker's start
(a fresh interpreter importing tactex) happens before the clock starts and is reported apart.
"""

from __future__ import annotations

import math
import resource
import time

import numpy as np

from tactex.pointcloud.shapes import sine_panel_height
from tactex.robots import MujocoBackend
from tactex.sim import SceneConfig
from tactex.sim.testing import SimpleImpedance

TARGETS = {
    "sim.realtime_factor": (">=", 5.0),
}

DOWN = np.diag([1.0, -1.0, -1.0])


def _children_cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _episode(seconds: float, worker: bool) -> dict:
    children0 = _children_cpu_s()
    t_make = time.perf_counter()
    backend = MujocoBackend(SceneConfig(object_name="sine_panel", camera_width=160, camera_height=120,
                                        camera_worker=worker))
    pos, _ = backend.object_pose()
    start = pos + np.array([0.0, 0.0, float(sine_panel_height(np.array(0.0), np.array(0.0))) + 0.005])
    backend.reset(seed=0, q0=backend.solve_ik(start, DOWN))
    cw = backend.camera_worker
    if cw is not None:
        cw.wait_ready()
    ready_s = time.perf_counter() - t_make
    ctrl = SimpleImpedance(free_axes=(2,))
    ff = np.array([0.0, 0.0, -15.0, 0.0, 0.0, 0.0])
    n = round(seconds / backend.dt)
    step_s = np.empty(n)
    cam_s = np.empty(n)  # every tick: most return at once
    frame_ticks = []
    worker_cpu0 = cw.cpu_time_s() if cw is not None else 0.0
    t_wall = time.perf_counter()
    t_cpu = time.process_time()
    for i in range(n):
        s = backend.state()
        t = s.t
        # VA-UFIC §III wiping policy, in the tool's x/y (= world x/−y here)
        offset = np.array([0.04 * math.sin(2 * t), -(0.04 * (math.cos(2 * t) - 1) - 0.005 * t), 0.0])
        backend.apply_torque(ctrl.torque(s, start + offset, DOWN, ff))
        t0 = time.perf_counter()
        backend.step()
        t1 = time.perf_counter()
        step_s[i] = t1 - t0
        frame = backend.camera_frame()
        cam_s[i] = time.perf_counter() - t1
        if frame is not None:
            frame_ticks.append(i)
    wall = time.perf_counter() - t_wall
    cpu_main = time.process_time() - t_cpu
    worker_cpu = (cw.cpu_time_s() - worker_cpu0) if cw is not None else 0.0
    dirt = backend.dirt_remaining()
    backend.close()
    cpu = cpu_main + worker_cpu
    out = {
        "realtime_factor": seconds / wall,
        # CPU time of the episode over both processes: what the wall time would be on one idle core
        "realtime_factor_cpu": seconds / cpu,
        "episode_wall_s": wall,
        "episode_cpu_s": cpu,
        "step_us_median": float(np.median(step_s) * 1e6),
        "camera_ms_median": float(np.median(cam_s[frame_ticks]) * 1e3),  # a tick that delivers a frame
        "camera_frames": len(frame_ticks),
        # where the wall time goes, per control tick: physics step (with F/T, contacts, dirt and the
        # state), camera (its frames, or with the worker the hand-over and any wait for it, spread
        # over the ticks), the rest (controller, torque command, loop)
        "tick_us": {
            "step": float(step_s.mean() * 1e6),
            "camera": float(cam_s.mean() * 1e6),
            "other": float((wall - step_s.sum() - cam_s.sum()) / n * 1e6),
        },
        "setup_s": ready_s,
        "dirt_remaining": dirt,
    }
    if cw is not None:
        out["worker_cpu_s"] = worker_cpu
        out["main_cpu_s"] = cpu_main
        # the worker's whole life (start, imports and the episode), from the kernel's accounting of
        # the process once it has exited
        out["worker_total_cpu_s"] = _children_cpu_s() - children0
    return out


def run(args) -> dict:
    seconds = 5.0 if getattr(args, "quick", False) else 20.0
    inproc = _episode(seconds, worker=False)
    with_worker = _episode(seconds, worker=True)
    return {"sim": {
        **with_worker,
        "realtime_factor_inprocess": inproc["realtime_factor"],
        "realtime_factor_cpu_inprocess": inproc["realtime_factor_cpu"],
        "inprocess": inproc,
    }}


if __name__ == "__main__":
    import argparse

    print(run(argparse.Namespace(quick=False)))
