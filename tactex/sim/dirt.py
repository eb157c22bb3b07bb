"""Dirt (a marking) on an object's surface, removed by the wiping pad according to Preston's law.

Preston's law of abrasive wear: the removal rate is proportional to contact pressure times
sliding speed, dh/dt = k_p · p · v. Here the dirt level of a surface cell (1 = marked, 0 = clean)
under the pad footprint decreases at k_p · p · v with p = F_n / (π r_pad²) (uniform pressure on
the pad disc) while the normal force exceeds a threshold (a light touch does not clean).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tactex.errors import ConfigError, InputError
from tactex.pointcloud.markings import BASE_RGB, MARK_RGB, marking_mask
from tactex.pointcloud.shapes import CylinderWallSurface, HeightFieldSurface, Surface

__all__ = ["DirtField", "DirtLookup", "PrestonParams"]


@dataclass(frozen=True)
class PrestonParams:
    """Wear model of the dirt.

    Attributes:
        coefficient: Preston coefficient k_p [1/(Pa·m)] (dirt level per pascal per metre slid);
            the default clears a cell in ~0.5 s of contact at 15 N on a 25 mm pad sliding at 5 cm/s.
        force_threshold_n: minimum normal force that removes dirt [N].
        pad_radius_m: radius of the pressure footprint [m].
    """

    coefficient: float = 5e-3
    force_threshold_n: float = 2.0
    pad_radius_m: float = 0.025

    def __post_init__(self) -> None:
        if not (np.isfinite(self.coefficient) and self.coefficient >= 0):
            raise ConfigError(f"Preston coefficient must be ≥ 0 [1/(Pa·m)], got {self.coefficient}")
        if not (np.isfinite(self.force_threshold_n) and self.force_threshold_n >= 0):
            raise ConfigError(f"dirt force threshold must be ≥ 0 N, got {self.force_threshold_n}")
        if not (np.isfinite(self.pad_radius_m) and self.pad_radius_m > 0):
            raise ConfigError(f"pad radius must be > 0 m, got {self.pad_radius_m}")


class DirtField:
    """Dirt levels on a grid of cells over a surface's uv square.

    Args:
        surface: the object's surface (object frame).
        marking: name of a marking (tactex.pointcloud.markings) or a boolean mask function uv → (N,).
        resolution_m: approximate cell size on the surface [m].
        params: the wear model.
    """

    def __init__(self, surface: Surface, marking: str, resolution_m: float = 0.002,
                 params: PrestonParams | None = None) -> None:
        if not (np.isfinite(resolution_m) and 1e-4 <= resolution_m <= 0.05):
            raise ConfigError(f"dirt resolution must be in [0.1, 50] mm, got {resolution_m} m")
        self.surface = surface
        self.params = params or PrestonParams()
        if isinstance(surface, HeightFieldSurface):
            extent = (surface.size_x_m, surface.size_y_m)
        elif isinstance(surface, CylinderWallSurface):
            extent = (np.deg2rad(surface.arc_deg) * surface.radius_m, surface.height_m)
        else:
            raise InputError(f"no dirt model for surface type {type(surface).__name__}")
        self.shape = (max(2, round(extent[1] / resolution_m)), max(2, round(extent[0] / resolution_m)))
        nv, nu = self.shape
        u = (np.arange(nu) + 0.5) / nu
        v = (np.arange(nv) + 0.5) / nv
        uu, vv = np.meshgrid(u, v)
        self.uv = np.column_stack([uu.ravel(), vv.ravel()])
        self.points, valid = self._cell_points(self.uv)
        self.valid = valid
        self.initial = (marking_mask(marking, self.uv) & valid).astype(float)
        self.level = self.initial.copy()
        # the cell centres as three (nv, nu) planes: the footprint test below reads them at 200 Hz
        self._xyz_grid = tuple(np.ascontiguousarray(self.points[:, k].reshape(nv, nu)) for k in range(3))
        gx, gy, _ = self._xyz_grid
        self._separable = bool(np.all(gx == gx[:1]) and np.all(gy == gy[:, :1]))
        self._xs, self._ys = gx[0].copy(), gy[:, 0].copy()
        # half-size of the cell window that contains the pad footprint (+1 cell of margin)
        self._win = (int(np.ceil(self.params.pad_radius_m / (extent[1] / nv))) + 1,
                     int(np.ceil(self.params.pad_radius_m / (extent[0] / nu))) + 1)

    def _cell_points(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s = self.surface
        if isinstance(s, HeightFieldSurface):
            x = (uv[:, 0] - 0.5) * s.size_x_m
            y = (uv[:, 1] - 0.5) * s.size_y_m
            return np.column_stack([x, y, s.height(x, y)]), s.inside(x, y)
        assert isinstance(s, CylinderWallSurface)
        half = np.deg2rad(s.arc_deg) / 2
        ang = -np.pi / 2 - half + uv[:, 0] * 2 * half
        pts = np.column_stack([s.radius_m * np.cos(ang), s.radius_m * np.sin(ang), uv[:, 1] * s.height_m])
        return pts, np.ones(len(uv), dtype=bool)

    def reset(self) -> None:
        self.level = self.initial.copy()

    def paint(self, points_obj_m: np.ndarray, radius_m: float) -> int:
        """Replace the marking by dirt on the cells within ``radius_m`` [m] of ``points_obj_m`` (M, 3)
        (object frame [m]; e.g. a given cloud's target, so that the simulation's dirt is that target).
        Returns the number of dirty cells; the levels start again from it."""
        from scipy.spatial import cKDTree

        pts = np.asarray(points_obj_m, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] == 0 or not np.isfinite(pts).all():
            raise InputError(f"dirt points must be a finite (M, 3) array with M ≥ 1, got shape {pts.shape}")
        if not (np.isfinite(radius_m) and radius_m > 0.0):
            raise ConfigError(f"paint radius must be a positive number of metres, got {radius_m!r}")
        near = cKDTree(pts).query(self.points, distance_upper_bound=radius_m)[0] <= radius_m
        self.initial = (near & self.valid).astype(float)
        self.reset()
        return int(np.count_nonzero(self.initial))

    @property
    def total_initial(self) -> float:
        return float(self.initial.sum())

    def remaining_fraction(self) -> float:
        """Fraction of the initial dirt still on the surface (1.0 when there was none)."""
        total = self.total_initial
        return float(self.level.sum() / total) if total > 0 else 1.0

    def wipe(self, contact_obj: np.ndarray, normal_force_n: float, slip_speed_m_s: float, dt_s: float) -> int:
        """Remove dirt under a pad centred at ``contact_obj`` (object frame) [m] pressing with
        ``normal_force_n`` [N] and sliding at ``slip_speed_m_s`` [m/s] for ``dt_s`` [s].
        Returns the number of cells touched (0 below the force threshold)."""
        p = self.params
        if not (normal_force_n > p.force_threshold_n) or slip_speed_m_s <= 0.0:
            return 0
        return self.apply_wear(contact_obj, normal_force_n * slip_speed_m_s * dt_s)

    def apply_wear(self, contact_obj: np.ndarray, force_slip_integral: float) -> int:
        """Remove k_p·∫F·v dt / (π r²) of dirt under a pad centred at ``contact_obj`` (object frame)
        [m]; ``force_slip_integral`` = ∫ F_n·v dt [N·m] over ticks above the force threshold."""
        p = self.params
        if not force_slip_integral > 0.0:
            return 0
        cx, cy, cz = np.asarray(contact_obj, dtype=float).reshape(3).tolist()
        # only a window of cells around the footprint is examined (this runs every few ticks)
        iu, iv = self._cell_index((cx, cy, cz))
        nv, nu = self.shape
        v0, v1 = max(iv - self._win[0], 0), min(iv + self._win[0] + 1, nv)
        u0, u1 = max(iu - self._win[1], 0), min(iu + self._win[1] + 1, nu)
        gx, gy, gz = self._xyz_grid
        d2 = gz[v0:v1, u0:u1] - cz
        d2 *= d2
        if self._separable:  # x varies along the rows only and y down the columns only
            ex = self._xs[u0:u1] - cx
            ey = self._ys[v0:v1, None] - cy
            d2 += ex * ex
            d2 += ey * ey
        else:
            for grid, ck in ((gx, cx), (gy, cy)):
                e = grid[v0:v1, u0:u1] - ck
                e *= e
                d2 += e
        inside = d2 <= p.pad_radius_m**2
        count = int(np.count_nonzero(inside))
        if count == 0:
            return 0
        removal = p.coefficient * force_slip_integral / (np.pi * p.pad_radius_m**2)
        levels = self.level.reshape(nv, nu)[v0:v1, u0:u1]
        np.copyto(levels, np.maximum(levels - removal, 0.0), where=inside)
        return count

    def _cell_index(self, point_obj: np.ndarray) -> tuple[int, int]:
        """(column u, row v) of the cell nearest to a point in the object frame."""
        s = self.surface
        nv, nu = self.shape
        if isinstance(s, HeightFieldSurface):
            u = float(point_obj[0]) / s.size_x_m + 0.5
            v = float(point_obj[1]) / s.size_y_m + 0.5
        else:
            u, v = s.uv(np.asarray(point_obj, dtype=float).reshape(1, 3))[0]
        return min(max(int(u * nu), 0), nu - 1), min(max(int(v * nv), 0), nv - 1)

    def level_at(self, points_obj: np.ndarray, level: np.ndarray | None = None) -> np.ndarray:
        """Dirt level (N,) at surface points (N, 3) in the object frame (nearest cell), from the
        current levels or from ``level`` (a snapshot of :attr:`level`)."""
        p = np.asarray(points_obj)
        return self.level_at_xyz(p[:, 0], p[:, 1], p[:, 2], level)

    def level_at_xyz(self, x: np.ndarray, y: np.ndarray, z: np.ndarray | None,
                     level: np.ndarray | None = None) -> np.ndarray:
        """:meth:`level_at` for points given by their coordinate arrays (N,) each (object frame) [m]
        (z is not read on a height field and may be None there)."""
        return _levels_at_xyz(self.surface, self.shape, self.level if level is None else level, x, y, z)

    def colors(self, points_obj: np.ndarray, base_rgb: np.ndarray | None = None,
               level: np.ndarray | None = None) -> np.ndarray:
        """RGB (N, 3) in [0, 1] of surface points: the clean colour blended with the marking colour."""
        base = BASE_RGB if base_rgb is None else np.asarray(base_rgb, dtype=float)
        d = self.level_at(points_obj, level)[:, None]
        return base + d * (MARK_RGB - base)

    def level_image(self) -> np.ndarray:
        """Dirt levels as an image (nv, nu), row 0 at v = 0."""
        return self.level.reshape(self.shape)


@dataclass(frozen=True)
class DirtLookup:
    """Read-only dirt lookup on a surface's cell grid, for levels held elsewhere (the camera worker
    process gets the levels of each frame through shared memory)."""

    surface: Surface
    shape: tuple[int, int]

    def level_at_xyz(self, x: np.ndarray, y: np.ndarray, z: np.ndarray | None, level: np.ndarray) -> np.ndarray:
        """Levels (N,) of the cells at the object-frame points (x, y, z) (see DirtField.level_at_xyz)."""
        return _levels_at_xyz(self.surface, self.shape, level, x, y, z)


def _levels_at_xyz(surface: Surface, shape: tuple[int, int], level: np.ndarray, x: np.ndarray, y: np.ndarray,
                   z: np.ndarray | None) -> np.ndarray:
    nv, nu = shape
    s = surface
    if isinstance(s, HeightFieldSurface):  # uv is affine in x, y: skip the generic uv()
        u = x * (nu / s.size_x_m)
        u += 0.5 * nu
        v = y * (nv / s.size_y_m)
        v += 0.5 * nv
    else:
        uv = s.uv(np.stack([x, y, z], axis=1))
        u, v = uv[:, 0] * nu, uv[:, 1] * nv
    # truncation is the floor on the grid; the clamps keep points off it on its border cells
    iu = np.clip(u.astype(np.int32), 0, nu - 1)
    iv = np.clip(v.astype(np.int32), 0, nv - 1)
    iv *= nu
    iv += iu
    return np.take(level, iv)
