"""The camera worker process (SceneConfig(camera_worker=True)): the same frames and the same episode
as the in-process camera with one frame period of latency, a clean stop in every way a backend
ends, and a clear error instead of a hang when the worker fails."""

from __future__ import annotations

import dataclasses
import gc
import os
import select
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from tactex.errors import ConfigError, InputError, SimulationError
from tactex.perception.frame import CameraIntrinsics
from tactex.pointcloud.shapes import HeightFieldSurface
from tactex.robots import MujocoBackend
from tactex.sim import SceneConfig, object_names
from tactex.sim.camera import RayCastCamera
from tactex.sim.camera_worker import CameraWorker, _surface_spec
from tactex.sim.objects import SimObject
from tactex.sim.raycast import SceneRayCaster

PERIOD = 1 / 30
SMALL = dict(camera_width=40, camera_height=30, camera_rate_hz=30.0)


def _gone(pid: int, within_s: float = 15.0) -> bool:
    """The process has exited (and been reaped, or is a zombie of a dead parent) within ``within_s``."""
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        try:
            with open(f"/proc/{pid}/stat") as f:
                if f.read().rsplit(")", 1)[1].split()[0] == "Z":
                    return True
        except FileNotFoundError:
            return True
        time.sleep(0.05)
    return False


def _episode(cfg: SceneConfig, ticks: int = 400, reset_at: int | None = None, wipe_dirt_at: int | None = None):
    """Frames (delivery time, frame) and final joint positions of a run with a torque wiggle."""
    out = []
    with MujocoBackend(cfg) as backend:
        for i in range(ticks):
            if i == reset_at:
                backend.reset(seed=3)
            backend.apply_torque(np.full(7, 0.3 * np.sin(i / 50)))
            f = backend.camera_frame()
            if f is not None:
                out.append((backend.time, f))
            if i == wipe_dirt_at:
                backend.dirt.level[:] = 0.0  # after a frame's exposure: that frame must still show the dirt
            backend.step()
        return out, backend.state().q.copy()


def _assert_same_frames(a, b):
    assert len(a) == len(b) > 0
    for (ta, fa), (tb, fb) in zip(a, b, strict=True):
        assert ta == tb and fa.timestamp == fb.timestamp
        np.testing.assert_array_equal(fa.world_T_camera, fb.world_T_camera)
        np.testing.assert_array_equal(fa.depth_m, fb.depth_m)
        np.testing.assert_array_equal(fa.rgb, fb.rgb)


@pytest.mark.parametrize("name", object_names())
def test_worker_frames_equal_in_process_frames(name):
    # the in-process camera with one period of latency delivers the same frames at the same ticks
    kw = dict(object_name=name, depth_noise_m=0.001, **SMALL)
    ref, q_ref = _episode(SceneConfig(camera_latency_s=PERIOD, **kw), ticks=240)
    got, q_got = _episode(SceneConfig(camera_worker=True, **kw), ticks=240)
    _assert_same_frames(ref, got)
    np.testing.assert_array_equal(q_ref, q_got)
    assert any((f.depth_m > 0).mean() > 0.5 for _, f in got)  # the object and the table are in view


def test_worker_frame_shows_the_dirt_at_its_exposure_and_survives_reset():
    # dirt wiped away right after an exposure still shows in that frame (the levels travel with
    # the snapshot); a reset drops the frame in flight, as in process
    kw = dict(object_name="plane", **SMALL)
    exposure = 100  # the frame exposed at tick 100 (t = 0.1 s) arrives at tick 134
    ref, q_ref = _episode(SceneConfig(camera_latency_s=PERIOD, **kw), 600, reset_at=420, wipe_dirt_at=exposure)
    got, q_got = _episode(SceneConfig(camera_worker=True, **kw), 600, reset_at=420, wipe_dirt_at=exposure)
    _assert_same_frames(ref, got)
    np.testing.assert_array_equal(q_ref, q_got)
    dirty = [f.rgb[..., 1].min() < 60 for _, f in got]  # the marking is dark
    at_exposure = [i for i, (_, f) in enumerate(got) if abs(f.timestamp - 0.1) < 1e-9]
    assert len(at_exposure) == 2  # before and after the reset (which restores the dirt)
    k = at_exposure[0]
    assert dirty[k] and not dirty[k + 1]  # the next frame was exposed after the wipe
    assert dirty[at_exposure[1]]
    # the frame exposed at 0.4 s was in flight at the reset (0.42 s): dropped
    assert not any(abs(f.timestamp - 0.4) < 1e-6 for _, f in got)
    assert any(abs(f.timestamp - 0.367) < 1e-6 for _, f in got)  # the one before it arrived (at 0.4 s)


