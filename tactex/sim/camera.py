"""Wrist RGB-D camera by ray casting: works without OpenGL.

One ray per pixel through the pinhole model of :class:`~tactex.perception.frame.CameraIntrinsics`.
The ray directions are (x', y', 1) in the optical frame (not normalised), so the distance along
them *is* the depth along the optical axis. Two ray casters: ``"analytic"`` (default; vectorised
against the table and the object, :mod:`tactex.sim.raycast`, fast enough for a 30 Hz camera beside
the 1 kHz loop) and ``"mujoco"`` (``mujoco.mj_multiRay`` over every scene geom, slower than real
time on height fields; the reference the analytic one is tested against).
Colour comes from what each ray hits: the object's clean colour blended with its dirt level, the
table, or black for misses. The robot's own geoms are not seen (like a camera whose view of the
tool is masked). ``SceneConfig(camera_worker=True)`` renders the frames with this same code in a
worker process (:mod:`tactex.sim.camera_worker`).
"""

from __future__ import annotations

import mujoco
import numpy as np

from tactex.errors import ConfigError
from tactex.perception.frame import CameraFrame, CameraIntrinsics
from tactex.pointcloud.markings import BASE_RGB, MARK_RGB
from tactex.pointcloud.shapes import HeightFieldSurface
from tactex.sim.dirt import DirtField, DirtLookup
from tactex.sim.raycast import CHUNK_RAYS, SceneRayCaster, chunk_bounds

__all__ = ["RayCastCamera", "optical_R_mujoco_camera"]

#: MuJoCo cameras look along −z with y up; the optical frame looks along +z with y down.
optical_R_mujoco_camera = np.diag([1.0, -1.0, -1.0])

_TABLE_RGB = np.array([0.4, 0.35, 0.3])
_TABLE_RGB_U8 = np.round(_TABLE_RGB * 255.0).astype(np.uint8)


