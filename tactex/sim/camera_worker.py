"""Wrist-camera frames ray cast in a worker process while the physics runs on (opt-in,
``SceneConfig(camera_worker=True)``).

Why a process: ray casting a 160×120 frame costs several control periods of numpy in the 1 kHz
loop, a large share of the wall time of a wiping episode; a thread does not help (its GIL
hand-overs with the control loop cost more than they overlap). A second process uses another core.

Protocol (one frame in flight): at a frame's exposure tick the backend writes a snapshot — camera
pose, object pose, the dirt levels, the timestamp and the noise seed — into shared memory and sends
one byte; the worker ray casts it with the same :class:`~tactex.sim.camera.RayCastCamera` code as
the in-process path and answers with one byte; the backend collects the frame at the *next*
exposure tick (blocking if the worker is late), so the frames and the episode do not depend on the
machine's speed, and a frame arrives one frame period after its exposure.

Transport: an anonymous shared-memory file (``os.memfd_create``, mapped by both processes: it has no
name to leak and disappears with its last user) and a ``SOCK_SEQPACKET`` socket pair for the one-byte
messages; the worker is a plain ``python -c`` subprocess configured by JSON on its command line (so
no pickle, and the caller's ``__main__`` is never re-imported, unlike multiprocessing's spawn). The
worker exits on a stop message or when its socket closes (the parent died); :meth:`close`, a
``weakref.finalize`` (also run at exit) and the backend's ``close`` stop it.

Start cost: a fresh interpreter importing tactex, about a second of one core, spent while
the backend goes on; :meth:`CameraWorker.wait_ready` waits for it.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import mmap
import os
import select
import signal
import socket
import subprocess
import sys
import time
import weakref
from pathlib import Path

import numpy as np

from tactex.errors import ConfigError, MissingDependencyError, SimulationError
from tactex.perception.frame import CameraFrame, CameraIntrinsics

__all__ = ["DEFAULT_TIMEOUT_S", "CameraWorker"]

#: Longest wait for the worker [s] (its start included) before it is declared hung.
DEFAULT_TIMEOUT_S = 60.0

_MSG_FRAME, _MSG_STOP, _MSG_READY, _MSG_DONE, _MSG_ERROR = b"F", b"S", b"R", b"D", b"E"
_POSE = 29  # world_T_camera (16), object position (3), object rotation (9), timestamp (1)
_ALIGN = 64


def _layout(spec: dict) -> tuple[dict[str, tuple[int, np.dtype, int]], int]:
    """Offsets [bytes], dtypes and lengths of the arrays in the shared block, and its size."""
    h, w = spec["intrinsics"]["height"], spec["intrinsics"]["width"]
    nx, ny = spec["hfield_shape"]
    parts = [("hf_xs", np.float64, nx), ("hf_ys", np.float64, ny), ("hf_z", np.float64, nx * ny),
             ("pose", np.float64, _POSE), ("ints", np.int64, 3), ("level", np.float64, spec["n_cells"]),
             ("depth", np.float32, h * w), ("rgb", np.uint8, h * w * 3)]
    out, off = {}, 0
    for name, dtype, n in parts:
        out[name] = (off, np.dtype(dtype), n)
        off += -(-np.dtype(dtype).itemsize * n // _ALIGN) * _ALIGN
    return out, max(off, _ALIGN)


def _views(buf: mmap.mmap, layout: dict) -> dict[str, np.ndarray]:
    return {name: np.frombuffer(buf, dtype=dt, count=n, offset=off) for name, (off, dt, n) in layout.items()}


def _surface_spec(surface) -> dict:
    """A surface as its class path and its plain fields; callables (a height function) are left out:
    the worker needs the surface only for uv, the domain test and sizes, and gets the height-field
    grid as arrays."""
    cls = type(surface)
    if not dataclasses.is_dataclass(surface) or "<locals>" in cls.__qualname__ or cls.__module__ == "__main__":
        raise ConfigError(f"camera_worker needs a surface dataclass defined in an importable module, got {cls!r}")
    fields, callables = {}, []
    for f in dataclasses.fields(surface):
        v = getattr(surface, f.name)
        if callable(v):
            callables.append(f.name)
            continue
        if not (v is None or isinstance(v, (bool, int, float, str))):
            raise ConfigError(f"camera_worker cannot send field '{f.name}' = {v!r} of {cls.__name__} to its worker")
        fields[f.name] = v
    return {"module": cls.__module__, "qualname": cls.__qualname__, "fields": fields, "callables": callables}


def _height_unavailable(x, y):
    raise SimulationError("the camera worker holds no height function (it casts on the height-field grid)")


def _surface_from_spec(spec: dict):
    cls = getattr(importlib.import_module(spec["module"]), spec["qualname"])
    return cls(**spec["fields"], **{name: _height_unavailable for name in spec["callables"]})


class CameraWorker:
    """A worker process ray casting the frames of one :class:`~tactex.sim.camera.RayCastCamera`
    (analytic method) of a scene.

    Args:
        camera: the in-process camera (its intrinsics, depth noise and ray caster are mirrored).
        dirt: the object's dirt field (its grid and surface; the levels travel with each frame), or None.
        object_rgb: clean colour of the object in [0, 1].
        board: a :class:`~tactex.sim.board.ChessBoard` on the table, painted into each frame, or None.
        timeout_s: longest wait for a frame (or the start) [s] before :class:`SimulationError`.
    """

    def __init__(self, camera, dirt=None, object_rgb=None, timeout_s: float = DEFAULT_TIMEOUT_S, *,
                 board=None) -> None:
        if camera.method != "analytic" or camera.caster is None:
            raise ConfigError("camera_worker needs the analytic ray caster (camera_raycast='analytic')")
        if not (np.isfinite(timeout_s) and timeout_s > 0):
            raise ConfigError(f"camera worker timeout must be > 0 s, got {timeout_s}")
        if not hasattr(os, "memfd_create"):
            raise MissingDependencyError(
                "os.memfd_create", "", "The camera worker process",
                fix="It needs Linux; elsewhere use SceneConfig(camera_worker=False)",
            )
        caster = camera.caster
        obj = caster.obj
        hf = obj.heightfield() if caster.kind == "hfield" else None
        self.intrinsics: CameraIntrinsics = camera.intrinsics
        self.timeout_s = float(timeout_s)
        spec = {
            "intrinsics": dataclasses.asdict(camera.intrinsics),
            "depth_noise_m": camera.depth_noise_m,
            "object": {"name": obj.name, "base_thickness_m": obj.base_thickness_m,
                       "hfield_spacing_m": obj.hfield_spacing_m, "surface": _surface_spec(obj.surface)},
            "kind": caster.kind,
            "caster": {"table_top_z": caster.table_z, "table_xy": list(caster.table_xy),
                       "newton_iterations": caster.iterations, "tolerance_m": float(caster.tolerance)},
            "hfield_shape": [0, 0] if hf is None else [len(hf[0]), len(hf[1])],
            "dirt": None if dirt is None else {"surface": _surface_spec(dirt.surface), "shape": list(dirt.shape)},
            "n_cells": 0 if dirt is None else int(dirt.level.size),
            "object_rgb": None if object_rgb is None else [float(c) for c in object_rgb],
            "board": None if board is None else dataclasses.asdict(board),
        }
        layout, size = _layout(spec)
        spec["size"] = size
        fd = os.memfd_create("tactex-camera", os.MFD_CLOEXEC)
        try:
            os.ftruncate(fd, size)
            self._mm = mmap.mmap(fd, size)
            parent, child = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        except BaseException:
            os.close(fd)
            raise
        self._views = _views(self._mm, layout)
        if hf is not None:
            for name, arr in zip(("hf_xs", "hf_ys", "hf_z"), hf, strict=True):
                self._views[name][:] = np.asarray(arr, dtype=np.float64).reshape(-1)
        spec["fds"] = [fd, child.fileno()]
        # the worker must import this very tactex, whatever sys.path the caller set up
        root = str(Path(__file__).resolve().parents[2])
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([root, *filter(None, [os.environ.get("PYTHONPATH")])]))
        env["OMP_NUM_THREADS"] = env.get("OMP_NUM_THREADS", "1")
        # glibc: keep a frame's freed temporaries (~5 MB) in the heap. In a fresh process the top of
        # the heap is trimmed back after each frame and large blocks are mmapped anew, whose page
        # faults would make a frame in the worker far slower than the same frame in process
        env.setdefault("MALLOC_MMAP_THRESHOLD_", str(64 << 20))
        env.setdefault("MALLOC_TRIM_THRESHOLD_", str(256 << 20))
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-c", "from tactex.sim.camera_worker import _main; _main()", json.dumps(spec)],
                pass_fds=(fd, child.fileno()), env=env, stdin=subprocess.DEVNULL,
            )
        except BaseException:
            parent.close()
            self._views.clear()
            self._mm.close()
            raise
        finally:
            os.close(fd)  # the worker holds its own copies; the mapping keeps the memory alive here
            child.close()
        self._sock = parent
        self.pid = self._proc.pid
        self._ready = False
        self._in_flight: tuple[np.ndarray, float] | None = None
        self._broken: str | None = None
        self._finalizer = weakref.finalize(self, _shutdown, self._proc, self._sock, self._mm, self._views)

    # -- public ---------------------------------------------------------------------------------
    @property
    def busy(self) -> bool:
        """A frame is in flight (submitted, not yet collected)."""
        return self._in_flight is not None

    @property
    def exit_code(self) -> int | None:
        """The worker's exit status once it has exited (negative: killed by that signal), else None."""
        return self._proc.poll()

    @property
    def alive(self) -> bool:
        return self._finalizer.alive and self._proc.poll() is None

    def wait_ready(self) -> float:
        """Block until the worker has started (imports done, ray caster built); returns the wait [s]."""
        t0 = time.perf_counter()
        if not self._ready:
            self._receive(_MSG_READY, "its start")
            self._ready = True
        return time.perf_counter() - t0

    def submit(self, world_T_camera: np.ndarray, object_position: np.ndarray, object_rotation: np.ndarray,
               timestamp: float, dirt_level: np.ndarray | None, seed: int, frame_index: int,
               noisy: bool) -> None:
        """Hand one snapshot to the worker (returns at once). ``seed`` and ``frame_index`` seed the
        frame's depth noise when ``noisy``, as the in-process camera does."""
        self._check_usable()
        if self._in_flight is not None:
            raise SimulationError("camera worker: a frame is already in flight; collect() it first")
        v = self._views
        pose = v["pose"]
        pose[0:16] = world_T_camera.reshape(16)
        pose[16:19] = object_position
        pose[19:28] = object_rotation.reshape(9)
        pose[28] = timestamp
        v["ints"][:] = (seed, frame_index, int(noisy))
        if dirt_level is not None:
            v["level"][:] = dirt_level
        self._send(_MSG_FRAME)
        self._in_flight = (np.array(world_T_camera, dtype=float), float(timestamp))

    def collect(self) -> CameraFrame:
        """The frame in flight, waiting for the worker if it is not done yet."""
        if self._in_flight is None:
            raise SimulationError("camera worker: no frame in flight")
        if not self._ready:
            self._receive(_MSG_READY, "its start")
            self._ready = True
        self._receive(_MSG_DONE, "the frame")
        world_T_cam, timestamp = self._in_flight
        self._in_flight = None
        k = self.intrinsics
        v = self._views
        return CameraFrame(depth_m=v["depth"].reshape(k.height, k.width).copy(), intrinsics=k,
                           world_T_camera=world_T_cam, timestamp=timestamp,
                           rgb=v["rgb"].reshape(k.height, k.width, 3).copy())

    def discard(self) -> None:
        """Drop the frame in flight (waits for the worker to finish it: the shared block is reused)."""
        if self._in_flight is not None:
            self.collect()

    def cpu_time_s(self) -> float:
        """User + system CPU time the worker has used so far [s] (from /proc; 0 once it has exited)."""
        try:
            with open(f"/proc/{self.pid}/stat", "rb") as f:
                fields = f.read().rsplit(b")", 1)[1].split()
        except OSError:
            return 0.0
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime (fields 14, 15)

    def close(self) -> None:
        """Stop the worker and release the shared memory (idempotent)."""
        self._in_flight = None
        self._finalizer()

    def __enter__(self) -> CameraWorker:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- internals ------------------------------------------------------------------------------
    def _check_usable(self) -> None:
        if self._broken is not None:
            raise SimulationError(self._broken)
        if not self._finalizer.alive:
            raise SimulationError("camera worker: already closed")

    def _send(self, msg: bytes) -> None:
        try:
            self._sock.send(msg)
        except OSError:
            self._fail(None)  # the message names the worker's exit code

    def _receive(self, expected: bytes, what: str) -> None:
        self._check_usable()
        deadline = time.monotonic() + self.timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                self._proc.kill()  # hung (or stopped): it cannot be trusted with the next frame
                self._fail(f"the camera worker (pid {self.pid}) did not finish {what} within {self.timeout_s:g} s "
                           "and was killed. Hint: raise camera_worker_timeout_s on a heavily loaded machine")
            # short slices: a worker killed while a descendant keeps the socket open is still noticed
            ready, _, _ = select.select([self._sock], [], [], min(left, 0.25))
            if not ready:
                if self._proc.poll() is not None:
                    self._fail(None)
                continue
            try:
                msg = self._sock.recv(65536)
            except OSError:
                msg = b""
            if not msg:
                self._fail(None)
            if msg[:1] == _MSG_ERROR:
                self._fail(f"the camera worker failed on {what}: {msg[1:].decode(errors='replace')}")
            if msg != expected:
                self._fail(f"camera worker protocol error: expected {expected!r}, got {msg[:40]!r}")
            return

    def _fail(self, message: str | None) -> None:
        if message is None:
            try:
                code = self._proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                code = None
            message = (f"the camera worker process (pid {self.pid}) died with exit code {code}"
                       + (" (killed by a signal)" if code is not None and code < 0 else ""))
        self._broken = message
        self._in_flight = None
        self._finalizer()
        raise SimulationError(message)


