"""Vectorised ray casting against the scene's known geometry: the table top and the object
(box, cylinder or height field), in numpy.

Why not only ``mujoco.mj_multiRay``: MuJoCo intersects each ray with each geom in C, one ray at a
time; against a height field that costs so much per ray that a 160×120 frame alone takes longer
than a 30 Hz camera's period, slower than real time. Here the table is a plane, boxes and
cylinders are closed-form, and a height field is intersected by safeguarded Newton iterations on
the same grid MuJoCo collides with (bilinear between grid nodes; MuJoCo's two triangles per cell
differ from it by less than the grid's own interpolation error). ``RayCastCamera(method="mujoco")``
keeps MuJoCo's ray caster, and the tests check both agree.

Speed (this runs at 30 Hz beside a 1 kHz control loop, in the same process by default): rays are
three component arrays (x, y, z of the directions), cast in chunks of at most :data:`CHUNK_RAYS`,
in float32 where the precision allows (depths keep ~10 nm). A frame costs a few hundred numpy
operations per chunk, so fewer, larger chunks are faster, up to the point where the temporaries
stop fitting in the cache and the heap: a whole 640×480 frame at once, or one (rays × samples)
array for the whole height-field march, is page-faulted anew on every allocation (glibc mmaps
blocks above its threshold), which makes it several times slower than its arithmetic.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from tactex.pointcloud.shapes import CylinderWallSurface, HeightFieldSurface
from tactex.sim.objects import SimObject

__all__ = ["CHUNK_RAYS", "SceneRayCaster", "chunk_bounds"]

#: Most rays cast at once: a 160×120 frame in one chunk, 640×480 in ten.
CHUNK_RAYS = 32768

_INF = np.inf
_F32 = np.float32

Components = tuple[np.ndarray, np.ndarray, np.ndarray]


def chunk_bounds(n: int, chunk: int = CHUNK_RAYS) -> list[tuple[int, int]]:
    """[start, stop) ranges splitting n items into near-equal chunks of at most ``chunk``."""
    parts = max(1, -(-n // chunk))
    edges = [round(i * n / parts) for i in range(parts + 1)]
    return list(itertools.pairwise(edges))


def _slab(o: np.ndarray, d: Components, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Entry and exit parameters (N,) of rays o + t·d (one origin o (3,), direction components d)
    through the box [lo, hi] (t_in > t_out: miss)."""
    t_in = t_out = None
    with np.errstate(divide="ignore", invalid="ignore"):
        for k in range(3):
            typ = d[k].dtype.type
            inv = np.reciprocal(d[k])  # ±inf for a ray parallel to the slab: inside it for all t or never
            t0 = inv * typ(lo[k] - o[k])
            t1 = inv * typ(hi[k] - o[k])
            # 0·inf (origin on the plane of a parallel slab) is NaN, which fmin/fmax ignore
            near, far = np.fmin(t0, t1), np.fmax(t0, t1)
            if t_in is None:
                t_in, t_out = near, far
            else:
                np.fmax(t_in, near, out=t_in)
                np.fmin(t_out, far, out=t_out)
    return t_in, t_out