def test_worker_runs_are_deterministic():
    cfg = SceneConfig(object_name="bowl", camera_worker=True, depth_noise_m=0.002, **SMALL)
    a, qa = _episode(cfg, ticks=200)
    b, qb = _episode(cfg, ticks=200)
    _assert_same_frames(a, b)
    np.testing.assert_array_equal(qa, qb)


def test_worker_latency_is_one_frame_period():
    with MujocoBackend(SceneConfig(object_name="plane", camera_worker=True, **SMALL)) as backend:
        frames = []
        for _ in range(1040):
            f = backend.camera_frame()
            if f is not None:
                frames.append((backend.time, f.timestamp))
            backend.step()
        delivered, exposed = np.array(frames).T
        assert exposed[0] == 0.0 and len(frames) == 31  # exposed 0 .. 1.0 s, the last one delivered at 1.033
        np.testing.assert_allclose(delivered - exposed, PERIOD, atol=1.01e-3)
        assert backend.camera_worker.cpu_time_s() > 0.0


def test_close_stops_the_worker_in_every_way():
    cfg = SceneConfig(object_name="plane", camera_worker=True, **SMALL)
    backend = MujocoBackend(cfg)
    pid = backend.camera_worker.pid
    backend.camera_worker.wait_ready()
    backend.close()
    backend.close()  # idempotent
    assert _gone(pid)
    with pytest.raises(SimulationError, match="closed"):
        for _ in range(40):
            backend.camera_frame()
            backend.step()
    with MujocoBackend(cfg) as backend:
        pid = backend.camera_worker.pid
    assert _gone(pid)
    backend = MujocoBackend(cfg)  # dropped without close: the finaliser stops it
    pid = backend.camera_worker.pid
    del backend
    gc.collect()
    assert _gone(pid)


