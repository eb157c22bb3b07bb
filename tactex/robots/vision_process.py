"""The wrist camera's surface estimate, computed in its own process for the 1 kHz loop.

A frame's surface estimate (normal, curvature, θ; VA-UFIC §II-B) costs milliseconds, several
control periods, so on the real robot it never runs in the control loop. The loop publishes the
tool pose each tick (:meth:`VisionProcess.publish_tool`) and picks up the newest estimate
when there is one (:meth:`VisionProcess.latest`); the worker takes frames at the camera's rate,
estimates, and publishes.

Frame sources:

- ``realsense``: a live RealSense (the ``realsense`` extra); each frame is posed with the tool pose
  the loop published last (the camera's mount from ``tool_T_camera``: a hand-eye calibration).
- ``sim``: tactex's ray-cast camera on a simulated scene (the object of ``tactex twin`` at its
  pose), posed the same way: how a run against the twin gets its vision.

Transport (no pickle): one anonymous shared-memory block (``memfd``) of float64, two seqlocked
slots: the pose (written by the loop) and the estimate (written by the worker), plus the worker's
heartbeat. The worker is a plain ``python -c`` subprocess configured by JSON on its command line;
it exits when its parent dies. A worker that stops beating for ``timeout_s`` is a
:class:`~tactex.errors.SensorFault` ("vision process ... stopped"), raised by :meth:`check`.
"""

from __future__ import annotations

import json
import mmap
import os
import subprocess
import sys
import time
from typing import Any

import numpy as np

from tactex.errors import ConfigError, SensorFault
from tactex.perception.estimate import SurfaceEstimate

__all__ = ["VisionProcess", "camera_mount"]

# slot layout (float64 indices)
_P_SEQ, _P_T, _P_POSE = 0, 1, 2  # pose slot: seq, t [s], world_T_tool (16, row-major)
_E_SEQ = 18  # estimate slot: seq, then the fields below
_E_FIELDS = ("valid", "timestamp", "normal_camera3", "normal_world3", "e1_world3", "e2_world3", "centroid_world3",
             "curvature", "theta_rad", "segment_size", "e1_camera3", "e2_camera3", "centroid_camera3",
             "eigenvalues3", "roi_points")
_E_LEN = sum(3 if f.endswith("3") else 1 for f in _E_FIELDS)
_E_DATA = _E_SEQ + 1
_HEARTBEAT = _E_DATA + _E_LEN  # worker's time.monotonic() at its last loop
_STATUS = _HEARTBEAT + 1  # 0 starting, 1 running, -1 failed
_SIZE = _STATUS + 1
_BYTES = 8 * _SIZE


def _pack_estimate(est: SurfaceEstimate) -> np.ndarray:
    out = []
    for f in _E_FIELDS:
        v = getattr(est, f.rstrip("3"))
        out.extend(np.asarray(v, dtype=float).reshape(-1).tolist() if f.endswith("3") else [float(v)])
    return np.array(out)


def _unpack_estimate(a: np.ndarray) -> SurfaceEstimate:
    kw: dict[str, Any] = {}
    i = 0
    for f in _E_FIELDS:
        if f.endswith("3"):
            kw[f[:-1]] = a[i:i + 3].copy()
            i += 3
        else:
            kw[f] = a[i]
            i += 1
    kw["valid"] = bool(kw["valid"])
    kw["segment_size"] = int(kw["segment_size"])
    kw["roi_points"] = int(kw["roi_points"])
    kw["timestamp"] = float(kw["timestamp"])
    kw["curvature"] = float(kw["curvature"])
    kw["theta_rad"] = float(kw["theta_rad"])
    return SurfaceEstimate(**kw, reason="" if kw["valid"] else "no usable segment")


def _write(buf: np.ndarray, seq_i: int, start: int, values: np.ndarray) -> None:
    """Seqlock write: an odd sequence number while the slot changes."""
    seq = buf[seq_i]
    buf[seq_i] = seq + 1.0
    buf[start:start + values.size] = values
    buf[seq_i] = seq + 2.0


def _read(buf: np.ndarray, seq_i: int, start: int, n: int) -> tuple[float, np.ndarray | None]:
    """Seqlock read: (seq, a consistent copy), or (seq, None) while the writer is inside."""
    for _ in range(100):
        s0 = buf[seq_i]
        if s0 % 2.0:
            continue
        values = buf[start:start + n].copy()
        if buf[seq_i] == s0:
            return s0, values
    return buf[seq_i], None


