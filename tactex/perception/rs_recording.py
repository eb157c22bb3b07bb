"""Writing RealSense recordings (``.db3``/``.bag``) from frames made elsewhere (extra ``realsense``).

pyrealsense2's software device stands for a camera: a depth sensor (z16) and a colour sensor
(rgb8), each with its own intrinsics, the depth-to-colour extrinsics registered between them, and
the depth units as a read-only option, exactly what a D400 reports. ``rs.recorder`` writes what
the sensors receive into the file, which :class:`~tactex.perception.realsense.RealSenseSource`
plays back through the pipeline a live camera uses (alignment of depth to colour included). This
is how the camera path is tested without a device: render depth and colour of a known scene
(different intrinsics, cameras a few centimetres apart, as on a D435), record, play back.

The pipeline's syncer drops the first frame set of a recording, so the first frame pair is
recorded twice.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tactex.errors import InputError
from tactex.perception.depth import check_pose
from tactex.perception.frame import CameraIntrinsics
from tactex.perception.realsense import import_pyrealsense2

__all__ = ["RecordedPair", "write_realsense_recording"]


@dataclass(frozen=True)
class RecordedPair:
    """One frame of each stream.

    Attributes:
        depth_m: (H_d, W_d) depth along the depth camera's optical axis [m], 0 where invalid.
        rgb: (H_c, W_c, 3) uint8 colour image.
    """

    depth_m: np.ndarray
    rgb: np.ndarray


def _rs_intrinsics(rs, k: CameraIntrinsics):
    out = rs.intrinsics()
    out.width, out.height = int(k.width), int(k.height)
    out.fx, out.fy, out.ppx, out.ppy = float(k.fx), float(k.fy), float(k.cx), float(k.cy)
    out.model = rs.distortion.none
    out.coeffs = [0.0] * 5
    return out


def _stream(rs, kind, fmt, uid: int, k: CameraIntrinsics, bpp: int, fps: int):
    vs = rs.video_stream()
    vs.type, vs.fmt, vs.index, vs.uid = kind, fmt, 0, uid
    vs.width, vs.height, vs.fps, vs.bpp = int(k.width), int(k.height), int(fps), bpp
    vs.intrinsics = _rs_intrinsics(rs, k)
    return vs


def write_realsense_recording(
    path: str | Path,
    pairs: Sequence[RecordedPair],
    depth_intrinsics: CameraIntrinsics,
    color_intrinsics: CameraIntrinsics,
    color_T_depth: np.ndarray,
    *,
    depth_scale: float = 0.001,
    fps: int = 30,
) -> Path:
    """Record ``pairs`` as a RealSense recording at ``path`` (.db3 or .bag).

    Args:
        pairs: the frames, in order.
        depth_intrinsics, color_intrinsics: each stream's pinhole model [px].
        color_T_depth: (4, 4) pose of the depth camera's optical frame in the colour camera's [m]
            (RealSense's depth-to-colour extrinsics: p_colour = R·p_depth + t).
        depth_scale: metres per z16 unit (a D400's default: 0.001).
        fps: the streams' nominal rate [Hz]; the frames' timestamps are 1/fps apart.
    """
    rs = import_pyrealsense2()
    out = Path(path)
    if out.suffix not in (".db3", ".bag"):
        raise InputError(f"a RealSense recording is a .db3 or .bag file, got '{out}'")
    pairs = list(pairs)
    if not pairs:
        raise InputError("write_realsense_recording needs at least one frame pair")
    pose = check_pose(color_T_depth, "color_T_depth")
    kd, kc = depth_intrinsics, color_intrinsics
    raw = []
    for i, p in enumerate(pairs):
        if p.depth_m.shape != (kd.height, kd.width) or p.rgb.shape != (kc.height, kc.width, 3) \
                or p.rgb.dtype != np.uint8:
            raise InputError(f"frame pair {i}: depth {p.depth_m.shape} and rgb {p.rgb.shape} {p.rgb.dtype} do not "
                             f"match the intrinsics ({kd.height}, {kd.width}) and ({kc.height}, {kc.width}, 3) uint8")
        units = np.nan_to_num(np.asarray(p.depth_m, dtype=float) / depth_scale, nan=0.0)
        raw.append((np.clip(np.rint(units), 0, 65535).astype(np.uint16), np.ascontiguousarray(p.rgb)))
    raw.insert(0, raw[0])
    out.parent.mkdir(parents=True, exist_ok=True)
    out.unlink(missing_ok=True)

    dev = rs.software_device()
    depth_sensor, color_sensor = dev.add_sensor("Depth"), dev.add_sensor("Color")
    depth_sensor.add_read_only_option(rs.option.depth_units, float(depth_scale))
    dp = depth_sensor.add_video_stream(_stream(rs, rs.stream.depth, rs.format.z16, 0, kd, 2, fps))
    cp = color_sensor.add_video_stream(_stream(rs, rs.stream.color, rs.format.rgb8, 1, kc, 3, fps))
    dp, cp = dp.as_video_stream_profile(), cp.as_video_stream_profile()
    ext = rs.extrinsics()
    ext.rotation = pose[:3, :3].T.reshape(9).tolist()  # column-major
    ext.translation = pose[:3, 3].tolist()
    dp.register_extrinsics_to(cp, ext)
    recorder = rs.recorder(str(out), dev)
    sync = rs.syncer()
    depth_sensor.open(dp)
    color_sensor.open(cp)
    depth_sensor.start(sync)
    color_sensor.start(sync)
    for k, (depth, rgb) in enumerate(raw):
        stamp_ms = 1000.0 * k / fps
        for sensor, profile, pixels, bpp in ((depth_sensor, dp, depth, 2), (color_sensor, cp, rgb, 3)):
            frame = rs.software_video_frame()  # a new one per frame: librealsense keeps a reference to it
            frame.pixels = pixels
            frame.bpp = bpp
            frame.stride = bpp * pixels.shape[1]
            frame.timestamp = stamp_ms
            frame.domain = rs.timestamp_domain.hardware_clock
            frame.frame_number = k
            frame.profile = profile
            if bpp == 2:
                frame.depth_units = float(depth_scale)
            sensor.on_video_frame(frame)
    for sensor in (depth_sensor, color_sensor):
        sensor.stop()
        sensor.close()
    recorder.pause()
    del recorder, dev  # the file is complete once the recorder is released
    return out