class SceneRayCaster:
    """Ray casting against table and object.

    Args:
        sim_object: the scene's object (its geometry as compiled into MuJoCo).
        table_top_z: world height of the table top [m]; table_xy: (xmin, xmax, ymin, ymax) [m].
        newton_iterations: most Newton iterations of the height-field intersection.
        tolerance_m: a ray's iterations stop once a step moves it by less than this [m] (Newton's
            quadratic convergence leaves an error far below it on smooth parts).
        kind, heightfield: the object's ``kind`` and ``heightfield()`` grid when already known (the
            camera worker process gets them as arrays: it has no height function).
    """

    #: the height-field march samples only the rays not yet bracketed once they are fewer than this
    #: fraction of those it samples (gathering them costs about one sample of the others)
    march_gather_below = 0.5

    def __init__(self, sim_object: SimObject, table_top_z: float = 0.0,
                 table_xy: tuple[float, float, float, float] = (-0.4, 1.2, -0.8, 0.8),
                 newton_iterations: int = 8, tolerance_m: float = 1e-5, *, kind: str | None = None,
                 heightfield: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> None:
        self.obj = sim_object
        self.kind = sim_object.kind if kind is None else kind
        self.table_z = float(table_top_z)
        self.table_xy = table_xy
        self.iterations = int(newton_iterations)
        self.tolerance = _F32(tolerance_m)
        t = sim_object.base_thickness_m
        surf = sim_object.surface
        if self.kind == "box":
            assert isinstance(surf, HeightFieldSurface)
            self.lo = np.array([-surf.size_x_m / 2, -surf.size_y_m / 2, -t])
            self.hi = np.array([surf.size_x_m / 2, surf.size_y_m / 2, 0.0])
        elif self.kind == "cylinder":
            assert isinstance(surf, CylinderWallSurface)
            self.radius, self.height = surf.radius_m, surf.height_m
            self.lo = np.array([-surf.radius_m, -surf.radius_m, 0.0])
            self.hi = np.array([surf.radius_m, surf.radius_m, surf.height_m])
        else:
            xs, ys, z = sim_object.heightfield() if heightfield is None else heightfield
            self.x0, self.y0 = float(xs[0]), float(ys[0])
            self.inv_dx = (len(xs) - 1) / float(xs[-1] - xs[0])
            self.inv_dy = (len(ys) - 1) / float(ys[-1] - ys[0])
            self.nx, self.ny = len(xs), len(ys)
            # cell indices are computed in float32, exact below 2²⁴ cells; beyond, in float64
            self._wide = self.nx * self.ny >= 2**24
            self._sx, self._sy = _F32(self.inv_dx), _F32(self.inv_dy)
            # one more column and row of cells past the last node, continuing the edge heights: a grid
            # coordinate that round-off puts just past the end needs no clamping (numpy's min/max
            # against a scalar cost three multiplications)
            zp = np.pad(z, ((0, 1), (0, 1)), mode="edge")
            self._row = _F32(self.nx)
            # bilinear coefficients per cell: z = a + b·fx + c·fy + e·fx·fy
            z00, z10, z01, z11 = zp[:-1, :-1], zp[:-1, 1:], zp[1:, :-1], zp[1:, 1:]
            coefs = (z00, z10 - z00, z01 - z00, z11 - z10 - z01 + z00)
            self.coefs = np.stack([c.reshape(-1) for c in coefs], axis=1).astype(np.float32)  # (cells, 4)
            self._coefs16 = self.coefs.view(np.complex128).reshape(-1)
            zmin = float(z.min())
            self.z_floor = zmin
            self.lo = np.array([xs[0], ys[0], zmin - t])
            self.hi = np.array([xs[-1], ys[-1], float(z.max())])

    # -- object intersections in the object frame ---------------------------------------------
    def _surface(self, cx: np.ndarray, cy: np.ndarray, gradient: bool = False):
        """Bilinear height [m] at grid coordinates (cx, cy) (float32 arrays, in cells from the first
        node, inside the grid up to round-off; overwritten), and with ``gradient`` also its slopes
        per cell (∂z/∂cx, ∂z/∂cy)."""
        # trunc, not floor: a round-off below 0 stays in cell 0 (extrapolated by that round-off)
        fx = np.trunc(cx)
        fy = np.trunc(cy)
        k = (fy.astype(np.float64) if self._wide else fy) * self._row
        k += fx
        k = k.astype(np.int32)  # float32 → int64 is not vectorised
        cx -= fx  # the fractions stay float32
        cy -= fy
        # one gather of the cell's four coefficients (16 bytes, a complex128) beats four of 4 bytes;
        # transposed into four contiguous rows by one copy, as arithmetic on the strided columns runs
        # numpy's scalar loops (several times the instructions of the copy per use)
        c0, c1, c2, c3 = self._coefs16.take(k, mode="clip").view(np.float32).reshape(-1, 4).T.copy()
        gx = c3 * cy  # ∂z/∂cx = c1 + c3·fy
        gx += c1
        z = cx * gx
        z += c0
        gy = None
        if gradient:
            gy = c3 * cx  # ∂z/∂cy = c2 + c3·fx
            gy += c2
        cy *= c2
        z += cy
        return (z, gx, gy) if gradient else z

    def _gap(self, t: np.ndarray, o: tuple, d: Components) -> np.ndarray:
        """Height [m] of the ray points o + t·d above the height field (≤ 0: below the surface), with
        o and d in grid units across (x, y) and in metres along z."""
        cx = t * d[0]
        cx += o[0]
        cy = t * d[1]
        cy += o[1]
        z = t * d[2]
        z += o[2]
        z -= self._surface(cx, cy)
        return z

    def _grid_rays(self, o: np.ndarray, d: Components) -> tuple[tuple, Components]:
        """The rays in grid units across (cells from the first node) and in metres along z."""
        og = (_F32((o[0] - self.x0) * self.inv_dx), _F32((o[1] - self.y0) * self.inv_dy), _F32(o[2]))
        return og, (d[0] * self._sx, d[1] * self._sy, d[2])

    def hit_hfield(self, o: np.ndarray, d: Components) -> tuple[np.ndarray, np.ndarray]:
        """First intersection t (N,) float32 of rays o + t·d (one origin, float32 direction components)
        with the height-field object (inf on a miss), and the mask of the rays that came in through a
        side wall of its solid (their t is the entry into the box)."""
        n = d[0].shape[0]
        out = np.full(n, _INF, dtype=_F32)
        out_wall = np.zeros(n, dtype=bool)
        t_in, t_out = _slab(o, d, self.lo, self.hi)
        ok = (t_in <= t_out) & (t_out > 0)
        idx = None
        if not ok.all():
            idx = np.flatnonzero(ok)
            if idx.size == 0:
                return out, out_wall
            d = tuple(c[idx] for c in d)
            t_in, t_out = t_in[idx], t_out[idx]
        og, dg = self._grid_rays(o, d)
        dz = d[2]
        lo_t = np.maximum(t_in, _F32(0.0))
        # below the lowest grid height a ray inside the box has necessarily crossed the surface: march
        # only down to that height (the solid base below adds nothing but samples)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_floor = (_F32(self.z_floor) - og[2]) / dz
        np.copyto(t_floor, _F32(_INF), where=dz >= 0)
        reach = t_floor <= t_out
        span = np.minimum(t_out, t_floor)
        span -= lo_t
        # sample each ray from its entry into the box to its exit, about two grid cells apart, to
        # bracket the *first* crossing (a ray can pass over a rim, dip below the surface and come out
        # above it again); sample 0 below the surface means the ray came in through a side wall
        travel = float((span * np.sqrt(dg[0] * dg[0] + dg[1] * dg[1])).max(initial=0.0))
        n_march = min(max(math.ceil(travel / 2.0), 1), 24)
        # a ray that enters through the top face starts at the highest node, so above the surface:
        # its height there is needed only if it crosses before the next sample (computed below)
        with np.errstate(divide="ignore", invalid="ignore"):
            top = np.reciprocal(dz) * _F32(self.hi[2] - o[2]) >= t_in  # the top face is the entry
        top &= t_in >= 0
        top &= dz < 0
        if top.all():
            f_prev = np.full_like(lo_t, np.nan)
        elif not top.any():
            f_prev = self._gap(lo_t, og, dg)
        else:
            f_prev = np.full_like(lo_t, np.nan)
            side = np.flatnonzero(~top)
            f_prev[side] = self._gap(lo_t[side], og, tuple(c[side] for c in dg))
        t_prev = lo_t
        wall = f_prev <= 0  # below the surface at the entry: came in through a side wall
        found = wall.copy()
        a, b, fa, fb = (np.zeros_like(lo_t) for _ in range(4))
        # the samples of the rays still unbracketed only, gathered once they are fewer than
        # march_gather_below of those sampled (each ray's samples, hence its bracket, are the same
        # either way)
        act = None  # indices of those rays; None: all
        a_span, a_lo, a_dg, a_reach, a_found = span, lo_t, dg, reach, found
        n_left = len(found)
        n_left -= int(np.count_nonzero(found))
        for j in range(1, n_march + 1):
            if n_left == 0:
                break
            if n_left < self.march_gather_below * len(a_found):
                sel = np.flatnonzero(~a_found)
                act = sel if act is None else act[sel]
                a_span, a_lo, a_reach, t_prev, f_prev = (v[sel] for v in (a_span, a_lo, a_reach, t_prev, f_prev))
                a_dg = tuple(c[sel] for c in a_dg)
                a_found = np.zeros(len(sel), dtype=bool)
            t_j = a_span * _F32(j / n_march)
            t_j += a_lo
            f_j = self._gap(t_j, og, a_dg)
            new = f_j <= 0
            if j == n_march:
                new |= a_reach  # reached the lowest height inside the box
            new &= ~a_found
            if act is None:
                np.copyto(a, t_prev, where=new)
                np.copyto(fa, f_prev, where=new)
                np.copyto(b, t_j, where=new)
                np.copyto(fb, f_j, where=new)
            else:
                k = act[new]
                a[k], fa[k], b[k], fb[k] = t_prev[new], f_prev[new], t_j[new], f_j[new]
                found[k] = True
            a_found |= new
            n_left -= int(np.count_nonzero(new))
            t_prev, f_prev = t_j, f_j
        lazy = np.flatnonzero(np.isnan(fa) & found)  # crossed in the first interval, entered at the top
        if lazy.size:
            fa[lazy] = self._gap(a[lazy], og, tuple(c[lazy] for c in dg))
        # regula falsi inside the bracket, then Newton steps kept inside it
        with np.errstate(divide="ignore", invalid="ignore"):
            tc = np.fmax(a, np.fmin(b, a - fa * (b - a) / (fb - fa)))
        tc = self._newton(og, dg, tc, a, b)
        np.copyto(tc, lo_t, where=wall)
        np.copyto(tc, _F32(_INF), where=~found)
        if idx is None:
            return tc, wall
        out[ok] = tc  # a boolean scatter is cheaper than through the indices
        out_wall[ok] = wall
        return out, out_wall

    def _newton(self, og: tuple, dg: Components, tc: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Newton steps on the rays' height above the surface, kept inside [lo, hi], until a ray's step
        is shorter than the tolerance (its error is then of the order of the step squared over the
        surface's radius of curvature, or the step itself next to a grid edge); a NaN step, from a
        ray tangent to the surface, falls back to ``hi``. The rays still moving are gathered once
        they are the minority."""
        act = None  # indices of the rays still iterating; None: all
        ta, tb, t_act, gdx, gdy, gdz = lo, hi, tc, dg[0], dg[1], dg[2]
        ox, oy, oz = og
        with np.errstate(divide="ignore", invalid="ignore"):
            for _ in range(self.iterations):
                cx = t_act * gdx
                cx += ox
                cy = t_act * gdy
                cy += oy
                h, gx, gy = self._surface(cx, cy, gradient=True)
                step = t_act * gdz
                step += oz
                step -= h
                gx *= gdx
                gy *= gdy
                slope = gdz - gx
                slope -= gy
                step /= slope
                t_new = t_act - step
                np.fmax(ta, np.fmin(tb, t_new, out=t_new), out=t_new)
                moving = np.abs(t_new - t_act) > self.tolerance
                if act is None:
                    tc = t_act = t_new
                else:
                    tc[act] = t_new
                    t_act = t_new
                n_moving = int(np.count_nonzero(moving))
                if n_moving == 0:
                    break
                if 2 * n_moving < len(moving):
                    sel = np.flatnonzero(moving)
                    act = sel if act is None else act[sel]
                    ta, tb, t_act, gdx, gdy, gdz = (v[sel] for v in (ta, tb, t_act, gdx, gdy, gdz))
        return tc

    def _hit_box(self, o: np.ndarray, d: Components) -> np.ndarray:
        t_in, t_out = _slab(o, d, self.lo, self.hi)
        return np.where((t_in <= t_out) & (t_in > 0), t_in, _INF)

    def _hit_cylinder(self, o: np.ndarray, d: Components) -> np.ndarray:
        r, h = self.radius, self.height
        dx, dy, dz = (np.asarray(c, dtype=float) for c in d)  # float64: the quadratic cancels digits
        a = dx * dx + dy * dy
        b = 2 * (o[0] * dx + o[1] * dy)
        c = o[0] ** 2 + o[1] ** 2 - r * r
        disc = b * b - 4 * a * c
        with np.errstate(divide="ignore", invalid="ignore"):
            t_side = (-b - np.sqrt(np.maximum(disc, 0.0))) / (2 * a)
            z_side = o[2] + t_side * dz
            side = (disc >= 0) & (a > 0) & (t_side > 0) & (z_side >= 0) & (z_side <= h)
            t_cap = (h - o[2]) / dz
            px, py = o[0] + dx * t_cap, o[1] + dy * t_cap
            cap = (dz < 0) & (t_cap > 0) & (px * px + py * py <= r * r)
        return np.minimum(np.where(side, t_side, _INF), np.where(cap, t_cap, _INF))

    # -- public ------------------------------------------------------------------------------
    def cast_components(self, origin_world: np.ndarray, dirs_world: Components, origin_obj: np.ndarray,
                        dirs_obj: Components) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One chunk of rays, origin + t·dir, given in the world and in the object frame (origins (3,),
        direction components (N,) each, float32): t (N,) float32 of the first hit (inf on a miss),
        with boolean masks (N,) of the rays that hit the object and the table."""
        if self.kind == "hfield":
            t_obj, _ = self.hit_hfield(origin_obj, dirs_obj)
        elif self.kind == "box":
            t_obj = self._hit_box(origin_obj, dirs_obj)
        else:
            t_obj = self._hit_cylinder(origin_obj, dirs_obj)
        return self.with_table(np.asarray(t_obj, dtype=_F32), origin_world, dirs_world)

    def cast(self, origin_world: np.ndarray, dirs_world: np.ndarray, object_position: np.ndarray,
             object_rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ray parameters t (N,) of the first hit of rays origin + t·dir (N, 3) (inf on a miss), with
        boolean masks (N,) of the rays that hit the object and the table."""
        o_w = np.asarray(origin_world, dtype=float).reshape(3)
        dirs = np.asarray(dirs_world, dtype=float).reshape(-1, 3)
        o_obj = (o_w - object_position) @ object_rotation
        n = len(dirs)
        t = np.empty(n, dtype=_F32)
        hit_obj = np.empty(n, dtype=bool)
        hit_tab = np.empty(n, dtype=bool)
        for i0, i1 in chunk_bounds(n):
            d = dirs[i0:i1]
            d_obj = d @ object_rotation
            comps = tuple(np.ascontiguousarray(c[:, k], dtype=_F32) for c in (d, d_obj) for k in range(3))
            t[i0:i1], hit_obj[i0:i1], hit_tab[i0:i1] = self.cast_components(o_w, comps[:3], o_obj, comps[3:])
        return t.astype(float), hit_obj, hit_tab

    def with_table(self, t_obj: np.ndarray, o_w: np.ndarray, d_w: Components):
        """The first hits (t, on object, on table) of rays o_w + t·d_w (world frame, float32 components)
        given their object hits t_obj (N,) float32 (inf on a miss)."""
        hit_obj = t_obj < _INF
        t = t_obj
        hit_tab = np.zeros_like(hit_obj)
        tz = self.table_z
        if o_w[2] > tz:
            # seen from above the table, a hit on the object above the table top comes before the ray
            # could cross the table plane: only the others need the table
            with np.errstate(invalid="ignore"):
                z_hit = t_obj * d_w[2]
                z_hit += _F32(o_w[2])
                need = np.flatnonzero(~(z_hit >= _F32(tz)))
        else:
            need = np.arange(len(t_obj))
        if need.size == 0:
            return t, hit_obj, hit_tab
        dx, dy, dz = (c[need].astype(float) for c in d_w)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_tab = (tz - o_w[2]) / dz
        xt = o_w[0] + t_tab * dx
        yt = o_w[1] + t_tab * dy
        x0, x1, y0, y1 = self.table_xy
        on = (t_tab > 0) & (xt >= x0) & (xt <= x1) & (yt >= y0) & (yt <= y1) & (t_tab < t_obj[need])
        sel = need[on]
        t = t_obj.copy()
        t[sel] = t_tab[on]
        hit_tab[sel] = True
        hit_obj[sel] = False
        return t, hit_obj, hit_tab
