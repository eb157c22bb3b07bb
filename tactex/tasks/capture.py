"""One coloured scan from the wrist camera → a cloud in the robot base frame (TEC §V-A1's capture).

The frames come from a :class:`~tactex.perception.pipeline.FrameSource` whose frames are posed in
the robot base frame: a RealSense (live, or a recording played back) posed by a given
``base_T_camera`` or by the robot's tool pose and the hand-eye calibration, or tactex's simulated
scene, whose arm moves to the capture pose(s) above its object. The frames are merged, cropped to
the workspace box (which also cuts the table the robot stands on), voxelised and cleaned of
outliers; each point gets a normal from its neighbours, turned towards the camera. The cloud keeps
its colours and no target: what is dirt is decided by whoever reads the file (``tactex explore``
and ``tactex clean --cloud`` take red by hue), so the scan can be re-used with another rule.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from tactex.config import param
from tactex.errors import CameraStreamEnded, ConfigError, InputError, PerceptionError
from tactex.perception.acquisition import AcquisitionConfig, acquire_surface
from tactex.perception.frame import CameraFrame
from tactex.perception.normals import knn_normals
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.pointcloud.io import save_ply

__all__ = [
    "DEFAULT_BOX_M",
    "CaptureConfig",
    "SimCaptureSource",
    "capture_cloud",
    "frames_to_cloud",
    "read_views",
    "write_capture",
]

#: Workspace box (xmin, ymin, zmin, xmax, ymax, zmax) in the robot base frame [m]: in front of a
#: Franka, within its reach, from 2 mm above the surface it stands on (the table is cut away, as the
#: clean's own capture cuts it; a higher floor cuts a flat part's thin middle, a plate's well).
DEFAULT_BOX_M = (0.2, -0.5, 0.002, 0.9, 0.5, 0.5)


@dataclass(frozen=True)
class CaptureConfig:
    """What a capture keeps of its frames (units in brackets)."""

    box_m: tuple[float, float, float, float, float, float] = param(
        DEFAULT_BOX_M, "workspace box xmin ymin zmin xmax ymax zmax in the robot base frame [m]")
    voxel_size_m: float = param(0.003, "voxel grid of the cloud (TEC: 3 mm); 0 keeps every pixel's point [m]")
    views: int = param(1, "frames merged into the cloud: from several poses where the arm moves (the simulated "
                          "scene), else consecutive frames of the camera [-]")
    normal_k: int = param(16, "neighbours of each point's normal [-]")
    sor_mean_k: int = param(50, "statistical outlier removal: neighbours (0 disables) [-]")

    def __post_init__(self) -> None:
        box = np.asarray(self.box_m, dtype=float)
        if box.shape != (6,) or not np.isfinite(box).all() or not (box[:3] < box[3:]).all():
            raise ConfigError(f"box_m must be six finite numbers xmin ymin zmin xmax ymax zmax with each min below "
                              f"its max [m], got {self.box_m!r}")
        if np.abs(box).max() > 5.0:
            raise ConfigError(f"box_m reaches {np.abs(box).max():g} from the robot base: it is in metres")
        if not (np.isfinite(self.voxel_size_m) and 0 <= self.voxel_size_m <= 0.05):
            raise ConfigError(f"voxel_size_m must be in [0, 0.05] m, got {self.voxel_size_m!r}")
        for name, lo in (("views", 1), ("normal_k", 3), ("sor_mean_k", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo or v > 1000:
                raise ConfigError(f"{name} must be a whole number in [{lo}, 1000], got {v!r}")

    def acquisition(self) -> AcquisitionConfig:
        box = tuple(float(v) for v in self.box_m)
        return AcquisitionConfig(crop_min_m=box[:3], crop_max_m=box[3:], voxel_size_m=self.voxel_size_m,
                                 sor_mean_k=self.sor_mean_k, color_method="hsv")


def read_views(source, views: int, what: str = "the camera",
               purpose: str = "frames of the capture") -> list[CameraFrame]:
    """``views`` frames from ``source`` (``read() -> CameraFrame | None``); a source that ends
    first is a :class:`~tactex.errors.CameraStreamEnded` naming how many of the ``purpose`` came."""
    frames: list[CameraFrame] = []
    for _ in range(views):
        try:
            frame = source.read()
        except CameraStreamEnded as exc:  # a source that says why it ended (a recording's end, a timeout)
            raise CameraStreamEnded(f"{what} stopped after {len(frames)} of the {views} {purpose}: {exc}") from exc
        if frame is None:
            raise CameraStreamEnded(f"{what} stopped after {len(frames)} of the {views} {purpose}")
        frames.append(frame)
    return frames


def frames_to_cloud(frames: Sequence[CameraFrame], config: CaptureConfig | None = None) -> SurfaceCloud:
    """The base-frame cloud of posed frames: merged, cropped, voxelised, outliers removed, normals
    from ``normal_k`` neighbours turned towards the cameras, colours kept, no target."""
    cfg = config or CaptureConfig()
    frames = list(frames)
    if not frames:
        raise PerceptionError("a capture needs at least one frame")
    if any(f.rgb is None for f in frames):
        raise PerceptionError("a capture needs colour in every frame (the camera delivered depth only)")
    cloud = acquire_surface(frames, cfg.acquisition())
    if len(cloud) <= cfg.normal_k:
        lo, hi = np.round(cfg.box_m[:3], 3).tolist(), np.round(cfg.box_m[3:], 3).tolist()
        raise PerceptionError(
            f"the capture holds only {len(cloud)} points inside the box {lo}…{hi} m (need > {cfg.normal_k}): is the "
            "object in the camera's view and inside --box, and is the camera pose in the robot base frame?")
    eye = np.mean([f.world_T_camera[:3, 3] for f in frames], axis=0)
    field = knn_normals(cloud.points, cfg.normal_k, viewpoint=eye)
    kept = cloud.subset(field.ok)
    return replace(kept, normals=field.normals[field.ok], spacing=cloud.spacing).with_target(np.zeros(len(kept)))


def capture_cloud(source, config: CaptureConfig | None = None, what: str = "the camera") -> SurfaceCloud:
    """:func:`frames_to_cloud` of ``config.views`` frames read from ``source``."""
    cfg = config or CaptureConfig()
    return frames_to_cloud(read_views(source, cfg.views, what), cfg)


def write_capture(cloud: SurfaceCloud, path: str | Path) -> Path:
    """The cloud as a binary PLY (x y z, normals, colours; target 0: chosen by the reader)."""
    out = Path(path)
    if out.suffix.lower() != ".ply":
        raise InputError(f"the capture is written as a PLY file: give --out a name ending in .ply, got '{out}'")
    return save_ply(cloud, out)


class SimCaptureSource:
    """Frames of tactex's simulated scene: the arm is placed (inverse kinematics) at each capture
    pose in turn and the wrist camera renders what it sees, dirt included.

    Args:
        scene_config: the scene (object, marking, camera resolution).
        base_T_camera: render from this camera pose instead (the arm is not used) [m].
        distance_m: the TCP's height above the object's top at the first view [m].
        tilt_deg: the further views look at the same point from this far off the vertical [deg].
    """

    def __init__(self, scene_config=None, *, base_T_camera: np.ndarray | None = None, distance_m: float = 0.42,
                 tilt_deg: float = 15.0) -> None:
        from tactex.robots.mujoco_backend import MujocoBackend
        from tactex.sim.scene import SceneConfig

        self.sim = MujocoBackend(scene_config or SceneConfig())
        self.base_T_camera = None if base_T_camera is None else np.asarray(base_T_camera, dtype=float)
        self.distance_m = float(distance_m)
        self.tilt_deg = float(tilt_deg)
        self._k = 0

    def view_pose(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """TCP position [m] and rotation of view ``k``: straight above the object's top, then around it."""
        from tactex.tasks.runner import tool_rotation_for_normal

        pos, rot = self.sim.object_pose()
        top = pos + rot @ np.array([0.0, 0.0, float(self.sim.scene.sim_object.surface.bounds_m[1, 2])])
        if k == 0:
            look = np.array([0.0, 0.0, 1.0])
        else:
            # from the sides and the robot's side first: the far side is the hardest to reach
            tilt, az = np.radians(self.tilt_deg), np.pi / 2.0 * (1 + (k - 1) % 4)
            look = np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)])
        return top + self.distance_m * look, tool_rotation_for_normal(look)

    def read(self) -> CameraFrame:
        sim = self.sim
        if self.base_T_camera is not None:
            obj_pos, obj_rot = sim.object_pose()
            frame = sim.camera.render(self.base_T_camera, obj_pos, obj_rot, float(self._k), dirt=sim.scene.dirt,
                                      dirt_level=sim.scene.dirt.level.copy(),
                                      object_rgb=sim.scene.sim_object.rgb)
        else:
            position, rotation = self.view_pose(self._k)
            sim.reset()  # each view's IK from the home posture: the same branch whatever came before
            sim.reset(q0=sim.solve_ik(position, rotation))
            frame = sim.render_depth()
        self._k += 1
        return frame

    def close(self) -> None:
        self.sim.close()