def test_no_worker_survives_its_parent():
    # a parent killed outright (no finaliser, no atexit) closes the worker's socket: the worker exits
    script = textwrap.dedent("""
        import os, signal, sys
        from tactex.robots import MujocoBackend
        from tactex.sim import SceneConfig
        b = MujocoBackend(SceneConfig(object_name="plane", camera_width=16, camera_height=12, camera_worker=True))
        b.camera_worker.wait_ready()
        print(b.camera_worker.pid, flush=True)
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert res.returncode == -signal.SIGKILL, res.stderr
    assert _gone(int(res.stdout.split()[0]))


def test_killed_worker_raises_with_its_exit_code():
    with MujocoBackend(SceneConfig(object_name="plane", camera_worker=True, **SMALL)) as backend:
        backend.camera_worker.wait_ready()
        assert backend.camera_frame() is None  # the first frame is in flight
        os.kill(backend.camera_worker.pid, signal.SIGKILL)
        # the frame in flight may have been finished before the kill: then the error comes with the
        # next frame's submit or collect, a camera period later
        with pytest.raises(SimulationError, match=r"died with exit code -9 \(killed by a signal\)"):
            for _ in range(2000):
                backend.step()
                backend.camera_frame()
        backend.reset()
        with pytest.raises(SimulationError, match="died with exit code -9"):  # and stays failed
            backend.camera_frame()


def _plane_camera(surface) -> RayCastCamera:
    obj = SimObject(name="probe", surface=surface)
    return RayCastCamera(None, -1, CameraIntrinsics.from_fov(16, 12, 60.0), method="analytic",
                         caster=SceneRayCaster(obj))


@dataclasses.dataclass(frozen=True, eq=False)
class _FailsInWorker(HeightFieldSurface):
    """A surface that cannot be rebuilt outside the process that made it."""

    parent_pid: int = 0

    def __post_init__(self) -> None:
        if os.getpid() != self.parent_pid:
            raise InputError("this surface refuses to be rebuilt in another process")


def _flat(x, y):
    return np.zeros_like(np.asarray(x, dtype=float))


def test_worker_failure_is_reported_with_its_message():
    camera = _plane_camera(_FailsInWorker("probe", 0.2, 0.2, _flat, parent_pid=os.getpid()))
    with CameraWorker(camera) as worker, pytest.raises(SimulationError, match="refuses to be rebuilt"):
        worker.wait_ready()


def test_hung_worker_times_out_and_is_killed():
    camera = _plane_camera(HeightFieldSurface("probe", 0.2, 0.2, _flat))
    with CameraWorker(camera) as worker:
        worker.wait_ready()
        worker.timeout_s = 0.5
        os.kill(worker.pid, signal.SIGSTOP)
        worker.submit(np.eye(4), np.zeros(3), np.eye(3), 0.0, None, 0, 1, False)
        with pytest.raises(SimulationError, match=r"did not finish the frame within 0.5 s and was killed"):
            worker.collect()
        assert _gone(worker.pid) and worker.exit_code == -signal.SIGKILL


def test_close_with_a_frame_in_flight_ends_the_worker_cleanly():
    camera = _plane_camera(HeightFieldSurface("probe", 0.2, 0.2, _flat))
    worker = CameraWorker(camera)
    worker.wait_ready()
    worker.submit(np.eye(4), np.zeros(3), np.eye(3), 0.0, None, 0, 1, False)
    worker.close()
    assert worker.exit_code == 0 and not worker.alive
    with pytest.raises(SimulationError, match="already closed"):
        worker.submit(np.eye(4), np.zeros(3), np.eye(3), 0.0, None, 0, 1, False)


def test_close_with_an_unread_ready_message_ends_the_worker_cleanly():
    """Closing with the worker's READY still unread reset the connection: the worker died with a
    ConnectionResetError traceback (exit code 1) instead of ending."""
    camera = _plane_camera(HeightFieldSurface("probe", 0.2, 0.2, _flat))
    worker = CameraWorker(camera)
    ready, _, _ = select.select([worker._sock], [], [], 60.0)  # READY sent, deliberately left unread
    assert ready
    worker.close()
    assert worker.exit_code == 0


def test_worker_protocol_misuse_is_refused():
    camera = _plane_camera(HeightFieldSurface("probe", 0.2, 0.2, _flat))
    with CameraWorker(camera) as worker:
        with pytest.raises(SimulationError, match="no frame in flight"):
            worker.collect()
        worker.submit(np.eye(4), np.zeros(3), np.eye(3), 0.5, None, 0, 1, False)
        with pytest.raises(SimulationError, match="already in flight"):
            worker.submit(np.eye(4), np.zeros(3), np.eye(3), 0.5, None, 0, 1, False)
        frame = worker.collect()
        assert frame.timestamp == 0.5 and frame.depth_m.shape == (12, 16)
        # the same snapshot in process
        np.testing.assert_array_equal(frame.depth_m, camera.render(np.eye(4), np.zeros(3), np.eye(3), 0.5).depth_m)


def test_worker_configuration_is_validated():
    with pytest.raises(ConfigError, match="camera_worker needs camera_raycast='analytic'"):
        SceneConfig(camera_worker=True, camera_raycast="mujoco")
    with pytest.raises(ConfigError, match=r"camera_latency_s must be 0 or that period, got 0\.01"):
        SceneConfig(camera_worker=True, camera_latency_s=0.01)
    SceneConfig(camera_worker=True, camera_latency_s=PERIOD)  # the worker's own latency is fine
    with pytest.raises(ConfigError, match="camera_worker_timeout_s must be > 0 s, got 0"):
        SceneConfig(camera_worker=True, camera_worker_timeout_s=0.0)
    backend = MujocoBackend(SceneConfig(object_name="plane", camera_raycast="mujoco", **SMALL))
    with pytest.raises(ConfigError, match="analytic ray caster"):
        CameraWorker(backend.camera)
    camera = _plane_camera(HeightFieldSurface("probe", 0.2, 0.2, _flat))
    with pytest.raises(ConfigError, match="timeout must be > 0 s, got nan"):
        CameraWorker(camera, timeout_s=float("nan"))


def test_surfaces_the_worker_cannot_rebuild_are_refused():
    @dataclasses.dataclass(frozen=True, eq=False)
    class Local(HeightFieldSurface):
        pass

    with pytest.raises(ConfigError, match="importable module"):
        _surface_spec(Local("x", 0.1, 0.1, _flat))

    @dataclasses.dataclass(frozen=True, eq=False)
    class WithArray(HeightFieldSurface):
        table: tuple = (1.0, 2.0)

    WithArray.__qualname__ = "WithArray"  # as if importable: the field is what is refused
    with pytest.raises(ConfigError, match=r"cannot send field 'table' = \(1.0, 2.0\)"):
        _surface_spec(WithArray("x", 0.1, 0.1, _flat))