class VisionProcess:
    """A worker process that turns camera frames into :class:`SurfaceEstimate`\\ s (see the module
    docstring).

    Args:
        source: ``{"kind": "sim", "scene": {SceneConfig fields}}`` or ``{"kind": "realsense",
            "tool_T_camera": 4×4 nested list, "serial": str | None}``; plus optional
            ``"rate_hz"`` (30), ``"estimator": {SurfaceEstimatorConfig fields}`` and ``"cpus"`` (the
            cores the worker may use; default: the parent's, which a pinned control loop is not).
        timeout_s: a worker silent this long (or not ready within ``start_timeout_s``) is a fault [s].
    """

    def __init__(self, source: dict, *, timeout_s: float = 1.0, start_timeout_s: float = 60.0) -> None:
        if source.get("kind") not in ("sim", "realsense"):
            raise ConfigError(f"vision source kind must be 'sim' or 'realsense', got {source.get('kind')!r}")
        self.source = source
        self.timeout_s = float(timeout_s)
        fd = os.memfd_create("tactex-vision")
        os.ftruncate(fd, _BYTES)
        self._fd = fd
        self._map = mmap.mmap(fd, _BYTES)
        self._buf = np.frombuffer(self._map, dtype=np.float64, count=_SIZE)
        self._buf[:] = 0.0
        self._last_seq = 0.0
        self.estimates = 0
        self._pose_values = np.zeros(17)  # t, then world_T_tool row-major; its last row stays 0 0 0 1
        self._pose_values[16] = 1.0
        code = ("import sys; from tactex.robots.vision_process import _worker_main; "
                "_worker_main(sys.argv[1], sys.argv[2])")
        self.proc = subprocess.Popen(
            [sys.executable, "-c", code, str(fd), json.dumps(source)], pass_fds=(fd,),
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            preexec_fn=_normal_priority)
        deadline = time.monotonic() + start_timeout_s
        while self._buf[_STATUS] == 0.0:
            if self.proc.poll() is not None or time.monotonic() > deadline:
                err = self._stderr()
                self.close()
                raise SensorFault(f"the vision process did not start: {err or 'no message (timed out)'}")
            time.sleep(0.01)
        if self._buf[_STATUS] < 0:
            err = self._stderr()
            self.close()
            raise SensorFault(f"the vision process failed to start: {err}")

    def _stderr(self) -> str:
        if self.proc.poll() is None:
            return ""
        text = (self.proc.stderr.read() or b"").decode(errors="replace").strip() if self.proc.stderr else ""
        return text.splitlines()[-1] if text else f"exit code {self.proc.returncode}"

    def publish_pose(self, t: float, world_T_tool: np.ndarray) -> None:
        """The tool pose (4, 4, rigid) at time ``t`` [s], for posing the next frame."""
        pose = np.asarray(world_T_tool, dtype=float)
        self.publish_tool(t, pose[:3, :3], pose[:3, 3])

    def publish_tool(self, t: float, world_R_tool: np.ndarray, position_m: np.ndarray) -> None:
        """The tool pose at time ``t`` [s] from its rotation (3, 3) and position (3,) [m], for posing
        the next frame; cheap enough for every tick (no 4 × 4 is made)."""
        values = self._pose_values
        values[0] = t
        pose = values[1:].reshape(4, 4)
        pose[:3, :3] = world_R_tool
        pose[:3, 3] = position_m
        _write(self._buf, _P_SEQ, _P_T, values)

    def latest(self) -> SurfaceEstimate | None:
        """The newest estimate if one arrived since the last call, else None (never blocks)."""
        if self._buf[_E_SEQ] == self._last_seq:
            return None
        seq, values = _read(self._buf, _E_SEQ, _E_DATA, _E_LEN)
        if values is None:
            return None
        self._last_seq = seq
        self.estimates += 1
        return _unpack_estimate(values)

    def check(self) -> None:
        """Raise :class:`SensorFault` when the worker died or stopped beating for ``timeout_s``."""
        beat = self._buf[_HEARTBEAT]
        if self.proc.poll() is not None or (beat > 0 and time.monotonic() - beat > self.timeout_s):
            code = self.proc.poll()
            raise SensorFault(
                "the vision process stopped" + (f" (exit code {code})" if code is not None else
                                                 f" (silent for {time.monotonic() - beat:.1f} s)")
                + ": the run ends; check the camera's USB link, or run without vision")

    def close(self) -> None:
        """Stop the worker and free the block (idempotent)."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=2.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc.stderr is not None:
            self.proc.stderr.close()
        if self._map is not None:
            self._buf = np.zeros(_SIZE)
            self._map.close()
            self._map = None
            os.close(self._fd)


# -- worker side -------------------------------------------------------------------------------
def camera_mount(sim) -> np.ndarray:
    """tool_T_camera (4, 4) of a :class:`~tactex.robots.mujoco_backend.MujocoBackend`'s wrist camera:
    the tactex tool's nominal mount."""
    return np.linalg.inv(sim.state().ee_pose) @ sim.camera.pose(sim.data)


