"""Intel RealSense source, live or from a recording (extra ``realsense``: pyrealsense2).

Opens the first (or a given) device, or plays back a RealSense recording (``.db3``/``.bag``,
``playback=``: its sensors into a syncer, as librealsense's playback tests read one), streams depth
(z16) and colour (rgb8), aligns depth to colour (as VA-UFIC does: "RGB and depth images are acquired
... precisely aligned"), and yields :class:`CameraFrame`s with the device's own intrinsics and depth
scale. The camera pose comes from the robot: ``world_T_camera = world_T_tool(t) · tool_T_camera``
(eq. 22), with the tool pose read from ``tool_pose_provider`` when the frame arrives; the frame is
the colour stream's optical frame (x right, y down, z forward), which the aligned depth shares.

A recording plays as fast as it is read (not in real time), so every recorded frame is seen; once
it has played to its end, :meth:`RealSenseSource.read` raises
:class:`~tactex.errors.CameraStreamEnded`, as it does when a live stream stalls.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from tactex.errors import CameraStreamEnded, InputError, MissingDependencyError, PerceptionError
from tactex.perception.frame import CameraFrame, CameraIntrinsics
from tactex.perception.mount import CameraMount

__all__ = ["RealSenseNotFoundError", "RealSenseSource", "import_pyrealsense2"]


#: Longest wait for a recording's sensors to stop when the source closes [s]; a player that does not stop
#: by then is left to the process's end rather than hang the run's report.
STOP_TIMEOUT_S = 5.0


class RealSenseNotFoundError(MissingDependencyError):
    """pyrealsense2 is installed but no RealSense device is connected."""

    def __init__(self, detail: str) -> None:
        ImportError.__init__(
            self,
            f"no Intel RealSense device found ({detail}); connect a D435i/D415 to a USB 3 port, "
            "or play a recording (RealSenseSource(playback=...), tactex capture --playback) or use the simulator's "
            "camera",
        )
        self.package = "pyrealsense2"
        self.extra = "realsense"


def import_pyrealsense2() -> Any:
    """Import pyrealsense2 or raise :class:`MissingDependencyError` naming the extra."""
    try:
        import pyrealsense2 as rs
    except ImportError as exc:
        if "libusb" in str(exc):  # the wheel is there; the system library it links against is not
            raise MissingDependencyError(
                "libusb-1.0", "", "The RealSense camera source (pyrealsense2)",
                fix="pyrealsense2 needs the system library libusb-1.0: apt-get install libusb-1.0-0") from exc
        raise MissingDependencyError("pyrealsense2", "realsense", "The RealSense camera source") from exc
    return rs


class RealSenseSource:
    """A :class:`~tactex.perception.pipeline.FrameSource` over a live RealSense camera.

    Args:
        width, height, fps: stream mode (640×480 at 30 Hz, as in VA-UFIC).
        mount: camera-on-tool extrinsics.
        tool_pose_provider: ``f() -> world_T_tool (4, 4)`` at the time of the call; None
            leaves the camera at the world origin (camera-frame estimates only).
        serial: device serial number, or None for the first device.
        timeout_ms: how long :meth:`read` waits for a frame.
        clock: timestamps of the produced frames [s] (the robot's clock, so ages compare).
        playback: a RealSense recording (.db3 or .bag) to play instead of a device; its own stream
            modes are used (``width``, ``height``, ``fps`` and ``serial`` are ignored).
    """

    def __init__(
        self,
        width: int = 640,
        height: int = 480,
        fps: int = 30,
        *,
        mount: CameraMount | None = None,
        tool_pose_provider: Callable[[], np.ndarray] | None = None,
        serial: str | None = None,
        timeout_ms: int = 1000,
        clock: Callable[[], float] = time.monotonic,
        playback: str | Path | None = None,
    ) -> None:
        if playback is not None:
            playback = Path(playback)
            if not playback.is_file():
                raise InputError(f"RealSense recording '{playback}' is not a file (give a .db3 or .bag recording)")
        rs = import_pyrealsense2()
        if playback is None:
            devices = rs.context().query_devices()
            serials = [d.get_info(rs.camera_info.serial_number) for d in devices]
            if not serials:
                raise RealSenseNotFoundError("pyrealsense2 reports 0 devices")
            if serial is not None and serial not in serials:
                raise RealSenseNotFoundError(f"serial {serial} not among connected devices {serials}")
        self._rs = rs
        self.playback = playback
        self.mount = mount or CameraMount()
        self.tool_pose_provider = tool_pose_provider
        self.timeout_ms = int(timeout_ms)
        self.clock = clock
        self._pipe = None
        self._player = None
        self._sensors: list = []
        if playback is not None:
            depth_sensor = self._start_playback(playback)
        else:
            self._pipe = rs.pipeline()
            cfg = rs.config()
            if serial is not None:
                cfg.enable_device(serial)
            cfg.enable_stream(rs.stream.depth, width, height, rs.format.z16, fps)
            cfg.enable_stream(rs.stream.color, width, height, rs.format.rgb8, fps)
            try:
                profile = self._pipe.start(cfg)
            except RuntimeError as exc:
                raise PerceptionError(f"the RealSense device refused the {width}×{height}@{fps} streams: {exc}") \
                    from exc
            depth_sensor = profile.get_device().first_depth_sensor()
        self.depth_scale = float(depth_sensor.get_depth_scale())
        self._align = rs.align(rs.stream.color)
        self.intrinsics: CameraIntrinsics | None = None

    def _start_playback(self, path: Path) -> Any:
        """Open the recording as a device: its sensors stream into a syncer, as fast as they are read."""
        rs = self._rs
        what = f"'{path}' is not a RealSense recording with depth (z16) and colour (rgb8) streams"
        try:
            device = rs.context().load_device(str(path))
        except RuntimeError as exc:
            raise InputError(f"{what} (record one with the RealSense Viewer or tactex.perception.rs_recording): "
                             f"{str(exc).strip()[:160]}") from None
        self._device = device
        self._player = device.as_playback()
        # not in real time: the recording waits for its reader, so no frame is dropped for a slow one
        self._player.set_real_time(False)
        sensors = device.query_sensors()
        streams = {(p.stream_type(), p.format()) for s in sensors for p in s.get_stream_profiles()}
        if not {(rs.stream.depth, rs.format.z16), (rs.stream.color, rs.format.rgb8)} <= streams:
            raise InputError(f"{what}; it holds {sorted(f'{t} {f}' for t, f in streams)}")
        self._sync = rs.syncer()
        for sensor in sensors:
            sensor.open(sensor.get_stream_profiles())
        for sensor in sensors:
            sensor.start(self._sync)
        self._sensors = sensors
        return device.first_depth_sensor()

    def _next_frames(self) -> Any:
        """The next frame set holding depth and colour."""
        if self._player is None:
            return self._pipe.wait_for_frames(self.timeout_ms)
        while True:  # the syncer's first sets may hold one stream each, before it has matched them
            ok, frames = self._sync.try_wait_for_frames(self.timeout_ms)
            if not ok:
                raise CameraStreamEnded(f"the RealSense recording '{self.playback}' ended: no frame within "
                                        f"{self.timeout_ms} ms")
            if frames.get_depth_frame() and frames.get_color_frame():
                return frames

    def read(self) -> CameraFrame | None:
        """Wait for the next aligned frame pair (raises :class:`~tactex.errors.CameraStreamEnded`
        when none comes within ``timeout_ms``, or a recording has played to its end)."""
        try:
            frames = self._next_frames()
        except CameraStreamEnded:
            raise
        except RuntimeError as exc:
            raise CameraStreamEnded(f"no frame from the RealSense within {self.timeout_ms} ms ({exc}): check its "
                                    "USB 3 cable and that no other program holds the camera") from exc
        stamp = self.clock()
        world_T_tool = self.tool_pose_provider() if self.tool_pose_provider is not None else np.eye(4)
        aligned = self._align.process(frames)
        depth_frame, color_frame = aligned.get_depth_frame(), aligned.get_color_frame()
        if not depth_frame or not color_frame:
            raise PerceptionError("the RealSense delivered a frame set without depth or colour")
        if self.intrinsics is None:
            # Depth is aligned to colour: the colour stream's intrinsics describe both.
            ci = color_frame.profile.as_video_stream_profile().get_intrinsics()
            self.intrinsics = CameraIntrinsics(
                int(ci.width), int(ci.height), float(ci.fx), float(ci.fy), float(ci.ppx), float(ci.ppy),
                depth_scale=self.depth_scale,
            )
        # CameraFrame.depth_m is float metres; 0 stays 0 (invalid).
        depth = np.asanyarray(depth_frame.get_data()).astype(np.float32) * np.float32(self.depth_scale)
        rgb = np.array(np.asanyarray(color_frame.get_data()), dtype=np.uint8)
        return CameraFrame(depth, self.intrinsics, self.mount.world_T_camera(world_T_tool), stamp, rgb)

    def close(self) -> None:
        """Stop the streams (idempotent)."""
        if self._pipe is not None:
            pipe, self._pipe = self._pipe, None
            pipe.stop()
        sensors, self._sensors = self._sensors, []
        if sensors:
            # A recording not played in real time waits until its frames are taken: stopping its
            # sensors while the syncer holds unread ones can wait forever, so they are stopped in a
            # thread while this one drains the syncer (with a pause between polls: a spinning drain
            # starves the stopping thread of the GIL), for at most STOP_TIMEOUT_S.
            import threading

            def stop() -> None:
                for sensor in sensors:
                    sensor.stop()
                for sensor in sensors:
                    sensor.close()

            stopper = threading.Thread(target=stop, daemon=True)
            stopper.start()
            deadline = time.monotonic() + STOP_TIMEOUT_S
            while stopper.is_alive() and time.monotonic() < deadline:
                self._sync.poll_for_frames()
                stopper.join(0.005)

    def __enter__(self) -> RealSenseSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
