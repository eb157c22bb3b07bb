"""Analytic depth rendering of known geometry (planes, spheres, cylinders, height fields).

Ground truth for tests, benchmarks and examples: each pixel's ray is intersected exactly with
the surfaces (ray–plane, ray–sphere, ray–cylinder in closed form; height fields z = h(x, y) by
Newton's method on the ray parameter). Rays are parameterised by depth: the camera-frame ray
of pixel (u, v) is s·((u − cx)/fx, (v − cy)/fy, 1), so the hit parameter s *is* the depth.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from tactex.errors import InputError
from tactex.perception.frame import CameraFrame, CameraIntrinsics

__all__ = [
    "Cylinder",
    "HeightField",
    "Plane",
    "Sphere",
    "Surface",
    "VaUficSinusoid",
    "look_at",
    "render_depth",
    "render_frame",
]


def look_at(eye: Sequence[float], target: Sequence[float], up: Sequence[float] = (0.0, 0.0, 1.0)) -> np.ndarray:
    """world_T_camera (4, 4) of an optical-frame camera (z forward, x right, y down) at ``eye``
    looking at ``target``; ``up`` is the world direction that appears upward in the image."""
    eye_a, tgt = np.asarray(eye, float), np.asarray(target, float)
    z = tgt - eye_a
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, float))
    if np.linalg.norm(x) < 1e-9:
        raise InputError("look_at: 'up' is parallel to the viewing direction; choose another up vector")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = eye_a
    return T


class Surface:
    """A surface that a ray o + s·d (s > 0) can hit; ``hit`` returns s (NaN where missed)."""

    def hit(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def normal(self, p: np.ndarray) -> np.ndarray:
        """(N, 3) unit outward normals at surface points p (N, 3)."""
        raise NotImplementedError


@dataclass(frozen=True)
class Plane(Surface):
    point: tuple[float, float, float]
    normal_vec: tuple[float, float, float]

    def hit(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        n = np.asarray(self.normal_vec, float)
        den = np.einsum("ij,j->i", d, n)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = ((np.asarray(self.point, float) - o) @ n) / den
        return np.where((np.abs(den) > 1e-12) & (s > 0), s, np.nan)

    def normal(self, p: np.ndarray) -> np.ndarray:
        n = np.asarray(self.normal_vec, float)
        return np.broadcast_to(n / np.linalg.norm(n), p.shape).copy()


@dataclass(frozen=True)
class Sphere(Surface):
    center: tuple[float, float, float]
    radius: float

    def hit(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        w = o - np.asarray(self.center, float)
        a = np.einsum("ij,ij->i", d, d)
        b = 2.0 * np.einsum("ij,j->i", d, w)
        c = w @ w - self.radius**2
        disc = b * b - 4.0 * a * c
        with np.errstate(invalid="ignore"):
            s = (-b - np.sqrt(disc)) / (2.0 * a)
        return np.where((disc >= 0) & (s > 0), s, np.nan)

    def normal(self, p: np.ndarray) -> np.ndarray:
        v = p - np.asarray(self.center, float)
        return v / np.linalg.norm(v, axis=1, keepdims=True)


@dataclass(frozen=True)
class Cylinder(Surface):
    """Infinite circular cylinder through ``point`` along unit ``axis``."""

    point: tuple[float, float, float]
    axis: tuple[float, float, float]
    radius: float

    def _perp(self, v: np.ndarray) -> np.ndarray:
        a = np.asarray(self.axis, float) / np.linalg.norm(self.axis)
        return v - np.outer(v @ a, a) if v.ndim == 2 else v - (v @ a) * a

    def hit(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        w = self._perp(o - np.asarray(self.point, float))
        dp = self._perp(d)
        a = np.einsum("ij,ij->i", dp, dp)
        b = 2.0 * np.einsum("ij,j->i", dp, w)
        c = w @ w - self.radius**2
        disc = b * b - 4.0 * a * c
        with np.errstate(invalid="ignore", divide="ignore"):
            s = (-b - np.sqrt(disc)) / (2.0 * a)
        return np.where((disc >= 0) & (a > 1e-15) & (s > 0), s, np.nan)

    def normal(self, p: np.ndarray) -> np.ndarray:
        v = self._perp(p - np.asarray(self.point, float))
        return v / np.linalg.norm(v, axis=1, keepdims=True)


@dataclass(frozen=True)
class HeightField(Surface):
    """Surface z = h(x, y) in the world, with its gradient (∂h/∂x, ∂h/∂y); seen from above."""

    h: Callable[[np.ndarray, np.ndarray], np.ndarray]
    grad: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
    z_guess: float = 0.0

    def hit(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(np.abs(d[:, 2]) > 1e-12, (self.z_guess - o[2]) / d[:, 2], np.nan)
            for _ in range(50):
                x, y = o[0] + s * d[:, 0], o[1] + s * d[:, 1]
                g = o[2] + s * d[:, 2] - self.h(x, y)
                gx, gy = self.grad(x, y)
                step = g / (d[:, 2] - gx * d[:, 0] - gy * d[:, 1])
                s = s - step
                if not np.nanmax(np.abs(step), initial=0.0) > 1e-13:
                    break
            x, y = o[0] + s * d[:, 0], o[1] + s * d[:, 1]
            residual = np.abs(o[2] + s * d[:, 2] - self.h(x, y))
        return np.where((residual < 1e-10) & (s > 0), s, np.nan)

    def normal(self, p: np.ndarray) -> np.ndarray:
        gx, gy = self.grad(p[:, 0], p[:, 1])
        n = np.stack([-gx, -gy, np.ones_like(gx)], axis=1)
        return n / np.linalg.norm(n, axis=1, keepdims=True)


def VaUficSinusoid(amplitude: float = 0.02, period_factor: float = np.pi / 0.19, phase: float = 0.44,
                   offset: float = 0.02) -> HeightField:
    """The 3D-printed surface of VA-UFIC §III: h = 0.02 sin(π/0.19 · y + 0.44) + 0.02 [m]."""

    def h(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return amplitude * np.sin(period_factor * y + phase) + offset

    def grad(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.zeros_like(x), amplitude * period_factor * np.cos(period_factor * y + phase)

    return HeightField(h, grad, z_guess=offset)


def render_depth(
    intrinsics: CameraIntrinsics, world_T_camera: np.ndarray, surfaces: Sequence[Surface]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact depth image of ``surfaces``.

    Returns:
        (depth (H, W) float32 [m], 0 where nothing is hit or out of range; hit points (H, W, 3)
        in the world, NaN where missed; index (H, W) of the surface hit, −1 where missed).
    """
    H, W = intrinsics.height, intrinsics.width
    v, u = np.mgrid[0:H, 0:W]
    d_c = np.stack([(u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy, np.ones((H, W))], -1)
    d_c = d_c.reshape(-1, 3)
    rot, o = world_T_camera[:3, :3], world_T_camera[:3, 3]
    d_w = np.einsum("ij,kj->ik", d_c, rot)
    best = np.full(H * W, np.inf)
    which = np.full(H * W, -1)
    for k, surf in enumerate(surfaces):
        s = surf.hit(o, d_w)
        closer = np.isfinite(s) & (s < best)
        best[closer] = s[closer]
        which[closer] = k
    ok = np.isfinite(best) & (best >= intrinsics.min_depth_m) & (best <= intrinsics.max_depth_m)
    depth = np.where(ok, best, 0.0).astype(np.float32)
    pts = np.where(ok[:, None], o + best[:, None] * d_w, np.nan)
    which = np.where(ok, which, -1)
    return depth.reshape(H, W), pts.reshape(H, W, 3), which.reshape(H, W)


def render_frame(
    intrinsics: CameraIntrinsics,
    world_T_camera: np.ndarray,
    surfaces: Sequence[Surface],
    *,
    timestamp: float = 0.0,
    paint: Callable[[np.ndarray], np.ndarray] | None = None,
    base_rgb: tuple[int, int, int] = (200, 200, 200),
    paint_rgb: tuple[int, int, int] = (230, 20, 20),
) -> tuple[CameraFrame, np.ndarray]:
    """A :class:`CameraFrame` of the scene and the painted-pixel mask (H, W).

    ``paint(points_world (N, 3)) -> bool (N,)`` marks surface points drawn in ``paint_rgb``
    (the rest in ``base_rgb``); without it there is no RGB image and the mask is all False.
    """
    depth, pts, which = render_depth(intrinsics, world_T_camera, surfaces)
    mask = np.zeros(depth.shape, dtype=bool)
    rgb = None
    if paint is not None:
        hit = which >= 0
        mask[hit] = np.asarray(paint(pts[hit]), dtype=bool)
        rgb = np.empty((*depth.shape, 3), dtype=np.uint8)
        rgb[...] = np.asarray(base_rgb, dtype=np.uint8)
        rgb[mask] = np.asarray(paint_rgb, dtype=np.uint8)
    return CameraFrame(depth, intrinsics, np.asarray(world_T_camera, float), float(timestamp), rgb), mask
