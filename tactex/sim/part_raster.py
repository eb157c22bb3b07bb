"""A part's top surface as a height raster: a mesh ray cast straight down on a grid, or a scan binned.

Both work in the part's frame (metres, z up, the part's lowest point at z = 0, x–y centred on its
bounding box). A node of the grid gets the height of the highest surface above it: what a tool
coming from above can touch. What lies under a higher surface (the floor under a lip, the inside of
a cup seen through its wall's top) is lost; :attr:`HeightRaster.lost_share` is the share of the part's
upward-facing area that is lost that way (for a scan: the share of its points). A node whose vertical
line misses the part lies off its footprint (height 0, the table).

The mesh is rasterised exactly (a vertical ray per node against every triangle over it, vectorised
over triangle-node pairs), so the raster equals the mesh at its nodes; a scan's nodes take the mean
height of the top band of the points binned to them, with the footprint's empty nodes interpolated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tactex.errors import CloudError

__all__ = ["LOST_TOLERANCE_M", "SCAN_TOP_BAND_M", "HeightRaster", "bilinear", "raster_mesh", "raster_points"]

#: A point of an upward face lower than the raster by more than this is under another surface [m].
LOST_TOLERANCE_M = 1e-3
#: Faces whose unit normal's z exceeds this count as upward (they can be pressed from above) [-].
UPWARD_NZ = 0.1
#: A scan's points within this of the highest point binned to a node are its top surface [m]
#: (a depth camera's noise at half a metre is about a millimetre).
SCAN_TOP_BAND_M = 3e-3
#: Most points an overhang is judged on.
_MAX_PROBES = 400_000
#: Largest number of triangle-node pairs tested at once (memory: about 100 bytes each).
_CHUNK_PAIRS = 2_000_000


@dataclass(frozen=True)
class HeightRaster:
    """The top surface of a part on a regular grid (part frame, metres).

    Attributes:
        xs, ys: node coordinates (nx,), (ny,) [m], centred on 0.
        z: heights (ny, nx) [m], row k at ys[k]; 0 off the footprint.
        footprint: (ny, nx) True where the part is under the node.
        colors: (ny, nx, 3) RGB in [0, 1] of the surface at each node, or None (no colours in the file).
        target: (ny, nx) the file's stored target at each node (≥ 0), or None.
        lost_share: share of the part's upward area (a scan: its points) under a higher surface [-].
        upward_area_m2: the part's upward-facing area [m²] (a scan: 0).
    """

    xs: np.ndarray
    ys: np.ndarray
    z: np.ndarray
    footprint: np.ndarray
    colors: np.ndarray | None
    target: np.ndarray | None
    lost_share: float
    upward_area_m2: float

    @property
    def spacing_m(self) -> float:
        return float(self.xs[1] - self.xs[0])


def _grid(size_xy: np.ndarray, spacing_m: float) -> tuple[np.ndarray, np.ndarray]:
    # to the micron: a float32 file's 0.2 m and a millimetre file's 200 mm get the same grid
    size_xy = np.round(np.asarray(size_xy, dtype=np.float64), 6)
    nx, ny = (max(2, int(np.ceil(s / spacing_m)) + 1) for s in size_xy)
    return (np.linspace(-size_xy[0] / 2, size_xy[0] / 2, nx), np.linspace(-size_xy[1] / 2, size_xy[1] / 2, ny))


def bilinear(xs: np.ndarray, ys: np.ndarray, z: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """z (ny, nx) on the grid (xs, ys) bilinearly interpolated at points (x, y) [m], clamped to the grid."""
    x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
    nx, ny = len(xs), len(ys)
    c = np.clip((x - xs[0]) / (xs[-1] - xs[0]) * (nx - 1), 0, nx - 1)
    r = np.clip((y - ys[0]) / (ys[-1] - ys[0]) * (ny - 1), 0, ny - 1)
    c0 = np.minimum(np.floor(c).astype(int), nx - 2)
    r0 = np.minimum(np.floor(r).astype(int), ny - 2)
    fc, fr = c - c0, r - r0
    low = z[r0, c0] * (1 - fc) + z[r0, c0 + 1] * fc
    high = z[r0 + 1, c0] * (1 - fc) + z[r0 + 1, c0 + 1] * fc
    return low * (1 - fr) + high * fr


def _pairs(tri_xy: np.ndarray, xs: np.ndarray, ys: np.ndarray, first: int, last: int):
    """The (triangle, node) pairs of triangles first..last-1 whose bounding box holds the node."""
    dx, dy = xs[1] - xs[0], ys[1] - ys[0]
    t = tri_xy[first:last]
    i0 = np.clip(np.ceil((t[:, :, 0].min(1) - xs[0]) / dx - 1e-9), 0, len(xs)).astype(np.int64)
    i1 = np.clip(np.floor((t[:, :, 0].max(1) - xs[0]) / dx + 1e-9), -1, len(xs) - 1).astype(np.int64)
    j0 = np.clip(np.ceil((t[:, :, 1].min(1) - ys[0]) / dy - 1e-9), 0, len(ys)).astype(np.int64)
    j1 = np.clip(np.floor((t[:, :, 1].max(1) - ys[0]) / dy + 1e-9), -1, len(ys) - 1).astype(np.int64)
    wi, wj = np.maximum(i1 - i0 + 1, 0), np.maximum(j1 - j0 + 1, 0)
    count = wi * wj
    tri = np.repeat(np.arange(first, last), count)
    k = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    w = np.repeat(wi, count)
    return tri, np.repeat(i0, count) + k % np.maximum(w, 1), np.repeat(j0, count) + k // np.maximum(w, 1)


def raster_mesh(vertices: np.ndarray, faces: np.ndarray, spacing_m: float, vertex_colors: np.ndarray | None = None,
                face_colors: np.ndarray | None = None, vertex_target: np.ndarray | None = None,
                watertight: bool = True) -> HeightRaster:
    """The height raster of a triangle mesh already in the part frame (vertices (V, 3) [m], min z = 0,
    x–y centred), ``spacing_m`` [m] between nodes. Colours (V, 3) or (F, 3) in [0, 1] and a per-vertex
    target are carried to the nodes from the top triangle (barycentric). An open mesh (``watertight``
    False) may have its faces wound either way: an upward face is then one whose normal is within 84°
    of vertical either way."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    size = np.ptp(v[:, :2], axis=0)
    xs, ys = _grid(size, spacing_m)
    tri = v[f]  # (F, 3, 3)
    a, b, c = tri[:, 0, :2], tri[:, 1, :2], tri[:, 2, :2]
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    usable = np.flatnonzero(np.abs(det) > 1e-14)  # vertical triangles cover no node
    tri_xy = tri[usable, :, :2]
    best = np.full(len(xs) * len(ys), -np.inf)
    best_tri = np.full(best.size, -1, dtype=np.int64)
    best_bary = np.zeros((best.size, 3))
    per = np.maximum(1, np.prod(np.ptp(tri_xy, axis=1) / spacing_m + 1, axis=1))
    cum = np.cumsum(per)
    edges = np.searchsorted(cum, np.arange(_CHUNK_PAIRS, cum[-1], _CHUNK_PAIRS)) + 1
    for start, stop in zip(np.r_[0, edges], np.r_[edges, len(usable)], strict=True):
        if stop <= start:
            continue
        k, ci, cj = _pairs(tri_xy, xs, ys, int(start), int(stop))
        if k.size == 0:
            continue
        g = usable[k]
        px, py = xs[ci], ys[cj]
        ax, ay, bx, by, cx, cy = a[g, 0], a[g, 1], b[g, 0], b[g, 1], c[g, 0], c[g, 1]
        d = det[g]
        l1 = ((px - ax) * (cy - ay) - (cx - ax) * (py - ay)) / d
        l2 = ((bx - ax) * (py - ay) - (px - ax) * (by - ay)) / d
        l0 = 1.0 - l1 - l2
        eps = -1e-9
        inside = (l0 >= eps) & (l1 >= eps) & (l2 >= eps)
        g, ci, cj, bary = g[inside], ci[inside], cj[inside], np.stack([l0, l1, l2], axis=1)[inside]
        z = np.einsum("nk,nk->n", bary, tri[g, :, 2])
        cell = cj * len(xs) + ci
        order = np.lexsort((z, cell))
        cell, z, g, bary = cell[order], z[order], g[order], bary[order]
        top = np.r_[cell[1:] != cell[:-1], True]
        cell, z, g, bary = cell[top], z[top], g[top], bary[top]
        higher = z > best[cell]
        cell = cell[higher]
        best[cell], best_tri[cell], best_bary[cell] = z[higher], g[higher], bary[higher]
    footprint = np.isfinite(best)
    if not footprint.any():
        raise CloudError("the part covers no node of its height raster (a flat or degenerate mesh seen from above)")
    shape = (len(ys), len(xs))
    zgrid = np.where(footprint, best, 0.0).reshape(shape)
    colors = None
    hit, hb = best_tri[footprint], best_bary[footprint]
    if vertex_colors is not None:
        colors = np.zeros((best.size, 3))
        colors[footprint] = np.einsum("nk,nkc->nc", hb, np.asarray(vertex_colors, float)[f[hit]])
    elif face_colors is not None:
        colors = np.zeros((best.size, 3))
        colors[footprint] = np.asarray(face_colors, float)[hit]
    target = None
    if vertex_target is not None:
        target = np.zeros(best.size)
        target[footprint] = np.einsum("nk,nk->n", hb, np.asarray(vertex_target, float)[f[hit]])
    area, lost = _lost_area(tri, xs, ys, zgrid, watertight)
    return HeightRaster(xs, ys, zgrid, footprint.reshape(shape),
                        None if colors is None else np.clip(colors.reshape(*shape, 3), 0.0, 1.0),
                        None if target is None else target.reshape(shape), lost / area if area > 0 else 0.0, area)


