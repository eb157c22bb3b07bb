"""The twin's wrist camera: RGB-D frames of its own scene served over TCP (:mod:`tactex.perception.twin_camera`).

Each frame is rendered by tactex's analytic ray caster (:class:`~tactex.sim.camera.RayCastCamera`) from a
snapshot the 1 kHz simulation thread takes between two steps: the wrist camera's pose in the twin's own
robot state (the MuJoCo camera on the tool, so the pose follows the arm as franky-sim moves it) and the
dirt as the twin's wear has left it. The ray casting runs in a :class:`~tactex.sim.camera_worker.CameraWorker`
process (started with the first stream), so a 640×480 frame costs the simulation thread only the
snapshot's copy, not the GIL.

Frames are rendered only while a client streams (a camera pipeline runs only while started). ``paused``
stops the frames with the connection kept open: the client then sees a camera that went silent (a drill
for the fault, SIGUSR2 on ``tactex twin``).
"""

from __future__ import annotations

import json
import math
import select
import socket
import threading
import time
from dataclasses import replace
from typing import Any

import numpy as np

from tactex.errors import TactexError
from tactex.perception.twin_camera import encode_frame, intrinsics_header

__all__ = ["TWIN_DEPTH_SCALE_M", "TwinCameraServer"]

#: Metres per depth unit of the served z16 frames (a D4xx set to 100 µm depth units).
TWIN_DEPTH_SCALE_M = 1e-4
#: Longest wait for the simulation thread's snapshot [s]; a twin that stalls longer sends no frame.
SNAPSHOT_TIMEOUT_S = 2.0


class TwinCameraServer:
    """Serves the wrist camera of ``twin`` (a :class:`~tactex.twin.twin.Twin` whose simulation runs) on
    ``host:port`` at ``width``×``height`` px and ``rate_hz``; :meth:`close` stops it."""

    def __init__(self, twin: Any, host: str, port: int, width: int, height: int, rate_hz: float) -> None:
        from tactex.sim.camera import RayCastCamera
        from tactex.sim.camera_worker import CameraWorker
        from tactex.sim.raycast import SceneRayCaster

        scene = replace(twin.scene, camera_width=int(width), camera_height=int(height))
        self.intrinsics = replace(scene.intrinsics, depth_scale=TWIN_DEPTH_SCALE_M)
        camera = RayCastCamera(None, -1, self.intrinsics, method="analytic", caster=SceneRayCaster(scene.sim_object))
        self.twin = twin
        self.rate_hz = float(rate_hz)
        self.paused = threading.Event()
        self.frames_sent = 0
        self._closed = threading.Event()
        self._render_lock = threading.Lock()  # one worker, one frame in flight
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((host, int(port)))
        except OSError as exc:
            sock.close()
            raise TactexError(f"tcp {host}:{port} (the twin's camera) cannot be bound ({exc.strerror}): stop what "
                              "serves there, or pick another port with --port-camera") from None
        sock.listen(4)
        self._listener = sock
        self.address = sock.getsockname()
        # the render worker starts with the first stream: a twin whose camera is never used pays nothing for it
        self._make_worker = lambda: CameraWorker(camera, twin.dirt, object_rgb=np.asarray(scene.sim_object.rgb,
                                                                                          dtype=float),
                                                 board=twin.config.chess_board())
        self.worker: Any = None
        self._thread = threading.Thread(target=self._accept, name="twin-camera", daemon=True)
        self._thread.start()

    # -- connections ---------------------------------------------------------------------------------
    def _accept(self) -> None:
        while not self._closed.is_set():
            try:
                ready, _, _ = select.select([self._listener], [], [], 0.2)
                if not ready:
                    continue
                conn, _ = self._listener.accept()
            except OSError:
                return
            threading.Thread(target=self._handle, args=(conn,), name="twin-camera-client", daemon=True).start()

    def _handle(self, conn: socket.socket) -> None:
        try:
            conn.settimeout(5.0)
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            request = conn.makefile("rb").readline(64).strip()
            if request == b"status":
                conn.sendall((json.dumps(self._status()) + "\n").encode())
            elif request == b"stream":
                self._stream(conn)
        except OSError:
            pass  # the client left
        finally:
            conn.close()

    def _status(self) -> dict:
        status = self.twin.status()
        status["camera_frames_sent"] = self.frames_sent
        status["camera_paused"] = self.paused.is_set()
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in status.items()}

    @staticmethod
    def _client_left(conn: socket.socket) -> bool:
        readable, _, _ = select.select([conn], [], [], 0.0)
        return bool(readable) and conn.recv(1, socket.MSG_PEEK) == b""

    def _stream(self, conn: socket.socket) -> None:
        k = self.intrinsics
        conn.sendall(intrinsics_header(k, self.rate_hz))
        period = 1.0 / self.rate_hz
        next_t = time.monotonic()
        seq = 0
        while not self._closed.is_set() and not self._client_left(conn):
            now = time.monotonic()
            if now < next_t or self.paused.is_set():
                time.sleep(min(max(next_t - now, 0.0), 0.05) if not self.paused.is_set() else 0.05)
                continue
            next_t = max(next_t + period, now)
            snap = self.twin.camera_snapshot(SNAPSHOT_TIMEOUT_S)
            if snap is None:
                continue  # the simulation stalled: no frame this period
            base_T_camera, obj_pos, obj_rot, t, level = snap
            with self._render_lock:
                if self.worker is None:
                    self.worker = self._make_worker()
                self.worker.submit(base_T_camera, obj_pos, obj_rot, t, level, 0, seq, False)
                frame = self.worker.collect()
            conn.sendall(encode_frame(seq, t, base_T_camera, frame.depth_m, frame.rgb, k.depth_scale))
            seq += 1
            self.frames_sent += 1

    def close(self) -> None:
        """Stop serving and the render worker (idempotent)."""
        if self._closed.is_set():
            return
        self._closed.set()
        self._listener.close()
        self._thread.join(timeout=2.0)
        with self._render_lock:
            if self.worker is not None:
                self.worker.close()
