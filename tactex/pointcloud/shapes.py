"""Analytic surfaces of the built-in objects, shared by the point-cloud side and the simulator.

Every surface lives in its own object frame: z up, the base at z = 0, centred on the origin in
x–y. A :class:`Surface` can be sampled into a :class:`~tactex.pointcloud.SurfaceCloud` with exact
normals, maps points to surface coordinates uv ∈ [0, 1]² (where markings are drawn), and gives
exact heights/normals for tests. The simulator builds its MuJoCo height fields from the same
functions, so both sides share one geometry.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tactex.errors import ConfigError, InputError
from tactex.pointcloud.cloud import SurfaceCloud

__all__ = [
    "SURFACES",
    "CylinderWallSurface",
    "HeightFieldSurface",
    "Surface",
    "door_height",
    "get_surface",
    "hull_height",
    "resolve_surface_name",
    "sine_panel_height",
    "surface_names",
]

HeightFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


def _check_spacing(spacing_m: float) -> float:
    if not np.isfinite(spacing_m) or spacing_m <= 0.0:
        raise ConfigError(f"sampling spacing must be a positive number of metres, got {spacing_m}")
    return float(spacing_m)


class Surface(ABC):
    """A smooth surface in its object frame (z up, base at z = 0)."""

    name: str

    @abstractmethod
    def sample(self, spacing_m: float) -> SurfaceCloud:
        """Points about ``spacing_m`` apart [m] with exact outward unit normals, target zero."""

    @abstractmethod
    def uv(self, points_m: np.ndarray) -> np.ndarray:
        """Surface coordinates (N, 2) in [0, 1]² of points on (or near) the surface."""

    @abstractmethod
    def project(self, points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Closest surface points (N, 3) [m] and their unit normals (N, 3) (approximate for
        height fields: vertical projection, exact on flat parts)."""

    @property
    @abstractmethod
    def bounds_m(self) -> np.ndarray:
        """Axis-aligned bounding box [[xmin, ymin, zmin], [xmax, ymax, zmax]] [m]."""