def _lost_area(tri: np.ndarray, xs: np.ndarray, ys: np.ndarray, z: np.ndarray, watertight: bool) -> tuple[float, float]:
    """(upward area, the part of it under a higher surface) [m²], the second judged on points spread uniformly
    over the upward faces (about four per raster cell of area, seeded: the same mesh gives the same share)."""
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    double = np.linalg.norm(cross, axis=1)
    nz = np.divide(cross[:, 2], double, out=np.zeros_like(double), where=double > 0)
    up = (nz > UPWARD_NZ) if watertight else (np.abs(nz) > UPWARD_NZ)
    if not up.any():
        return 0.0, 0.0
    t, area = tri[up], double[up] / 2
    total = float(area.sum())
    count = int(np.clip(4 * total / (xs[1] - xs[0]) ** 2, 1000, _MAX_PROBES))
    rng = np.random.default_rng(0)
    face = rng.choice(len(t), size=count, p=area / total)
    r1, r2 = np.sqrt(rng.random(count)), rng.random(count)
    w = np.stack([1 - r1, r1 * (1 - r2), r1 * r2], axis=1)
    probes = np.einsum("nk,nkc->nc", w, t[face])
    # under a higher surface by the interpolated raster and by its nearest node: at the foot of a cliff the first
    # alone would count a cell-wide band of the lower surface as lost, on a steep face the second alone
    # would count the half cell uphill
    above = bilinear(xs, ys, z, probes[:, 0], probes[:, 1]) - probes[:, 2]
    h = xs[1] - xs[0]
    ci = np.clip(np.rint((probes[:, 0] - xs[0]) / h).astype(np.int64), 0, len(xs) - 1)
    cj = np.clip(np.rint((probes[:, 1] - ys[0]) / (ys[1] - ys[0])).astype(np.int64), 0, len(ys) - 1)
    lost = (above > LOST_TOLERANCE_M) & (z[cj, ci] - probes[:, 2] > LOST_TOLERANCE_M)
    return total, total * float(np.mean(lost))


