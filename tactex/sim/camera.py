"""Wrist RGB-D camera by ray casting (``mujoco.mj_multiRay``): works without OpenGL.

One ray per pixel through the pinhole model of :class:`~tactex.perception.frame.CameraIntrinsics`.
The ray directions are (x', y', 1) in the optical frame (not normalised), so MuJoCo's distance
along them *is* the depth along the optical axis. Colour comes from what each ray hits: the
object's clean colour blended with its dirt level, the table, or black for misses. The robot's own
geoms are not seen (they are in geom group 2, which the rays skip).
"""

from __future__ import annotations

import mujoco
import numpy as np

from tactex.perception.frame import CameraFrame, CameraIntrinsics
from tactex.sim.dirt import DirtField

__all__ = ["RayCastCamera", "optical_R_mujoco_camera"]

#: MuJoCo cameras look along −z with y up; the optical frame looks along +z with y down.
optical_R_mujoco_camera = np.diag([1.0, -1.0, -1.0])

_TABLE_RGB = np.array([0.4, 0.35, 0.3])


class RayCastCamera:
    """Depth and colour of a MuJoCo camera by ray casting.

    Args:
        model: the compiled model; camera_id: the MuJoCo camera.
        intrinsics: pinhole model (image size, focal lengths, principal point, valid depth range).
        depth_noise_m: standard deviation of depth noise at 1 m [m], scaled by depth² (stereo-like).
        geom_groups: the geom groups rays can hit (default 0 and 1: scene and tool pad).
    """

    def __init__(self, model: mujoco.MjModel, camera_id: int, intrinsics: CameraIntrinsics,
                 depth_noise_m: float = 0.0, geom_groups: tuple[int, ...] = (0,)) -> None:
        self.model = model
        self.camera_id = int(camera_id)
        self.intrinsics = intrinsics
        self.depth_noise_m = float(depth_noise_m)
        k = intrinsics
        u, v = np.meshgrid(np.arange(k.width, dtype=float), np.arange(k.height, dtype=float))
        self._dirs_optical = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u)], axis=-1).reshape(-1, 3)
        self._n = self._dirs_optical.shape[0]
        self._geomid = np.zeros(self._n, dtype=np.int32)
        self._dist = np.zeros(self._n, dtype=float)
        self._groups = np.zeros(6, dtype=np.uint8)
        self._groups[list(geom_groups)] = 1

    def pose(self, data: mujoco.MjData) -> np.ndarray:
        """world_T_camera (4, 4) of the optical frame."""
        out = np.eye(4)
        out[:3, :3] = data.cam_xmat[self.camera_id].reshape(3, 3) @ optical_R_mujoco_camera
        out[:3, 3] = data.cam_xpos[self.camera_id]
        return out

    def capture(self, data: mujoco.MjData, timestamp: float, *, dirt: DirtField | None = None,
                object_geom: int = -1, object_body: int = -1, object_rgb=None, table_geom: int = -1,
                rng: np.random.Generator | None = None) -> CameraFrame:
        """One frame (depth [m], colour) from the current state of ``data`` (kinematics up to date)."""
        k = self.intrinsics
        world_T_cam = self.pose(data)
        dirs_world = self._dirs_optical @ world_T_cam[:3, :3].T
        mujoco.mj_multiRay(
            self.model, data, world_T_cam[:3, 3].copy(), dirs_world.reshape(-1), self._groups, 1, -1,
            self._geomid, self._dist, None, self._n, k.max_depth_m * 2.0,
        )
        depth = self._dist.copy()
        hit = (self._geomid >= 0) & (depth > 0)
        depth[~hit] = 0.0
        if self.depth_noise_m > 0 and rng is not None:
            depth[hit] += rng.normal(0.0, self.depth_noise_m, int(hit.sum())) * depth[hit] ** 2
        valid = hit & (depth >= k.min_depth_m) & (depth <= k.max_depth_m)
        depth[~valid] = 0.0
        rgb = np.zeros((self._n, 3))
        on_table = valid & (self._geomid == table_geom)
        rgb[on_table] = _TABLE_RGB
        on_obj = valid & (self._geomid == object_geom)
        if on_obj.any():
            pts_world = world_T_cam[:3, 3] + dirs_world[on_obj] * depth[on_obj, None]
            if dirt is not None and object_body >= 0:
                pos = data.xpos[object_body]
                rot = data.xmat[object_body].reshape(3, 3)
                rgb[on_obj] = dirt.colors((pts_world - pos) @ rot, object_rgb)
            else:
                rgb[on_obj] = 0.8
        other = valid & ~on_table & ~on_obj
        rgb[other] = 0.5
        return CameraFrame(
            depth_m=depth.reshape(k.height, k.width).astype(np.float32),
            intrinsics=k,
            world_T_camera=world_T_cam,
            timestamp=float(timestamp),
            rgb=np.clip(np.round(rgb * 255.0), 0, 255).astype(np.uint8).reshape(k.height, k.width, 3),
        )