@dataclass(frozen=True, eq=False)
class HeightFieldSurface(Surface):
    """z = height(x, y) over a rectangle size_x × size_y [m] centred at the origin, optionally
    restricted to a disc of ``radius_m`` (plates and bowls).

    Attributes:
        name: registry name.
        size_x_m, size_y_m: extent of the domain [m].
        height: vectorised z = f(x, y) [m].
        radius_m: if set, the domain is the disc x² + y² ≤ radius² [m].
        fd_step_m: step of the central differences giving the normals [m].
    """

    name: str
    size_x_m: float
    size_y_m: float
    height: HeightFn
    radius_m: float | None = None
    fd_step_m: float = 1e-6

    def gradient(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(∂z/∂x, ∂z/∂y) by central differences (exact to ~1e-9 for these smooth shapes)."""
        e = self.fd_step_m
        gx = (self.height(x + e, y) - self.height(x - e, y)) / (2 * e)
        gy = (self.height(x, y + e) - self.height(x, y - e)) / (2 * e)
        return gx, gy

    def normal(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Upward unit normals (N, 3) at (x, y)."""
        gx, gy = self.gradient(np.asarray(x, float), np.asarray(y, float))
        n = np.stack([-gx, -gy, np.ones_like(gx)], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def inside(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Boolean mask of (x, y) inside the domain."""
        ok = (np.abs(x) <= self.size_x_m / 2 + 1e-12) & (np.abs(y) <= self.size_y_m / 2 + 1e-12)
        if self.radius_m is not None:
            ok &= x * x + y * y <= self.radius_m**2 + 1e-12
        return ok

    def grid(self, spacing_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Regular grid (xs (nx,), ys (ny,), Z (ny, nx)) covering the rectangle, for height fields."""
        spacing_m = _check_spacing(spacing_m)
        nx = max(2, int(np.ceil(self.size_x_m / spacing_m)) + 1)
        ny = max(2, int(np.ceil(self.size_y_m / spacing_m)) + 1)
        xs = np.linspace(-self.size_x_m / 2, self.size_x_m / 2, nx)
        ys = np.linspace(-self.size_y_m / 2, self.size_y_m / 2, ny)
        gx, gy = np.meshgrid(xs, ys)
        return xs, ys, self.height(gx, gy)

    def sample(self, spacing_m: float) -> SurfaceCloud:
        xs, ys, z = self.grid(spacing_m)
        gx, gy = np.meshgrid(xs, ys)
        keep = self.inside(gx, gy)
        x, y, z = gx[keep], gy[keep], z[keep]
        pts = np.stack([x, y, z], axis=1)
        return SurfaceCloud(points=pts, normals=self.normal(x, y), spacing=0.0)

    def uv(self, points_m: np.ndarray) -> np.ndarray:
        p = np.asarray(points_m, dtype=float).reshape(-1, 3)
        u = p[:, 0] / self.size_x_m + 0.5
        v = p[:, 1] / self.size_y_m + 0.5
        return np.clip(np.stack([u, v], axis=1), 0.0, 1.0)

    def project(self, points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = np.asarray(points_m, dtype=float).reshape(-1, 3)
        x = np.clip(p[:, 0], -self.size_x_m / 2, self.size_x_m / 2)
        y = np.clip(p[:, 1], -self.size_y_m / 2, self.size_y_m / 2)
        return np.stack([x, y, self.height(x, y)], axis=1), self.normal(x, y)

    @property
    def bounds_m(self) -> np.ndarray:
        xs, ys, z = self.grid(min(self.size_x_m, self.size_y_m) / 200)
        gx, gy = np.meshgrid(xs, ys)
        z = z[self.inside(gx, gy)]
        half_x, half_y = self.size_x_m / 2, self.size_y_m / 2
        return np.array([[-half_x, -half_y, float(z.min())], [half_x, half_y, float(z.max())]])


@dataclass(frozen=True, eq=False)
class CylinderWallSurface(Surface):
    """The outer wall of a vertical cylinder (a cup), axis z, from z = 0 to ``height_m``.

    Attributes:
        radius_m: cylinder radius [m].
        height_m: wall height [m].
        arc_deg: angular extent centred on the −y side (what a camera in front sees); 360 = whole.
    """

    name: str
    radius_m: float
    height_m: float
    arc_deg: float = 360.0

    def _angle_range(self) -> tuple[float, float]:
        half = np.deg2rad(self.arc_deg) / 2
        centre = -np.pi / 2
        return centre - half, centre + half

    def sample(self, spacing_m: float) -> SurfaceCloud:
        spacing_m = _check_spacing(spacing_m)
        a0, a1 = self._angle_range()
        full = self.arc_deg >= 360.0
        n_a = max(3, round((a1 - a0) * self.radius_m / spacing_m) + (0 if full else 1))
        angles = a0 + (a1 - a0) * np.arange(n_a) / (n_a if full else n_a - 1)
        zs = np.linspace(0.0, self.height_m, max(2, round(self.height_m / spacing_m) + 1))
        aa, zz = np.meshgrid(angles, zs)
        normals = np.stack([np.cos(aa), np.sin(aa), np.zeros_like(aa)], axis=-1).reshape(-1, 3)
        pts = np.column_stack([self.radius_m * normals[:, :2], zz.reshape(-1)])
        return SurfaceCloud(points=pts, normals=normals, spacing=0.0)

    def uv(self, points_m: np.ndarray) -> np.ndarray:
        p = np.asarray(points_m, dtype=float).reshape(-1, 3)
        a0, a1 = self._angle_range()
        ang = np.arctan2(p[:, 1], p[:, 0])
        ang = np.where(ang < a0, ang + 2 * np.pi, ang)
        u = (ang - a0) / (a1 - a0)
        v = p[:, 2] / self.height_m
        return np.clip(np.stack([u, v], axis=1), 0.0, 1.0)

    def project(self, points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = np.asarray(points_m, dtype=float).reshape(-1, 3)
        radial = p[:, :2]
        r = np.linalg.norm(radial, axis=1)
        if np.any(r < 1e-12):
            raise InputError("a point on the cylinder axis has no unique closest point on the wall")
        n2 = radial / r[:, None]
        normals = np.column_stack([n2, np.zeros(len(p))])
        z = np.clip(p[:, 2], 0.0, self.height_m)
        return np.column_stack([self.radius_m * n2, z]), normals

    @property
    def bounds_m(self) -> np.ndarray:
        r = self.radius_m
        return np.array([[-r, -r, 0.0], [r, r, self.height_m]])


def sine_panel_height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """VA-UFIC §III test surface: h = 0.02 sin(π/0.19·y' + 0.44) + 0.02 m, y' = y + 0.255 ∈ [0, 0.51]."""
    return 0.02 * np.sin(np.pi / 0.19 * (np.asarray(y) + 0.255) + 0.44) + 0.02 + 0.0 * np.asarray(x)


def _plate_height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    # A dinner plate: flat well (r < 7 cm) 4 mm above the base, a smooth rim rising to 2 cm at 13 cm.
    r = np.hypot(x, y)
    s = np.clip((r - 0.07) / 0.06, 0.0, 1.0)
    return 0.004 + 0.016 * s * s * (3 - 2 * s)


def _bowl_height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    # Inside of a bowl: paraboloid 1 cm above the base at the centre, 6 cm at the 9 cm rim (48° slope).
    # Outside the rim the height stays at the rim's, so height fields over the square are continuous.
    r2 = np.minimum(np.asarray(x) ** 2 + np.asarray(y) ** 2, 0.09**2)
    return 0.01 + 0.05 * r2 / 0.09**2


def door_height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A car door's outer skin lying on its inside: 0.4 m (x, the door's height) × 0.6 m (y, its length).

    Crowned 20 mm over its height (radius 1 m) and 15 mm over its length (radius 3 m), with a
    character line: a 6 mm step, 30 mm wide, 5 cm above the middle [m].
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    return 0.045 - x**2 / (2 * 1.0) - y**2 / (2 * 3.0) + 0.003 * np.tanh((x - 0.05) / 0.015)


def hull_height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A doubly curved hull patch (the bilge of a boat), 0.5 m × 0.4 m: principal radii 0.6 m and 0.9 m
    with a slight twist (the principal directions turn across the patch) [m]."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    return 0.08 - x**2 / (2 * 0.6) - y**2 / (2 * 0.9) + 0.05 * x * y


def _flat(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return 0.0 * np.asarray(x) + 0.0 * np.asarray(y)


#: The built-in surfaces, by name.
SURFACES: dict[str, Surface] = {
    "plane": HeightFieldSurface("plane", 0.30, 0.30, _flat),
    "sine_panel": HeightFieldSurface("sine_panel", 0.26, 0.51, sine_panel_height),
    "plate": HeightFieldSurface("plate", 0.26, 0.26, _plate_height, radius_m=0.13),
    "bowl": HeightFieldSurface("bowl", 0.18, 0.18, _bowl_height, radius_m=0.09),
    "cup": CylinderWallSurface("cup", radius_m=0.04, height_m=0.10, arc_deg=180.0),
    "door": HeightFieldSurface("door", 0.40, 0.60, door_height),
    "hull": HeightFieldSurface("hull", 0.40, 0.50, hull_height),
}


def surface_names() -> list[str]:
    return sorted(SURFACES)


def resolve_surface_name(name: str) -> str | None:
    """The built-in surface called ``name`` in any case ('Plate' → 'plate'), or None."""
    return {n.lower(): n for n in SURFACES}.get(str(name).lower())


def get_surface(name: str) -> Surface:
    """A built-in surface by name; the error lists the valid names."""
    try:
        return SURFACES[name]
    except KeyError:
        raise ConfigError(f"unknown object '{name}'; built-in objects: {', '.join(surface_names())}") from None