def _sim_frames(spec: dict):
    """(capture(world_T_tool, t) -> CameraFrame) on tactex's simulated scene."""
    from tactex.robots.mujoco_backend import MujocoBackend
    from tactex.sim.scene import SceneConfig

    scene = SceneConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in spec["scene"].items()})
    sim = MujocoBackend(scene)
    tool_T_cam = camera_mount(sim)
    obj_pos, obj_rot = sim.object_pose()

    def capture(world_T_tool: np.ndarray, t: float):
        return sim.camera.render(world_T_tool @ tool_T_cam, obj_pos, obj_rot, t, dirt=sim.scene.dirt,
                                 dirt_level=sim.scene.dirt.level.copy())

    return capture


def _realsense_frames(spec: dict, pose_fn):
    from tactex.perception.mount import CameraMount
    from tactex.perception.realsense import RealSenseSource

    mount = CameraMount(np.asarray(spec["tool_T_camera"], dtype=float))
    source = RealSenseSource(mount=mount, tool_pose_provider=lambda: pose_fn()[1], serial=spec.get("serial"))

    def capture(world_T_tool: np.ndarray, t: float):
        return source.read()

    return capture


def _normal_priority() -> None:
    """In the worker, before it starts: the ordinary time-sharing policy. A child inherits its
    parent's scheduling, and the control loop that starts the worker may hold SCHED_FIFO (libfranka's
    real-time set-up, :func:`~tactex.robots.libfranka_backend.pin_control_thread`): at that priority
    each frame (milliseconds of ray cast and estimate) would run to its end ahead of everything else
    on its core, the robot's network traffic and a protocol twin included."""
    if hasattr(os, "sched_setscheduler"):
        try:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        except OSError:
            pass


def _worker_main(fd_text: str, spec_text: str) -> None:
    """Entry point of the worker process."""
    from tactex.perception.estimator import SurfaceEstimator, SurfaceEstimatorConfig

    fd = int(fd_text)
    spec = json.loads(spec_text)
    if spec.get("cpus"):  # off the control loop's core
        os.sched_setaffinity(0, set(spec["cpus"]))
    mapping = mmap.mmap(fd, _BYTES)
    buf = np.frombuffer(mapping, dtype=np.float64, count=_SIZE)
    parent = os.getppid()

    def pose() -> tuple[float, np.ndarray] | None:
        seq, values = _read(buf, _P_SEQ, _P_T, 17)
        if values is None or seq == 0.0:
            return None
        return values[0], values[1:].reshape(4, 4)

    try:
        estimator = SurfaceEstimator(SurfaceEstimatorConfig(**spec.get("estimator", {})))
        capture = _sim_frames(spec) if spec["kind"] == "sim" else _realsense_frames(spec, pose)
    except Exception as exc:
        buf[_STATUS] = -1.0
        print(f"{type(exc).__name__}: {exc}", file=sys.stderr)
        raise SystemExit(1) from exc
    period = 1.0 / float(spec.get("rate_hz", 30.0))
    buf[_HEARTBEAT] = time.monotonic()
    buf[_STATUS] = 1.0
    next_t = time.monotonic()
    while os.getppid() == parent:
        buf[_HEARTBEAT] = time.monotonic()
        now = time.monotonic()
        if now < next_t:
            time.sleep(min(next_t - now, 0.05))
            continue
        next_t += period
        if next_t < now:
            next_t = now + period
        posed = pose()
        if posed is None:
            continue
        t, world_T_tool = posed
        frame = capture(world_T_tool, t)
        if frame is None:  # the camera had no new frame within its timeout
            continue
        estimate = estimator.estimate(frame, world_T_tool)
        _write(buf, _E_SEQ, _E_DATA, _pack_estimate(estimate))
