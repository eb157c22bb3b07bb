"""A replay video of a run: its recorded joint positions rendered in a fresh scene, as a GIF."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from tactex.errors import ConfigError, InputError

__all__ = ["write_replay_video"]


def write_replay_video(result: Any, path: str | Path, *, fps: float = 8.0, max_frames: int = 80,
                       width: int = 320, height: int = 240) -> Path:
    """Replay the recorded joint positions ``series['q']`` in a fresh scene and write an animated GIF.

    Kinematic replay (the dirt texture is not replayed): MuJoCo renders each posture with OpenGL,
    so this needs ``MUJOCO_GL=egl`` or ``osmesa`` on a machine without a display; otherwise
    :class:`MissingDependencyError`. Pillow (a matplotlib dependency) writes the GIF, so no ffmpeg.
    """
    from PIL import Image

    from tactex.robots.mujoco_backend import MujocoBackend

    series = getattr(result, "series", {}) or {}
    if "q" not in series or "t" not in series:
        raise InputError("the run recorded no joint positions 'q' in its series, so there is nothing to replay")
    q, t = np.asarray(series["q"], dtype=np.float64), np.asarray(series["t"], dtype=np.float64)
    if q.ndim != 2 or q.shape[0] != t.shape[0] or q.shape[0] == 0:
        raise InputError(f"series 'q' must be (T, n_joints) like 't' ({t.shape[0]} rows), got {q.shape}")
    if fps <= 0 or max_frames < 1:
        raise ConfigError(f"fps must be > 0 and max_frames ≥ 1, got {fps} and {max_frames}")
    n = int(min(max_frames, max(1, np.floor((t[-1] - t[0]) * fps) + 1)))
    idx = np.unique(np.searchsorted(t, np.linspace(t[0], t[-1], n)).clip(0, len(t) - 1))
    backend = MujocoBackend(result.config.scene())
    try:
        frames = []
        for i in idx:
            if not np.isfinite(q[i]).all():
                continue
            backend.reset(q0=q[i])
            frames.append(Image.fromarray(backend.render_rgb(width, height)))
    finally:
        backend.close()
    if not frames:
        raise InputError("series 'q' holds no finite posture to render")
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    frames[0].save(out, save_all=True, append_images=frames[1:], duration=int(1000 / fps), loop=0)
    return out