def _shutdown(proc: subprocess.Popen, sock: socket.socket, mm: mmap.mmap, views: dict) -> None:
    """Stop the worker (a stop message, then its socket closed; killed if it does not exit) and unmap."""
    try:
        sock.send(_MSG_STOP)
    except OSError:
        pass
    sock.close()
    try:
        proc.wait(timeout=5.0)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    views.clear()
    try:
        mm.close()
    except BufferError:  # a view escaped (never handed out); the mapping goes with the process
        pass


# -- the worker process ---------------------------------------------------------------------------
def _main() -> None:
    """Entry point of the worker process: ``python -c ... <spec JSON>``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle; it stops us
    spec = json.loads(sys.argv[1])
    fd, sock_fd = spec["fds"]
    sock = socket.socket(fileno=sock_fd)
    try:
        _serve(spec, fd, sock)
    except Exception as exc:  # report, then exit: the parent raises with this message
        try:
            sock.send(_MSG_ERROR + f"{type(exc).__name__}: {exc}".encode()[:60000])
        except OSError:
            pass
        raise


def _serve(spec: dict, fd: int, sock: socket.socket) -> None:
    from tactex.sim.board import ChessBoard, overlay_board
    from tactex.sim.camera import RayCastCamera
    from tactex.sim.dirt import DirtLookup
    from tactex.sim.objects import SimObject
    from tactex.sim.raycast import SceneRayCaster

    mm = mmap.mmap(fd, spec["size"])
    os.close(fd)
    layout, _ = _layout(spec)
    v = _views(mm, layout)
    o = spec["object"]
    obj = SimObject(name=o["name"], surface=_surface_from_spec(o["surface"]), base_thickness_m=o["base_thickness_m"],
                    hfield_spacing_m=o["hfield_spacing_m"])
    nx, ny = spec["hfield_shape"]
    hf = None if nx == 0 else (v["hf_xs"].copy(), v["hf_ys"].copy(), v["hf_z"].reshape(ny, nx).copy())
    c = spec["caster"]
    caster = SceneRayCaster(obj, c["table_top_z"], tuple(c["table_xy"]), c["newton_iterations"], c["tolerance_m"],
                            kind=spec["kind"], heightfield=hf)
    camera = RayCastCamera(None, -1, CameraIntrinsics(**spec["intrinsics"]), spec["depth_noise_m"],
                           method="analytic", caster=caster)
    d = spec["dirt"]
    dirt = None if d is None else DirtLookup(_surface_from_spec(d["surface"]), tuple(d["shape"]))
    rgb = None if spec["object_rgb"] is None else np.asarray(spec["object_rgb"], dtype=float)
    board = None if spec.get("board") is None else ChessBoard(**{k: tuple(v) if isinstance(v, list) else v
                                                                 for k, v in spec["board"].items()})
    pose, ints = v["pose"], v["ints"]
    level = v["level"] if dirt is not None else None
    depth_out, rgb_out = v["depth"], v["rgb"]
    sock.send(_MSG_READY)
    while True:
        try:
            msg = sock.recv(16)
        except OSError:  # the parent closed with a message of ours unread (ECONNRESET): it is gone
            return
        if msg != _MSG_FRAME:  # stop, or b"" when the parent is gone
            return
        p = pose.copy()
        seed, index, noisy = (int(i) for i in ints)
        rng = np.random.default_rng([seed, index]) if noisy else None
        frame = camera.render(p[0:16].reshape(4, 4), p[16:19], p[19:28].reshape(3, 3), float(p[28]), dirt=dirt,
                              dirt_level=level, object_rgb=rgb, rng=rng)
        depth_out[:] = frame.depth_m.reshape(-1)
        shown = frame.rgb if board is None else overlay_board(frame.rgb, frame.depth_m, board, p[0:16].reshape(4, 4),
                                                              camera.intrinsics)
        rgb_out[:] = shown.reshape(-1)
        try:
            sock.send(_MSG_DONE)
        except OSError:  # closed while this frame was in flight: nobody wants it
            return