def raster_points(points: np.ndarray, spacing_m: float, colors: np.ndarray | None = None,
                  target: np.ndarray | None = None) -> HeightRaster:
    """The height raster of a scan's points (N, 3) already in the part frame [m], ``spacing_m`` [m]
    between nodes (about twice the scan's spacing, so that most nodes get points). A node's height is
    the mean of the points binned to it within :data:`SCAN_TOP_BAND_M` of their highest; its colour and
    target are those points' means. Nodes without points inside the footprint (within two nodes of a
    node with points, holes closed) are interpolated linearly from their neighbours."""
    from scipy import ndimage
    from scipy.interpolate import griddata

    p = np.asarray(points, dtype=np.float64)
    xs, ys = _grid(np.ptp(p[:, :2], axis=0), spacing_m)
    ci = np.clip(np.rint((p[:, 0] - xs[0]) / spacing_m).astype(np.int64), 0, len(xs) - 1)
    cj = np.clip(np.rint((p[:, 1] - ys[0]) / spacing_m).astype(np.int64), 0, len(ys) - 1)
    cell = cj * len(xs) + ci
    n = len(xs) * len(ys)
    top = np.full(n, -np.inf)
    np.maximum.at(top, cell, p[:, 2])
    band = p[:, 2] >= top[cell] - SCAN_TOP_BAND_M
    count = np.bincount(cell[band], minlength=n).astype(float)
    has = count > 0

    def mean(values: np.ndarray) -> np.ndarray:
        return np.bincount(cell[band], weights=values[band], minlength=n) / np.maximum(count, 1)

    zsum = mean(p[:, 2])
    shape = (len(ys), len(xs))
    footprint = ndimage.binary_fill_holes(ndimage.binary_closing(has.reshape(shape), iterations=2)) | has.reshape(shape)
    gx, gy = np.meshgrid(xs, ys)
    known = np.column_stack([gx.ravel()[has], gy.ravel()[has]])
    fill = footprint.ravel() & ~has
    z = np.where(has, zsum, 0.0)
    cols = None if colors is None else np.stack([mean(np.asarray(colors, float)[:, k]) for k in range(3)], axis=1)
    tgt = None if target is None else mean(np.asarray(target, float))
    if fill.any():
        query = np.column_stack([gx.ravel()[fill], gy.ravel()[fill]])
        for arr in [a for a in (z, tgt) if a is not None] + ([] if cols is None else [cols]):
            known_vals = arr[has]
            got = griddata(known, known_vals, query, method="linear")
            near = griddata(known, known_vals, query, method="nearest")
            arr[fill] = np.where(np.isfinite(got), got, near)
    lost = float(np.mean(p[:, 2] < top[cell] - SCAN_TOP_BAND_M))
    return HeightRaster(xs, ys, z.reshape(shape), footprint, None if cols is None else cols.reshape(*shape, 3),
                        None if tgt is None else tgt.reshape(shape), lost, 0.0)
