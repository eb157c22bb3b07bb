"""Wrist RGB-D camera by ray casting: works without OpenGL.

One ray per pixel through the pinhole model of :class:`~tactex.perception.frame.CameraIntrinsics`.
The ray directions are (x', y', 1) in the optical frame (not normalised), so the distance along
them *is* the depth along the optical axis. Two ray casters: ``"analytic"`` (default; vectorised
against the table and the object, :mod:`tactex.sim.raycast`, ~1–2 ms per 160×120 frame) and
``"mujoco"`` (``mujoco.mj_multiRay`` over every scene geom, 20–100 ms per frame on height fields).
Colour comes from what each ray hits: the object's clean colour blended with its dirt level, the
table, or black for misses. The robot's own geoms are not seen (like a camera whose view of the
tool is masked).
"""

from __future__ import annotations

import mujoco
import numpy as np

from tactex.errors import ConfigError
from tactex.perception.frame import CameraFrame, CameraIntrinsics
from tactex.pointcloud.shapes import HeightFieldSurface
from tactex.sim.dirt import DirtField
from tactex.sim.raycast import SceneRayCaster

__all__ = ["RayCastCamera", "optical_R_mujoco_camera"]

#: MuJoCo cameras look along −z with y up; the optical frame looks along +z with y down.
optical_R_mujoco_camera = np.diag([1.0, -1.0, -1.0])

_TABLE_RGB = np.array([0.4, 0.35, 0.3])
_TABLE_RGB_U8 = np.round(_TABLE_RGB * 255.0).astype(np.uint8)


class RayCastCamera:
    """Depth and colour of a MuJoCo camera by ray casting.

    Args:
        model: the compiled model; camera_id: the MuJoCo camera.
        intrinsics: pinhole model (image size, focal lengths, principal point, valid depth range).
        depth_noise_m: standard deviation of depth noise at 1 m [m], scaled by depth² (stereo-like).
        geom_groups: the geom groups MuJoCo's rays can hit (default 0: table and objects).
        method: "analytic" (needs ``caster``) or "mujoco".
        caster: the analytic ray caster of the scene.
    """

    def __init__(self, model: mujoco.MjModel, camera_id: int, intrinsics: CameraIntrinsics,
                 depth_noise_m: float = 0.0, geom_groups: tuple[int, ...] = (0,), method: str = "mujoco",
                 caster: SceneRayCaster | None = None) -> None:
        if method not in ("analytic", "mujoco"):
            raise ConfigError(f"camera ray-casting method must be 'analytic' or 'mujoco', got '{method}'")
        if method == "analytic" and caster is None:
            raise ConfigError("the analytic camera needs the scene's SceneRayCaster")
        self.method = method
        self.caster = caster
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

    def snapshot(self, data: mujoco.MjData, object_body: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What a frame depends on in ``data``: world_T_camera, object position and rotation."""
        return self.pose(data), data.xpos[object_body].copy(), data.xmat[object_body].reshape(3, 3).copy()

    def capture(self, data: mujoco.MjData, timestamp: float, *, dirt: DirtField | None = None,
                object_geom: int = -1, object_body: int = -1, object_rgb=None, table_geom: int = -1,
                rng: np.random.Generator | None = None) -> CameraFrame:
        """One frame (depth [m], colour) from the current state of ``data`` (kinematics up to date)."""
        world_T_cam, obj_pos, obj_rot = self.snapshot(data, object_body)
        if self.method == "analytic":
            return self.render(world_T_cam, obj_pos, obj_rot, timestamp, dirt=dirt,
                               dirt_level=None if dirt is None else dirt.level, object_rgb=object_rgb, rng=rng)
        dirs_world = self._dirs_optical @ world_T_cam[:3, :3].T
        mujoco.mj_multiRay(
            self.model, data, world_T_cam[:3, 3].copy(), dirs_world.reshape(-1), self._groups, 1, -1,
            self._geomid, self._dist, None, self._n, self.intrinsics.max_depth_m * 2.0,
        )
        depth = self._dist.copy()
        hit = (self._geomid >= 0) & (depth > 0)
        depth[~hit] = 0.0
        return self._finish(world_T_cam, dirs_world, depth, hit, self._geomid == object_geom,
                            self._geomid == table_geom, obj_pos, obj_rot, timestamp, dirt,
                            None if dirt is None else dirt.level, object_rgb, rng)

    def render(self, world_T_cam: np.ndarray, obj_pos: np.ndarray, obj_rot: np.ndarray, timestamp: float, *,
               dirt: DirtField | None = None, dirt_level: np.ndarray | None = None, object_rgb=None,
               rng: np.random.Generator | None = None) -> CameraFrame:
        """A frame by the analytic ray caster from a snapshot (touches no MuJoCo data: thread-safe
        as long as ``dirt_level`` is a copy)."""
        assert self.caster is not None
        dirs_world = self._dirs_optical @ world_T_cam[:3, :3].T
        depth, on_obj, on_table = self.caster.cast(world_T_cam[:3, 3], dirs_world, obj_pos, obj_rot)
        hit = np.isfinite(depth)
        depth[~hit] = 0.0
        return self._finish(world_T_cam, dirs_world, depth, hit, on_obj, on_table, obj_pos, obj_rot, timestamp,
                            dirt, dirt_level, object_rgb, rng)

    def _finish(self, world_T_cam, dirs_world, depth, hit, on_obj, on_table, obj_pos, obj_rot, timestamp,
                dirt, dirt_level, object_rgb, rng) -> CameraFrame:
        k = self.intrinsics
        if self.depth_noise_m > 0 and rng is not None:
            depth[hit] += rng.normal(0.0, self.depth_noise_m, int(hit.sum())) * depth[hit] ** 2
        valid = hit & (depth >= k.min_depth_m) & (depth <= k.max_depth_m)
        depth[~valid] = 0.0
        rgb = np.zeros((self._n, 3), dtype=np.uint8)
        on_table = valid & on_table
        rgb[on_table] = _TABLE_RGB_U8
        on_obj = valid & on_obj
        rgb[valid & ~on_table & ~on_obj] = 128
        if on_obj.any():
            if dirt is not None:
                pts_obj = (world_T_cam[:3, 3] - obj_pos + dirs_world[on_obj] * depth[on_obj, None]) @ obj_rot
                colours = np.round(dirt.colors(pts_obj, object_rgb, level=dirt_level) * 255.0)
                surf = dirt.surface
                if isinstance(surf, HeightFieldSurface) and surf.radius_m is not None:
                    # the height field's corners outside a plate's disc lie on the table: show the table
                    colours[~surf.inside(pts_obj[:, 0], pts_obj[:, 1])] = _TABLE_RGB_U8
                rgb[on_obj] = colours
            else:
                rgb[on_obj] = 204
        return CameraFrame(
            depth_m=depth.reshape(k.height, k.width).astype(np.float32),
            intrinsics=k,
            world_T_camera=world_T_cam,
            timestamp=float(timestamp),
            rgb=rgb.reshape(k.height, k.width, 3),
        )
