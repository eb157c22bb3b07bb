"""Recording and replaying camera frames as ``.npz`` (plain arrays, never pickle).

File layout (all frames share one camera model):

- ``depth_m``: (T, H, W) float32 [m] (0/NaN invalid);
- ``rgb``: (T, H, W, 3) uint8 (only when every frame has colour);
- ``world_T_camera``: (T, 4, 4) float64; ``timestamp``: (T,) float64 [s];
- ``intrinsics``: (9,) float64, see :meth:`CameraIntrinsics.to_array`;
- ``format``: the string ``"tactex-frames-v1"``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from tactex.errors import InputError, PerceptionError
from tactex.perception.depth import depth_in_meters
from tactex.perception.frame import CameraFrame, CameraIntrinsics

__all__ = ["FORMAT", "FrameRecorder", "RecordedFrameSource", "load_frames", "save_frames"]

FORMAT = "tactex-frames-v1"


def save_frames(path: str | Path, frames: Sequence[CameraFrame]) -> Path:
    """Write frames (same intrinsics) to ``path`` (.npz)."""
    frames = list(frames)
    if not frames:
        raise InputError("save_frames needs at least one frame")
    intr = frames[0].intrinsics
    for k, fr in enumerate(frames):
        if fr.intrinsics != intr:
            raise PerceptionError(f"frame {k} has other intrinsics than frame 0; record one camera per file")
    depth = np.stack([depth_in_meters(fr.depth_m, intr) for fr in frames])
    arrays = {
        "format": np.array(FORMAT),
        "depth_m": depth.astype(np.float32),
        "world_T_camera": np.stack([np.asarray(fr.world_T_camera, np.float64) for fr in frames]),
        "timestamp": np.array([fr.timestamp for fr in frames], dtype=np.float64),
        "intrinsics": intr.to_array(),
    }
    has_rgb = [fr.rgb is not None for fr in frames]
    if all(has_rgb):
        rgb = np.stack([np.asarray(fr.rgb) for fr in frames])
        if rgb.dtype != np.uint8 or rgb.shape[1:] != (intr.height, intr.width, 3):
            raise PerceptionError(f"rgb must be uint8 (H, W, 3) to record, got {rgb.dtype} {rgb.shape[1:]}")
        arrays["rgb"] = rgb
    elif any(has_rgb):
        raise PerceptionError("either every frame or no frame must carry rgb")
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out, **arrays)
    return out


def load_frames(path: str | Path) -> list[CameraFrame]:
    """Read frames written by :func:`save_frames`."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"frame recording '{p}' does not exist")
    try:
        with np.load(p, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (ValueError, OSError) as exc:
        raise PerceptionError(f"'{p}' is not a readable .npz of arrays: {exc}") from exc
    missing = {"depth_m", "world_T_camera", "timestamp", "intrinsics"} - set(data)
    if missing:
        raise PerceptionError(f"'{p}' is not a tactex frame recording: missing {sorted(missing)}")
    if "format" in data and str(data["format"]) != FORMAT:
        raise PerceptionError(f"'{p}' has format {data['format']!s}, expected {FORMAT}")
    intr = CameraIntrinsics.from_array(data["intrinsics"])
    depth, poses, stamps = data["depth_m"], data["world_T_camera"], data["timestamp"]
    n = depth.shape[0]
    if poses.shape != (n, 4, 4) or stamps.shape != (n,):
        raise PerceptionError(f"'{p}': {n} depth images but poses {poses.shape} and timestamps {stamps.shape}")
    rgb = data.get("rgb")
    return [
        CameraFrame(depth[k], intr, poses[k], float(stamps[k]), None if rgb is None else rgb[k]) for k in range(n)
    ]


class FrameRecorder:
    """Collects frames (e.g. from a live camera or the simulator) and writes them on ``close()``."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.frames: list[CameraFrame] = []

    def add(self, frame: CameraFrame) -> None:
        self.frames.append(frame)

    def extend(self, frames: Iterable[CameraFrame]) -> None:
        self.frames.extend(frames)

    def close(self) -> Path:
        return save_frames(self.path, self.frames)

    def __enter__(self) -> FrameRecorder:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is None and self.frames:
            self.close()


class RecordedFrameSource:
    """A :class:`~tactex.perception.pipeline.FrameSource` replaying a recording (or a list of frames)."""

    def __init__(self, frames: str | Path | Sequence[CameraFrame], *, loop: bool = False) -> None:
        self.frames = load_frames(frames) if isinstance(frames, (str, Path)) else list(frames)
        self.loop = loop
        self._next = 0

    def read(self) -> CameraFrame | None:
        if self._next >= len(self.frames):
            if not self.loop or not self.frames:
                return None
            self._next = 0
        frame = self.frames[self._next]
        self._next += 1
        return frame

    def __len__(self) -> int:
        return len(self.frames)
