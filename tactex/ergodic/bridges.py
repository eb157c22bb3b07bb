"""Scan-hole bridges: links of the Laplacian that join two sides of a hole in the cloud.

A single-view scan has holes (occlusion shadows, dark or shiny patches). robust_laplacian builds
its operator from local triangulations of each point's ``n_neighbors`` nearest points, so where a
hole is narrower than that neighbourhood the Laplacian links the two sides and heat diffuses
across (TEC §VI-D: the neighbour count decides which parts are connected). An agent that walks on
the cloud cannot follow: it stays within ``max_off_cloud_voxels`` voxels of a cloud point and stops at
the hole's rim while the potential keeps pulling it across (a scan's base may be joined to its
body only by such links: an agent started there would never reach the target).

:func:`gap_links` finds these links once per cloud: a link of L whose straight chord passes
farther than the walking limit from every cloud point, and no longer than the longest hop
allowed. The explorer hops along one (:class:`Bridge`) when the agent is at a scan edge and
the potential at the far end is higher than anywhere around the agent: there is no way up on
this side, and the Laplacian says the surface goes on over there. The chord is the surface's
linear interpolation across the hole. Links through the material (the front and back of a thin
part, which the Laplacian links too) are told apart by the direction of the chord's offset from
the surface: beside it for a hole, along the normal for a wall.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

__all__ = ["NORMAL_NEIGHBOURS", "WALL_ANGLE", "Bridge", "GapLinks", "gap_links"]

#: Angle [rad] between a deep chord sample's offset from the cloud and the surface normal there
#: above which the sample is beside the surface (a hole), below which above or below it (a wall).
#: A hole in a plane: ~90°; across a 60° fold: ~60°; through a slab: ~0° at every sample.
WALL_ANGLE = np.radians(45.0)
#: Neighbours of the local PCA that gives the normal at a cloud point [-].
NORMAL_NEIGHBOURS = 10


@dataclass(frozen=True)
class GapLinks:
    """Per cloud point, the far ends of its gap links (CSR layout).

    ``far[ptr[j]:ptr[j + 1]]`` are the points joined to point j across a hole; ``has[j]`` says
    whether there are any.
    """

    ptr: np.ndarray
    far: np.ndarray
    has: np.ndarray

    @property
    def n_links(self) -> int:
        """Number of links (each counted once)."""
        return int(self.far.size // 2)

    def of(self, points: np.ndarray) -> np.ndarray:
        """Far ends of the links of the given points (indices, possibly repeated)."""
        parts = [self.far[self.ptr[j] : self.ptr[j + 1]] for j in points.tolist() if self.has[j]]
        return np.concatenate(parts) if parts else np.zeros(0, dtype=np.intp)


@dataclass
class Bridge:
    """A hop in progress: from ``start`` [m] with normal ``start_normal`` to cloud point
    ``target`` at ``end`` [m] with outward normal ``end_normal`` (unit, (3,) each)."""

    target: int
    start: np.ndarray
    end: np.ndarray
    start_normal: np.ndarray
    end_normal: np.ndarray

    def share(self, x: np.ndarray) -> float:
        """Share of the chord done at x [m]: its projection on the chord, clamped to [0, 1] (1 for a point chord)."""
        chord = self.end - self.start
        c2 = float(chord @ chord)
        return min(max(float((x - self.start) @ chord) / c2, 0.0), 1.0) if c2 > 0.0 else 1.0

    def normal_at(self, x: np.ndarray) -> np.ndarray:
        """Unit normal at x on the chord: the end normals blended by the share of the chord done."""
        t = self.share(x)
        n = (1.0 - t) * self.start_normal + t * self.end_normal
        nn = float(np.sqrt(n @ n))
        # Opposite end normals (a hole across a knife edge) blend to zero: keep the nearer end's.
        if nn < 1e-6:
            return (self.start_normal if t < 0.5 else self.end_normal).copy()
        return n / nn


def _unit_normals(points: np.ndarray, tree: cKDTree, which: np.ndarray, k: int = NORMAL_NEIGHBOURS) -> np.ndarray:
    """Unoriented unit normals (m, 3) of the cloud at the points ``which`` (local PCA of k neighbours)."""
    nb = points[tree.query(points[which], k=min(k, points.shape[0]))[1]]
    q = nb - nb.mean(axis=1, keepdims=True)
    return np.linalg.eigh(np.einsum("mki,mkj->mij", q, q))[1][:, :, 0]


def gap_links(points: np.ndarray, laplacian, tree: cKDTree, max_off_m: float, max_length_m: float) -> GapLinks:
    """The links of ``laplacian`` (N × N, sparse) that cross a hole in ``points`` (N, 3) [m].

    A link (i, j) crosses a hole when some point of its chord, sampled every ``max_off_m / 4``
    along the link, is farther than ``max_off_m`` from every cloud point (``tree`` is the cloud's
    K-D tree), and some such deep sample lies *beside* the surface rather than above or below
    it: its offset from the nearest cloud point makes more than ``WALL_ANGLE`` with that point's
    normal. The Laplacian also links the front and back of a thin part; every deep sample of such
    a chord sits straight above or below a sheet (offset along the normal), so it is left out and
    the agent never hops through a wall. A step in depth (an occlusion shadow of a single-view
    scan) keeps its link: near the upper edge the chord runs beside the surface. Links longer
    than ``max_length_m`` are left out (0 leaves out every link).
    """
    n = points.shape[0]
    empty = GapLinks(np.zeros(n + 1, dtype=np.intp), np.zeros(0, dtype=np.intp), np.zeros(n, dtype=bool))
    if max_length_m <= 0.0 or laplacian is None:
        return empty
    coo = sp.triu(sp.coo_matrix(laplacian), k=1).tocoo()
    i, j = coo.row.astype(np.intp), coo.col.astype(np.intp)
    length = np.linalg.norm(points[j] - points[i], axis=1)
    # A chord shorter than 2·max_off stays within max_off of its own ends: it cannot cross a hole.
    keep = (length > 2.0 * max_off_m) & (length <= max_length_m) & (coo.data != 0)
    i, j, length = i[keep], j[keep], length[keep]
    if i.size == 0:
        return empty
    # Samples every max_off/4 along each link (a hole deeper than 1.125·max_off cannot hide between two).
    per_link = np.ceil(length / (0.25 * max_off_m)).astype(np.intp)
    link = np.repeat(np.arange(i.size), per_link - 1)
    first = np.cumsum(per_link - 1) - (per_link - 1)
    t = (np.arange(link.size) - first[link] + 1) / per_link[link]
    samples = points[i[link]] + t[:, None] * (points[j[link]] - points[i[link]])
    dist, nearest = tree.query(samples)
    deep = dist > max_off_m
    # |cos| of the angle between a deep sample's offset and the normal, the smallest along each link.
    along_normal = np.full(i.size, np.inf)
    if deep.any():
        offset = (samples[deep] - points[nearest[deep]]) / dist[deep, None]
        normals = _unit_normals(points, tree, nearest[deep])
        np.minimum.at(along_normal, link[deep], np.abs(np.einsum("mi,mi->m", offset, normals)))
    crosses = along_normal <= np.cos(WALL_ANGLE)  # links without deep samples stay at inf: no hole
    i, j = i[crosses], j[crosses]
    src = np.concatenate([i, j])
    dst = np.concatenate([j, i])
    order = np.argsort(src, kind="stable")
    counts = np.bincount(src, minlength=n)
    ptr = np.zeros(n + 1, dtype=np.intp)
    np.cumsum(counts, out=ptr[1:])
    return GapLinks(ptr, dst[order].astype(np.intp), counts > 0)
