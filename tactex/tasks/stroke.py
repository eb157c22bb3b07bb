"""Straight strokes through small islands of dirt: the pad wipes an island in a pass or two.

An island of dirt smaller than the pad needs no ergodic coverage: one straight pass of the pad over it
wipes every point of it, back and forth until the robot's wear model
(:class:`~tactex.tasks.wear_model.WearModel`) says it is clean (the task ends the stroke there, part-way
through a pass if need be). HEDAC's potential, cooled to stay
local, would instead hold the agent dithering on the island's peak, where it slides slowly and wipes
little. Islands larger than the pad stay with the explorer.

A stroke may start with a slide in contact from where the pad is (a transfer between two islands close
together), when sliding there takes less time than a lift-off, a move and a touch-down, and the
straight line between them stays on the captured surface (never across a bowl's hollow or a hole in
the capture).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from tactex.pointcloud.cloud import SurfaceCloud
from tactex.tasks.raster import WaypointPath
from tactex.tasks.wear_model import WearModel

__all__ = ["IslandStroke", "plan_stroke", "surface_line"]

#: Most passes of a stroke before the island is handed to the explorer [-].
MAX_PASSES = 4
#: How far a stroke's pass runs past the island on each side, in pad radii [-]. Half a radius: every island
#: point stays under the pad for 1.37 radii of each pass or more (an island is at most half a radius across
#: from its centre, the worst point on its rim beside the line), and the pass turns back soon after the pad has
#: left the island, where a full radius slides a third of each pass over clean surface.
STROKE_OVERRUN_RADII = 0.5
#: Farthest a straight line may leave the captured surface and still count as a line on it [m].
MAX_LINE_GAP_M = 0.004


def surface_line(cloud: SurfaceCloud, tree: cKDTree, a_m: np.ndarray, b_m: np.ndarray,
                 step_m: float) -> tuple[np.ndarray, float]:
    """The chord from ``a_m`` to ``b_m`` (3,) [m] sampled every ``step_m`` and snapped to the nearest cloud
    points: the waypoints (M, 3) [m] (repeats dropped) and the largest sample-to-point distance [m] (how far
    the chord leaves the captured surface)."""
    a, b = np.asarray(a_m, dtype=float), np.asarray(b_m, dtype=float)
    n = max(int(np.ceil(np.linalg.norm(b - a) / step_m)), 1)
    samples = a + np.linspace(0.0, 1.0, n + 1)[:, None] * (b - a)
    dist, idx = tree.query(samples)
    keep = np.concatenate([[True], idx[1:] != idx[:-1]])
    return cloud.points[idx[keep]], float(dist.max())


@dataclass
class IslandStroke:
    """A stroke in progress: ``path`` serves its commands; ``island`` are the cloud indices it wipes, between
    ``a`` and ``b`` (3,) [m], the ends of one pass (the same point for a transfer only)."""

    path: WaypointPath
    island: np.ndarray
    a: np.ndarray
    b: np.ndarray
    passes: int = 1
    transfer: bool = False  # it starts with a slide in contact from the pad's position

    @property
    def transfer_only(self) -> bool:
        """A slide in contact to an island the explorer covers, wiping no island of its own."""
        return self.island.size == 0

    def clean(self, wear: WearModel) -> bool:
        """Whether the wear model has every point of the island wiped with its margin."""
        return bool(np.all(wear.removed[self.island] >= wear.margin))

    def wiped(self, wear: WearModel) -> bool:
        """Whether the stroke may end before its path does: the wear model calls the island wiped (a pass back over
        a small island is needed only until the first pass's worst-wiped points, at its ends, have their margin;
        the rest of it would slide over what the model calls clean). A slide to another island runs to its end."""
        return not self.transfer_only and self.clean(wear)

    def next_pass(self, step_m: float) -> bool:
        """Back over the island once more (from the end the pad is at); False after :data:`MAX_PASSES`."""
        if self.passes >= MAX_PASSES:
            return False
        line, _ = surface_line(self.path.cloud, self.path.tree, self.b, self.a, step_m)
        self.path.extend(line)
        self.a, self.b = self.b, self.a
        self.passes += 1
        return True


def plan_stroke(cloud: SurfaceCloud, tree: cKDTree, wear: WearModel, island_point_m: np.ndarray,
                from_m: np.ndarray, pad_radius_m: float, step_m: float,
                transfer_from_m: np.ndarray | None = None) -> IslandStroke | None:
    """A stroke through the island of dirt at ``island_point_m`` (3,) [m], or None when that island is not
    smaller than the pad (the explorer covers it) and there is no transfer.

    The island is the dirt the wear model calls dirty within two pad radii of ``island_point_m``; it is small
    when it lies within half a pad radius of its centroid. The pass runs through the centroid along the
    surface, in the direction from ``from_m`` towards it, half a pad radius plus the island's spread beyond
    each side (:data:`STROKE_OVERRUN_RADII`). With ``transfer_from_m`` (the pad's position,
    in contact) the stroke starts there and slides to the pass's start, or to ``island_point_m`` for an
    island the explorer covers (a transfer only: ``island`` is empty); None when that line leaves the
    surface.
    """
    pts = cloud.points
    near = np.linalg.norm(pts - np.asarray(island_point_m, dtype=float), axis=1) <= 2.0 * pad_radius_m
    island = np.flatnonzero(near & wear.dirty())
    small = False
    if island.size:
        centre = pts[island].mean(axis=0)
        spread = float(np.max(np.linalg.norm(pts[island] - centre, axis=1)))
        small = spread <= 0.5 * pad_radius_m
    if small:
        k = int(tree.query(centre)[1])
        normal = cloud.normals[k]
        centre = pts[k]
        d = centre - np.asarray(from_m, dtype=float)
        d -= (d @ normal) * normal
        if np.linalg.norm(d) < 1e-6:  # straight above it: any tangent will do
            d = np.cross(normal, [0.0, 1.0, 0.0] if abs(normal[0]) > 0.9 else [1.0, 0.0, 0.0])
        d /= np.linalg.norm(d)
        half = STROKE_OVERRUN_RADII * pad_radius_m + spread
        line, _ = surface_line(cloud, tree, centre - half * d, centre + half * d, step_m)
    elif transfer_from_m is None:
        return None
    else:
        island = np.zeros(0, dtype=int)
        line = np.asarray(island_point_m, dtype=float).reshape(1, 3)
    a, b = line[0], line[-1]
    if transfer_from_m is not None:
        lead, gap = surface_line(cloud, tree, transfer_from_m, a, step_m)
        if gap > MAX_LINE_GAP_M:
            return None
        line = np.concatenate([lead, line[1:]])
    return IslandStroke(WaypointPath(cloud, line, step_m, tree=tree), island, a, b,
                        transfer=transfer_from_m is not None)
