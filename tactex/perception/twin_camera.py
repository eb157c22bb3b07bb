"""The wrist camera of ``tactex twin`` over TCP: the wire format and the client frame source.

The twin renders RGB-D frames of its own scene (its dirt as it is now) from the wrist camera's pose
in its own robot state and serves them on ``HOST:PORT`` (:mod:`tactex.twin.camera_server`). A
client sends one request line:

- ``stream``: the server answers with a JSON line (the intrinsics of the colour stream, which the
  depth shares, its depth scale and rate), then frames at that rate for as long as the connection
  stays open; each frame is a 4-byte big-endian length, a JSON header (``seq``, ``t`` the twin's
  simulated time [s], ``base_T_camera`` the pose the twin rendered from, row-major) and the pixels:
  depth as uint16 (``depth_scale`` metres per unit, 0 = no depth), then colour as rgb8, row-major;
- ``status``: the twin's status as one JSON line (its own count of the dirt removed among it).

:class:`TwinCameraSource` is a :class:`~tactex.perception.pipeline.FrameSource` over it, posed like
a RealSense: ``world_T_camera = world_T_tool · tool_T_camera`` with the tool pose the robot reports
when the frame arrives, so a hand-eye error shows as it would on the real robot (the twin's own pose
is kept in :attr:`TwinCameraSource.rendered_pose`). A stream that stays silent for ``timeout_s``
or closes is a :class:`~tactex.errors.CameraStreamEnded`.
"""

from __future__ import annotations

import json
import socket
import struct
import time
from collections.abc import Callable

import numpy as np

from tactex.errors import CameraStreamEnded, InputError
from tactex.perception.frame import CameraFrame, CameraIntrinsics
from tactex.perception.mount import CameraMount

__all__ = ["TWIN_CAMERA_PORT", "TwinCameraSource", "decode_frame", "encode_frame", "intrinsics_header",
           "twin_status"]

#: TCP port of the twin's camera (beside franky-sim's 1337 and 1338).
TWIN_CAMERA_PORT = 1339
_LEN = struct.Struct(">I")
#: Largest header or status line accepted [bytes]: a corrupt stream is refused, not read into memory.
_MAX_LINE = 1 << 20


def intrinsics_header(k: CameraIntrinsics, rate_hz: float) -> bytes:
    """The stream's first line: the colour stream's intrinsics (the depth is aligned to it) and rate."""
    return (json.dumps({"width": k.width, "height": k.height, "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy,
                        "depth_scale": k.depth_scale, "min_depth_m": k.min_depth_m, "max_depth_m": k.max_depth_m,
                        "rate_hz": rate_hz}) + "\n").encode()


def encode_frame(seq: int, t: float, base_T_camera: np.ndarray, depth_m: np.ndarray, rgb: np.ndarray,
                 depth_scale: float) -> bytes:
    """One frame on the wire: length, JSON header, z16 depth (``depth_scale`` m per unit), rgb8."""
    header = json.dumps({"seq": int(seq), "t": float(t),
                         "base_T_camera": np.asarray(base_T_camera, dtype=float).reshape(16).tolist()}).encode()
    z16 = np.clip(np.rint(np.asarray(depth_m, dtype=np.float64) / depth_scale), 0, 65535).astype("<u2")
    return b"".join((_LEN.pack(len(header)), header, z16.tobytes(), np.ascontiguousarray(rgb, np.uint8).tobytes()))


def decode_frame(header: bytes, pixels: bytes, k: CameraIntrinsics) -> tuple[dict, np.ndarray, np.ndarray]:
    """(header dict, depth [m] float32 (H, W), rgb uint8 (H, W, 3)) of one frame's parts."""
    n = k.width * k.height
    meta = json.loads(header)
    depth = np.frombuffer(pixels, dtype="<u2", count=n).astype(np.float32) * np.float32(k.depth_scale)
    rgb = np.frombuffer(pixels, dtype=np.uint8, count=3 * n, offset=2 * n).reshape(k.height, k.width, 3).copy()
    return meta, depth.reshape(k.height, k.width), rgb


def _recv_exact(sock: socket.socket, n: int) -> bytes:
    buf = bytearray(n)
    view, got = memoryview(buf), 0
    while got < n:
        k = sock.recv_into(view[got:], n - got)
        if k == 0:
            raise ConnectionError("the connection closed")
        got += k
    return bytes(buf)


def _recv_line(sock: socket.socket) -> bytes:
    out = bytearray()
    while not out.endswith(b"\n"):
        chunk = sock.recv(1)
        if not chunk:
            raise ConnectionError("the connection closed")
        out += chunk
        if len(out) > _MAX_LINE:
            raise ConnectionError("a line longer than 1 MiB: not the twin's camera")
    return bytes(out)