class RayCastCamera:
    """Depth and colour of a MuJoCo camera by ray casting.

    Args:
        model: the compiled model; camera_id: the MuJoCo camera (None and -1 for a camera that only
            renders snapshots, as in the camera worker process).
        intrinsics: pinhole model (image size, focal lengths, principal point, valid depth range).
        depth_noise_m: standard deviation of depth noise at 1 m [m], scaled by depth² (stereo-like).
        geom_groups: the geom groups MuJoCo's rays can hit (default 0: table and objects).
        method: "analytic" (needs ``caster``) or "mujoco".
        caster: the analytic ray caster of the scene.
    """

    def __init__(self, model: mujoco.MjModel | None, camera_id: int, intrinsics: CameraIntrinsics,
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
        self._u = ((np.arange(k.width) - k.cx) / k.fx).astype(np.float32)
        self._v = ((np.arange(k.height) - k.cy) / k.fy).astype(np.float32)
        self._row_chunks = chunk_bounds(k.height, max(1, CHUNK_RAYS // k.width))
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
        level = None if dirt is None else dirt.level
        if self.method == "analytic":
            return self.render(world_T_cam, obj_pos, obj_rot, timestamp, dirt=dirt, dirt_level=level,
                               object_rgb=object_rgb, rng=rng)
        dirs_world = self._dirs_optical @ world_T_cam[:3, :3].T
        mujoco.mj_multiRay(
            self.model, data, world_T_cam[:3, 3].copy(), dirs_world.reshape(-1), self._groups, 1, -1,
            self._geomid, self._dist, None, self._n, self.intrinsics.max_depth_m * 2.0,
        )
        hit = (self._geomid >= 0) & (self._dist > 0)
        depth = np.where(hit, self._dist, 0.0).astype(np.float32)
        d_obj = dirs_world @ obj_rot
        o_obj = (world_T_cam[:3, 3] - obj_pos) @ obj_rot
        rgb = np.zeros((self._n, 3), dtype=np.uint8)
        self._shade(depth, hit, self._geomid == object_geom, self._geomid == table_geom, o_obj,
                    tuple(d_obj[:, k] for k in range(3)), rgb, dirt, level, object_rgb, rng)
        return self._frame(depth, rgb, world_T_cam, timestamp)

    def render(self, world_T_cam: np.ndarray, obj_pos: np.ndarray, obj_rot: np.ndarray, timestamp: float, *,
               dirt: DirtField | DirtLookup | None = None, dirt_level: np.ndarray | None = None, object_rgb=None,
               rng: np.random.Generator | None = None) -> CameraFrame:
        """A frame by the analytic ray caster from a snapshot (touches no MuJoCo data: thread-safe
        as long as ``dirt_level`` is a copy; ``dirt`` may be a :class:`~tactex.sim.dirt.DirtLookup`).
        Cast and shaded in chunks of image rows (see :mod:`tactex.sim.raycast` for why)."""
        assert self.caster is not None
        w = self.intrinsics.width
        cam_rot, cam_pos = world_T_cam[:3, :3], world_T_cam[:3, 3]
        obj_R_cam = obj_rot.T @ cam_rot
        o_obj = (cam_pos - obj_pos) @ obj_rot
        depth = np.empty(self._n, dtype=np.float32)
        rgb = np.zeros((self._n, 3), dtype=np.uint8)
        for r0, r1 in self._row_chunks:
            dirs_world = self._directions(cam_rot, r0, r1)
            dirs_obj = self._directions(obj_R_cam, r0, r1)
            t, on_obj, on_table = self.caster.cast_components(cam_pos, dirs_world, o_obj, dirs_obj)
            hit = t < np.inf
            t[~hit] = 0.0
            s = slice(r0 * w, r1 * w)
            depth[s] = t
            self._shade(depth[s], hit, on_obj, on_table, o_obj, dirs_obj, rgb[s], dirt, dirt_level, object_rgb,
                        rng)
        return self._frame(depth, rgb, world_T_cam, timestamp)

    def _directions(self, rot: np.ndarray, r0: int, r1: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Components (float32, (r1 − r0)·W each) of the ray directions rot·(x', y', 1) of image rows
        r0..r1: x' varies along a row and y' down a column, so each is an outer sum."""
        u, v = self._u, self._v[r0:r1]
        r = rot.astype(np.float32)
        return tuple(np.add.outer(v * r[k, 1] + r[k, 2], u * r[k, 0]).reshape(-1) for k in range(3))

    def _shade(self, depth, hit, on_obj, on_table, o_obj, dirs_obj, rgb, dirt, dirt_level, object_rgb,
               rng) -> None:
        """Noise, depth range and colour of a block of pixels, in place in ``depth`` (float32) and
        ``rgb`` (uint8, zeros); ``dirs_obj`` are the object-frame ray components (for the dirt)."""
        k = self.intrinsics
        if self.depth_noise_m > 0 and rng is not None:
            dh = depth[hit].astype(float)
            depth[hit] = dh + rng.normal(0.0, self.depth_noise_m, dh.shape[0]) * dh**2
        valid = hit & (depth >= k.min_depth_m) & (depth <= k.max_depth_m)
        depth[~valid] = 0.0
        on_table = valid & on_table
        on_obj = valid & on_obj
        other = valid & ~on_table & ~on_obj
        # per channel with masks: assigning rows through a boolean index is several times slower
        channels = [rgb[:, c] for c in range(3)]
        if on_table.any():
            for ch, value in zip(channels, _TABLE_RGB_U8, strict=True):
                np.copyto(ch, value, where=on_table)
        if other.any():
            rgb[other] = 128
        if not on_obj.any():
            return
        if dirt is None:
            rgb[on_obj] = 204
            return
        # the seen points in the object frame, for every pixel of the block (a pixel off the object
        # reads some cell, unused): masks beat gathering the object's pixels
        x, y = (depth * dirs_obj[i] + np.float32(o_obj[i]) for i in range(2))
        surf = dirt.surface
        z = None if isinstance(surf, HeightFieldSurface) else depth * dirs_obj[2] + np.float32(o_obj[2])
        level = dirt.level_at_xyz(x, y, z, dirt_level)
        base = BASE_RGB if object_rgb is None else np.asarray(object_rgb, dtype=float)
        for c, ch in enumerate(channels):
            value = level * (255.0 * (MARK_RGB[c] - base[c]))
            value += 255.0 * base[c]
            np.copyto(ch, np.rint(value, out=value), where=on_obj, casting="unsafe")
        if isinstance(surf, HeightFieldSurface) and surf.radius_m is not None:
            # the height field's corners outside a plate's disc lie on the table: show the table
            rgb[on_obj & ~surf.inside(x, y)] = _TABLE_RGB_U8

    def _frame(self, depth, rgb, world_T_cam, timestamp) -> CameraFrame:
        k = self.intrinsics
        return CameraFrame(depth_m=depth.reshape(k.height, k.width), intrinsics=k, world_T_camera=world_T_cam,
                           timestamp=float(timestamp), rgb=rgb.reshape(k.height, k.width, 3))
