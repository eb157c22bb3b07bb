"""Painting marks on a cloud: a target (with a weight) and a keep-out zone, by brush and by fill.

What ``tactex annotate``'s page does, as plain array operations on the cloud's points (world frame, m):
a brush dab marks every point within its radius of the picked point (a KD-tree ball query, so the
brush is a ball in space, not a disc on the screen), a stroke sweeps that ball along the chord from
one picked point to another; erasing clears both marks there; a fill marks the connected region of
points that carry the same marks as the picked one, points being neighbours within
:data:`FILL_LINK_SPACINGS` × the cloud's spacing h (so a closed stroke stops a fill, as a painted
outline does in an image editor). A point is target or kept out, never both: a mark replaces the
other. Areas count h² per point (a point of a cloud of mean spacing h stands for that much surface).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from tactex.errors import InputError
from tactex.pointcloud.cloud import SurfaceCloud

__all__ = ["FILL_LINK_SPACINGS", "MARK_KINDS", "PICK_SPACINGS", "UNDO_DEPTH", "Annotation", "MarkCounts"]

#: What a brush or a fill puts down: target mass, a keep-out zone, or nothing (erase).
MARK_KINDS = ("target", "keep_out", "erase")
#: Two points are neighbours for a fill within this many spacings h: above 1 so that a grid's
#: diagonal neighbours (√2 h) link, below 2 so that a stroke one point wide still stops the fill.
FILL_LINK_SPACINGS = 1.5
#: A click's ray picks among the points this many spacings h from it (points are drawn about h wide):
#: the first of them along the ray, so a click never reaches through the surface to its far side.
PICK_SPACINGS = 1.0
#: How many marks :meth:`Annotation.undo` can take back.
UNDO_DEPTH = 100
#: A ray farther than this many spacings from every point picks nothing (a click beside the cloud).
PICK_MISS_SPACINGS = 10.0


@dataclass(frozen=True)
class MarkCounts:
    """How much is marked: points and area [cm²] of each mark."""

    n_points: int
    n_target: int
    n_keep_out: int
    target_area_cm2: float
    keep_out_area_cm2: float

    def as_dict(self) -> dict[str, float]:
        return {"n_points": self.n_points, "n_target": self.n_target, "n_keep_out": self.n_keep_out,
                "target_area_cm2": self.target_area_cm2, "keep_out_area_cm2": self.keep_out_area_cm2}


class Annotation:
    """The marks on one cloud, edited in place.

    Attributes:
        cloud: the cloud painted on (points in m).
        target: (N,) float ≥ 0, the target mass per point (0 = not target).
        keep_out: (N,) bool, True where no footprint may touch.
    """

    def __init__(self, cloud: SurfaceCloud, target: np.ndarray | None = None,
                 keep_out: np.ndarray | None = None) -> None:
        n = len(cloud)
        self.cloud = cloud
        self.target = np.zeros(n) if target is None else np.array(target, dtype=np.float64)
        self.keep_out = np.zeros(n, dtype=bool) if keep_out is None else np.array(keep_out, dtype=bool)
        if self.target.shape != (n,) or self.keep_out.shape != (n,):
            raise InputError(f"the marks need one entry per point ({n})")
        self.target[~np.isfinite(self.target) | (self.target < 0)] = 0.0
        self.target[self.keep_out] = 0.0
        self._tree = cKDTree(cloud.points)
        self._links: list[np.ndarray] | None = None
        self._history: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (indices, target, keep_out) before

    @property
    def point_area_m2(self) -> float:
        """Surface one point stands for [m²]: h² for a cloud of mean spacing h."""
        return float(self.cloud.spacing) ** 2

    def _index(self, index: int) -> int:
        i = int(index)
        if not 0 <= i < len(self.cloud):
            raise InputError(f"point index {index} is outside the cloud (0..{len(self.cloud) - 1})")
        return i

    def pick(self, ray_origin: np.ndarray, ray_direction: np.ndarray) -> int | None:
        """The point a click on the screen meant: of the points within :data:`PICK_SPACINGS` × h of the
        ray (world frame, m; the nearest ones when none is), the one nearest the ray on the first surface
        it meets; None when the ray
        passes the cloud by more than a brush could reach or every point lies behind its origin."""
        o = np.asarray(ray_origin, dtype=np.float64)
        d = np.asarray(ray_direction, dtype=np.float64)
        norm = float(np.linalg.norm(d))
        if o.shape != (3,) or d.shape != (3,) or not np.isfinite(norm) or norm == 0.0:
            raise InputError("a pick needs a ray: an origin and a non-zero direction, 3 numbers each")
        d = d / norm
        rel = self.cloud.points - o
        along = rel @ d
        off = np.linalg.norm(rel - along[:, None] * d, axis=1)
        ahead = along > 0
        if not ahead.any():
            return None
        off = np.where(ahead, off, np.inf)
        h = float(self.cloud.spacing)
        reach = max(PICK_SPACINGS * h, float(off.min()) + h)
        if off.min() > PICK_MISS_SPACINGS * h:
            return None
        near = np.flatnonzero(off <= reach)
        front = near[along[near] <= along[near].min() + h]  # the surface the ray meets first
        return int(front[np.argmin(off[front])])

    def brush(self, index: int, radius_m: float) -> np.ndarray:
        """Indices of the points within ``radius_m`` [m] of point ``index`` (the point itself always)."""
        i = self._index(index)
        if not (np.isfinite(radius_m) and radius_m >= 0):
            raise InputError(f"the brush radius must be ≥ 0 m, got {radius_m!r}")
        return np.asarray(self._tree.query_ball_point(self.cloud.points[i], float(radius_m)), dtype=np.intp)

    def mark(self, indices: np.ndarray, kind: str, weight: float = 1.0) -> np.ndarray:
        """Put mark ``kind`` (:data:`MARK_KINDS`) on ``indices``; a target weight is the mass per point
        (> 0). Returns the indices whose marks changed."""
        idx = np.asarray(indices, dtype=np.intp)
        before_t, before_k = self.target[idx].copy(), self.keep_out[idx].copy()
        if kind == "target":
            if not (np.isfinite(weight) and weight > 0):
                raise InputError(f"a target weight must be > 0, got {weight!r}")
            self.target[idx] = float(weight)
            self.keep_out[idx] = False
        elif kind == "keep_out":
            self.keep_out[idx] = True
            self.target[idx] = 0.0
        elif kind == "erase":
            self.keep_out[idx] = False
            self.target[idx] = 0.0
        else:
            raise InputError(f"unknown mark '{kind}'; valid: {', '.join(MARK_KINDS)}")
        changed = (self.target[idx] != before_t) | (self.keep_out[idx] != before_k)
        if changed.any():
            self._history.append((idx[changed], before_t[changed], before_k[changed]))
            del self._history[:-UNDO_DEPTH]
        return np.unique(idx[changed])

    def undo(self) -> np.ndarray:
        """Take back the last mark that changed anything (up to :data:`UNDO_DEPTH` of them); the indices
        restored (none when there is nothing to take back)."""
        if not self._history:
            return np.zeros(0, dtype=np.intp)
        idx, target, keep_out = self._history.pop()
        self.target[idx], self.keep_out[idx] = target, keep_out
        return np.unique(idx)

    def paint(self, index: int, radius_m: float, kind: str, weight: float = 1.0) -> np.ndarray:
        """One brush dab of ``kind`` centred on point ``index``; the indices changed."""
        return self.mark(self.brush(index, radius_m), kind, weight)

    def stroke_points(self, start: int, end: int, radius_m: float) -> np.ndarray:
        """Indices of the points a brush of ``radius_m`` [m] covers moving straight from point ``start``
        to point ``end``: those within the radius of the chord between them (a capsule). On a curved
        surface the chord runs under it, by its sagitta: strokes shorter than the bend allows keep on it."""
        a, b = self.cloud.points[self._index(start)], self.cloud.points[self._index(end)]
        radius = max(float(radius_m), 0.0)
        ab = b - a
        length = float(np.linalg.norm(ab))
        # candidates: the ball around the chord's middle holding the whole capsule
        near = np.asarray(self._tree.query_ball_point((a + b) / 2.0, length / 2.0 + radius), dtype=np.intp)
        rel = self.cloud.points[near] - a
        t = np.clip(rel @ ab / (length * length), 0.0, 1.0) if length > 0 else np.zeros(len(near))
        dist = np.linalg.norm(rel - t[:, None] * ab, axis=1)
        return np.sort(near[dist <= radius])

    def stroke(self, start: int, end: int, radius_m: float, kind: str, weight: float = 1.0) -> np.ndarray:
        """A brush stroke of ``kind`` from point ``start`` to point ``end``; the indices changed."""
        if not (np.isfinite(radius_m) and radius_m >= 0):
            raise InputError(f"the brush radius must be ≥ 0 m, got {radius_m!r}")
        return self.mark(self.stroke_points(start, end, radius_m), kind, weight)

    def _neighbours(self) -> list[np.ndarray]:
        if self._links is None:
            radius = FILL_LINK_SPACINGS * float(self.cloud.spacing)
            self._links = [np.asarray(n, dtype=np.intp) for n in self._tree.query_ball_point(self.cloud.points, radius)]
        return self._links

    def region(self, index: int) -> np.ndarray:
        """The connected points that carry the same marks as point ``index`` (it included), sorted."""
        i = self._index(index)
        same = (self.keep_out == self.keep_out[i]) & (self.target == self.target[i])
        links = self._neighbours()
        seen = np.zeros(len(self.cloud), dtype=bool)
        seen[i] = True
        frontier = [i]
        while frontier:
            nxt = np.concatenate([links[j] for j in frontier])
            nxt = np.unique(nxt[same[nxt] & ~seen[nxt]])
            seen[nxt] = True
            frontier = nxt.tolist()
        return np.flatnonzero(seen)

    def fill(self, index: int, kind: str, weight: float = 1.0) -> np.ndarray:
        """Mark the connected region of point ``index`` (:meth:`region`); the indices changed."""
        return self.mark(self.region(index), kind, weight)

    def counts(self) -> MarkCounts:
        """Points and areas [cm²] marked."""
        n_target = int(np.count_nonzero(self.target > 0))
        n_keep = int(np.count_nonzero(self.keep_out))
        cm2 = self.point_area_m2 * 1e4
        return MarkCounts(len(self.cloud), n_target, n_keep, round(n_target * cm2, 3), round(n_keep * cm2, 3))