def _connect(host: str, port: int, timeout_s: float, request: bytes) -> socket.socket:
    try:
        sock = socket.create_connection((host, port), timeout=timeout_s)
    except OSError as exc:
        raise CameraStreamEnded(f"the twin's camera at tcp {host}:{port} cannot be reached ({exc.strerror or exc}): "
                                "is tactex twin running there with its camera (--port-camera)?") from None
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    sock.sendall(request)
    return sock


def twin_status(host: str, port: int = TWIN_CAMERA_PORT, timeout_s: float = 5.0) -> dict:
    """The twin's status (``dirt_removed_fraction``: its own count, and more) through its camera port."""
    sock = _connect(host, port, timeout_s, b"status\n")
    try:
        return json.loads(_recv_line(sock))
    except (OSError, ConnectionError, ValueError) as exc:
        raise CameraStreamEnded(f"the twin at tcp {host}:{port} sent no status ({exc})") from None
    finally:
        sock.close()


class TwinCameraSource:
    """Frames of the twin's wrist camera (a :class:`~tactex.perception.pipeline.FrameSource`).

    The stream is opened at the first :meth:`read` and closed by :meth:`stop` (the twin renders only
    while a client streams, as a camera pipeline runs only while started); :meth:`read` waits for the
    next frame.

    Args:
        host, port: the twin's camera address.
        mount: tool_T_camera, the hand-eye calibration (the tactex tool's nominal mount on the twin).
        tool_pose_provider: ``f() -> world_T_tool (4, 4)`` when a frame arrives (the robot's state).
        timeout_s: longest wait for a frame [s] before :class:`CameraStreamEnded`.
        start_timeout_s: the same for a stream's first frame (the twin starts its render worker then) [s].
        clock: the frames' timestamps [s].
    """

    def __init__(self, host: str, port: int = TWIN_CAMERA_PORT, *, mount: CameraMount | None = None,
                 tool_pose_provider: Callable[[], np.ndarray] | None = None, timeout_s: float = 5.0,
                 start_timeout_s: float = 60.0, clock: Callable[[], float] = time.monotonic) -> None:
        if not (isinstance(port, int) and 0 < port < 65536):
            raise InputError(f"the twin's camera port must be a TCP port in 1..65535, got {port!r}")
        self.host, self.port = host, int(port)
        self.mount = mount or CameraMount()
        self.tool_pose_provider = tool_pose_provider
        self.timeout_s = float(timeout_s)
        self.start_timeout_s = float(start_timeout_s)
        self.clock = clock
        self.intrinsics: CameraIntrinsics | None = None
        self.rate_hz = float("nan")
        self.rendered_pose: np.ndarray | None = None  # base_T_camera the twin rendered the last frame from
        self.frames = 0
        self._sock: socket.socket | None = None

    @property
    def what(self) -> str:
        return f"the twin's camera at tcp {self.host}:{self.port}"

    def _open(self) -> socket.socket:
        sock = _connect(self.host, self.port, self.start_timeout_s, b"stream\n")
        try:
            head = json.loads(_recv_line(sock))
            self.rate_hz = float(head.pop("rate_hz"))
            self.intrinsics = CameraIntrinsics(**head)
        except (OSError, ConnectionError, ValueError, TypeError, KeyError) as exc:
            sock.close()
            raise CameraStreamEnded(f"{self.what} sent no stream header ({exc})") from None
        self._sock = sock
        return sock

    def read(self) -> CameraFrame:
        """The next frame (raises :class:`CameraStreamEnded` when none comes within ``timeout_s``)."""
        sock = self._sock or self._open()
        k = self.intrinsics
        assert k is not None
        try:
            (n,) = _LEN.unpack(_recv_exact(sock, _LEN.size))
            if n > _MAX_LINE:
                raise ConnectionError(f"a frame header of {n} bytes")
            header = _recv_exact(sock, n)
            pixels = _recv_exact(sock, 5 * k.width * k.height)
        except TimeoutError:
            self.stop()
            raise CameraStreamEnded(f"{self.what} sent no frame within {sock.gettimeout():g} s (after {self.frames} "
                                    "frame(s)): is the twin's camera stream stopped?") from None
        except (OSError, ConnectionError) as exc:
            self.stop()
            raise CameraStreamEnded(f"{self.what} stopped after {self.frames} frame(s) ({exc})") from None
        sock.settimeout(self.timeout_s)  # the stream runs: later frames come at its rate
        meta, depth, rgb = decode_frame(header, pixels, k)
        self.rendered_pose = np.asarray(meta["base_T_camera"], dtype=float).reshape(4, 4)
        self.frames += 1
        world_T_tool = self.tool_pose_provider() if self.tool_pose_provider is not None else np.eye(4)
        return CameraFrame(depth, k, self.mount.world_T_camera(world_T_tool), self.clock(), rgb)

    def stop(self) -> None:
        """Close the stream (the twin stops rendering); the next :meth:`read` opens it again."""
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()

    def close(self) -> None:
        self.stop()

    def __enter__(self) -> TwinCameraSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
