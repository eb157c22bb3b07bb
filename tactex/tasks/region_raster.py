"""A plane-slicer raster over the dirty region of a cloud: the tool path an integrator would program.

It follows the plane slicer of ROS-Industrial's Noether tool-path planner: parallel cutting planes
``line_spacing_m`` apart intersected with the region to clean, each intersection a line segment, the
segments walked in snake order. This is tactex's own code, written after Noether's description, not
Noether. The region and the choices made on it:

- The region is the dirt (target > 0) dilated by the pad radius: the surface points the pad's centre
  may have to visit. It is split into islands (connected through points less than ``link_factor`` ×
  the cloud's spacing apart); dirt less than two pad radii apart is one island.
- Each island is rastered on its own, in its own tangent frame (the plane across its mean normal, axes
  its principal axes). Its lines run along candidate directions (the principal axes and every
  ``angle_step_deg`` between them), as many as it takes to be at most ``line_spacing_m`` apart across the
  island's dirt, the outer ones at most half a spacing inside its edge. A line is the island's points
  within a spacing of its cutting plane, one per spacing along the line, moved onto the plane; it breaks
  where the island leaves the plane (an arm of an X, a hole). Each dirty point is assigned to the
  nearest line point, and each segment runs from the first to the last of its points that some dirty
  point is assigned to (the pad's centre passes over every dirty point's projection on its line), and
  on by ``overrun_m`` (default: the pad radius) past them within the island, so that the pad passes
  wholly over the last dirty points too: a line stopping over them would wipe them for half the pad's
  length, and an island smaller than the pad for a fraction of it.
- The direction kept is the one with the shortest path (segments, slides and flights between them, a
  flight counted with its climb and descent), the fewest turns (changes of line) breaking ties within
  :data:`TIE_TOLERANCE`, among the directions whose lines pass within the pad radius of every dirty
  point: on a strongly bent island (a half cylinder) cutting planes across the bend lie farther apart on
  the surface where it turns away from them, and leave strips out of reach.
- Islands are visited greedily, the nearest entry first (an island's raster may be walked from either
  end and either way round). Consecutive segments are joined by a slide on the surface when their ends
  lie at most ``gap_m`` apart and the straight line between them stays on the captured surface, else
  by a lift-off, a flight ``clearance_m`` above the surface and a touch-down.

Frames: the cloud's (the robot base frame for a capture); every length in metres.
"""

from __future__ import annotations

from itertools import pairwise
from typing import NamedTuple

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from tactex.ergodic.relocation import air_length
from tactex.errors import ConfigError, ExplorationError, InputError
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.tasks.stroke import MAX_LINE_GAP_M, surface_line

__all__ = [
    "TIE_TOLERANCE",
    "WAYPOINT_LINE",
    "WAYPOINT_SLIDE",
    "WAYPOINT_TOUCH_DOWN",
    "RegionRasterPlan",
    "dirty_islands",
    "path_distance",
    "plan_region_raster",
    "spacing_from_overlap",
]

#: Waypoint kinds (:attr:`RegionRasterPlan.kind`): on a raster line (the pad cleans there) ...
WAYPOINT_LINE = 0
#: ... on a slide in contact from the previous segment's end to the next segment's start ...
WAYPOINT_SLIDE = 1
#: ... or reached through the air from the previous waypoint (a lift-off there, a touch-down here).
WAYPOINT_TOUCH_DOWN = 2
#: Paths whose lengths differ by less than this share count as equally long; the fewer turns wins [-].
TIE_TOLERANCE = 0.01
#: A line breaks where consecutive line points lie farther apart than this many cloud spacings [-].
BREAK_SPACINGS = 3.0


class RegionRasterPlan(NamedTuple):
    """A raster over the dirty region (cloud frame).

    Attributes:
        waypoints: (M, 3) [m] on the surface, in the order to follow them.
        normals: (M, 3) unit outward normals there.
        kind: (M,) int8, :data:`WAYPOINT_LINE`, :data:`WAYPOINT_SLIDE` or :data:`WAYPOINT_TOUCH_DOWN` (the
            first waypoint is a touch-down: the tool comes from elsewhere).
        segment: (M,) the index of each waypoint's line segment in walking order (−1 on a slide, and at the
            start point of a plan made ``from_start``).
        surface_length_m: the path in contact (lines and slides) [m].
        air_length_m: the flights between lift-off and touch-down, ``clearance_m`` above both [m].
        turns: changes of line within the islands [-].
        lift_offs: flights between the first and the last waypoint [-].
        directions: (I, 3) unit line direction of each island, in the order the islands are visited.
        angles_deg: (I,) that direction's angle from the island's first principal axis [deg].
        islands: (I,) cloud indices of the dirty points of each island, in the same order.
        line_spacing_m: the lines' spacing [m].
        uncovered: dirty points no line passes within the pad radius of (0 but on an island bent so strongly
            that no candidate direction reaches all of it) [-].
    """

    waypoints: np.ndarray
    normals: np.ndarray
    kind: np.ndarray
    segment: np.ndarray
    surface_length_m: float
    air_length_m: float
    turns: int
    lift_offs: int
    directions: np.ndarray
    angles_deg: np.ndarray
    islands: tuple[np.ndarray, ...]
    line_spacing_m: float
    uncovered: int

    @property
    def lift_off(self) -> np.ndarray:
        """(M,) bool: True where the waypoint is reached through the air from the one before."""
        return self.kind == WAYPOINT_TOUCH_DOWN


class _Segment(NamedTuple):
    points: np.ndarray  # (m, 3) [m] on the cutting plane, in walking order
    normals: np.ndarray  # (m, 3)
    line: int  # index of its cutting plane within the island


def spacing_from_overlap(pad_width_m: float, overlap: float) -> float:
    """The line spacing [m] at which a pad ``pad_width_m`` [m] wide overlaps its neighbouring line by
    ``overlap`` [-] (0 ≤ overlap < 1) of its width: width × (1 − overlap)."""
    if not (np.isfinite(pad_width_m) and pad_width_m > 0):
        raise ConfigError(f"the pad's effective width must be > 0 m, got {pad_width_m!r}")
    if not (np.isfinite(overlap) and 0.0 <= overlap < 1.0):
        raise ConfigError(f"the lines' overlap must lie in [0, 1) of the pad's width, got {overlap!r}")
    return float(pad_width_m * (1.0 - overlap))


def dirty_islands(cloud: SurfaceCloud, pad_radius_m: float, link_factor: float = 1.5) -> list[np.ndarray]:
    """The dirty region's islands: cloud indices of the points within ``pad_radius_m`` [m] of dirt
    (target > 0), one array per island (points less than ``link_factor`` × the cloud spacing apart joined),
    islands without dirt dropped, the largest first."""
    dirty = np.flatnonzero(cloud.target > 0)
    if dirty.size == 0:
        return []
    dist, _ = cKDTree(cloud.points[dirty]).query(cloud.points, distance_upper_bound=pad_radius_m * (1 + 1e-9))
    region = np.flatnonzero(np.isfinite(dist))
    pairs = cKDTree(cloud.points[region]).query_pairs(link_factor * cloud.spacing, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])) if len(pairs) else
                       (np.zeros(0), (np.zeros(0, dtype=int), np.zeros(0, dtype=int))),
                       shape=(len(region), len(region)))
    n, label = connected_components(graph, directed=False)
    islands = [region[label == k] for k in range(n)]
    islands = [isl for isl in islands if np.any(cloud.target[isl] > 0)]
    return sorted(islands, key=len, reverse=True)


def _island_frame(points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Centre (3,) [m], first and second principal axes in the island's tangent plane and its mean normal."""
    centre = points.mean(axis=0)
    n = normals.mean(axis=0)
    if np.linalg.norm(n) < 1e-6:  # a closed surface's normals cancel: the least-spread axis instead
        n = np.linalg.svd(points - centre, full_matrices=True)[2][-1]
    n = n / np.linalg.norm(n)
    flat = (points - centre) - np.outer((points - centre) @ n, n)
    helper = [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0]
    e1 = np.cross(n, helper)
    if len(points) >= 2 and np.ptp(flat, axis=0).max() > 0:
        e1 = np.linalg.svd(flat, full_matrices=False)[2][0]
        e1 = e1 - (e1 @ n) * n
    e1 = e1 / np.linalg.norm(e1)
    return centre, e1, np.cross(n, e1), n


def _slices(points: np.ndarray, normals: np.ndarray, dirty_xyz: np.ndarray, t: np.ndarray, d: np.ndarray,
            centre: np.ndarray, spacing_m: float, h: float, overrun_m: float,
            min_segment_m: float = 0.0) -> list[_Segment]:
    """The island's line segments for lines along ``t`` spaced along ``d`` (3,) each, forward along ``t``,
    trimmed to the dirt assigned to them (see the module's description); those shorter than ``min_segment_m`` [m]
    dropped."""
    v_dirt = (dirty_xyz - centre) @ d
    v0, v1 = float(v_dirt.min()), float(v_dirt.max())
    n_lines = max(int(np.ceil((v1 - v0) / spacing_m - 1e-9)), 1)
    offsets = v0 + (np.arange(n_lines) + 0.5) * (v1 - v0) / n_lines
    rel = points - centre
    u_all, v_all = rel @ t, rel @ d
    raw: list[tuple[np.ndarray, np.ndarray, int]] = []
    for k, c in enumerate(offsets):
        near = np.flatnonzero(np.abs(v_all - c) <= h)
        if near.size == 0:
            continue
        bins = np.floor(u_all[near] / h).astype(np.int64)
        order = np.lexsort((np.abs(v_all[near] - c), bins))  # per bin, the point nearest the plane first
        first = np.concatenate([[True], bins[order][1:] != bins[order][:-1]])
        pick = near[order[first]]  # ascending along t
        on_plane = points[pick] - np.outer(v_all[pick] - c, d)
        gaps = np.linalg.norm(np.diff(on_plane, axis=0), axis=1) > BREAK_SPACINGS * h
        for part in np.split(np.arange(pick.size), np.flatnonzero(gaps) + 1):
            raw.append((on_plane[part], normals[pick[part]], k))
    if not raw:
        return []
    owner = np.concatenate([np.full(len(p), i) for i, (p, _, _) in enumerate(raw)])
    index = np.concatenate([np.arange(len(p)) for p, _, _ in raw])
    nearest = cKDTree(np.concatenate([p for p, _, _ in raw])).query(dirty_xyz)[1]
    segments = []
    for i, (p, nrm, k) in enumerate(raw):
        hit = index[nearest[owner[nearest] == i]]
        if hit.size:
            # the line runs overrun_m past its outermost assigned dirt, as far as the island goes
            along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
            a = int(np.searchsorted(along, along[hit.min()] - overrun_m - 1e-12, side="left"))
            b = int(np.searchsorted(along, along[hit.max()] + overrun_m + 1e-12, side="right")) - 1
            if along[b] - along[a] >= min_segment_m:
                segments.append(_Segment(p[a:b + 1], nrm[a:b + 1], k))
    return segments


def _snake(segments: list[_Segment], flip_first: bool, gap_m: float = np.inf,
           clearance_m: float = 0.0) -> tuple[list[_Segment], float, int]:
    """The segments in snake order (the first line forward along its direction, unless ``flip_first``; each next
    line the other way), the path's length through them [m] and its turns. The moves between segments count
    straight, those longer than ``gap_m`` [m] as flights ``clearance_m`` [m] high."""
    lines = sorted({s.line for s in segments})
    out: list[_Segment] = []
    for j, k in enumerate(lines):
        row = [s for s in segments if s.line == k]
        if (j % 2 == 1) != flip_first:
            row = [_Segment(s.points[::-1], s.normals[::-1], s.line) for s in row[::-1]]
        out.extend(row)
    length = sum(float(np.linalg.norm(np.diff(s.points, axis=0), axis=1).sum()) for s in out)
    moves = np.array([float(np.linalg.norm(b.points[0] - a.points[-1])) for a, b in pairwise(out)])
    length += float(moves.sum()) + 2.0 * clearance_m * int(np.count_nonzero(moves > gap_m))
    return out, length, max(len(lines) - 1, 0)


def _raster_island(cloud: SurfaceCloud, island: np.ndarray, spacing_m: float, angle_step_deg: float, gap_m: float,
                   clearance_m: float, reach_m: float, overrun_m: float,
                   min_segment_m: float = 0.0) -> tuple[list[_Segment], np.ndarray, float, int]:
    """The island's raster along the candidate direction with the shortest path (fewest turns on a tie) among
    those whose lines pass within ``reach_m`` [m] of every dirty point (if none does, those that leave the fewest
    out): its segments (each forward along the line direction), that direction (3,), its angle from the first
    principal axis [deg] and how many dirty points it leaves out of reach."""
    pts, nrm = cloud.points[island], cloud.normals[island]
    dirty_xyz = pts[cloud.target[island] > 0]
    centre, e1, e2, n = _island_frame(pts, nrm)
    angles = np.unique(np.concatenate([np.arange(0.0, 180.0 - 1e-9, angle_step_deg), [90.0]]))
    results = []
    for ang in angles:
        a = np.radians(ang)
        t = np.cos(a) * e1 + np.sin(a) * e2
        segs = _slices(pts, nrm, dirty_xyz, t, np.cross(n, t), centre, spacing_m, cloud.spacing, overrun_m,
                       min_segment_m)
        if segs:
            _, length, turns = _snake(segs, False, gap_m, clearance_m)
            # on a strongly bent island the cutting planes lie farther apart on the surface where it turns away
            # from them: such a direction drops strips
            missed = int(np.count_nonzero(_lines_distance(segs, dirty_xyz, cloud.spacing) > reach_m))
            results.append((missed, length, turns, ang, t, segs))
    if not results:  # every segment shorter than min_segment_m (with 0, every dirty point lies near some line)
        if min_segment_m > 0.0:
            return [], e1, 0.0, len(dirty_xyz)
        raise ExplorationError("no raster line crosses an island of dirt; check the cloud's spacing")
    fewest_missed = min(r[0] for r in results)
    results = [r for r in results if r[0] == fewest_missed]
    shortest = min(r[1] for r in results)
    tied = [r for r in results if r[1] <= shortest * (1.0 + TIE_TOLERANCE)]
    best = min(tied, key=lambda r: (r[2], r[1]))
    return best[5], best[4], float(best[3]), fewest_missed


def _lines_distance(segments: list[_Segment], query_m: np.ndarray, h: float) -> np.ndarray:
    """Distance [m] from each point ``query_m`` (Q, 3) to the nearest segment (sampled every half spacing ``h``)."""
    samples = np.concatenate([_sampled(s.points, h / 2) for s in segments])
    return cKDTree(samples).query(query_m)[0]


def _sampled(points: np.ndarray, step_m: float) -> np.ndarray:
    """The polyline through ``points`` (m, 3) [m] sampled every ``step_m`` [m] or closer, its vertices included."""
    if len(points) < 2:
        return points
    seg = np.diff(points, axis=0)
    n = np.maximum(np.ceil(np.linalg.norm(seg, axis=1) / step_m).astype(int), 1)
    start = np.repeat(points[:-1], n, axis=0)
    frac = np.concatenate([np.arange(k) / k for k in n])
    return np.concatenate([start + frac[:, None] * np.repeat(seg, n, axis=0), points[-1:]])


def _variants(segments: list[_Segment]) -> list[list[_Segment]]:
    """The island's raster (its segments forward along the line direction) in snake order, walked from either
    end, either way round."""
    forward, _, _ = _snake(segments, False)
    flipped, _, _ = _snake(segments, True)

    def backwards(segs: list[_Segment]) -> list[_Segment]:
        return [_Segment(s.points[::-1], s.normals[::-1], s.line) for s in segs[::-1]]

    return [forward, backwards(forward), flipped, backwards(flipped)]


def _number(name: str, value: object) -> float:
    try:
        return float(value)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{name} must be a number, got {value!r}") from exc


def _check(cloud: SurfaceCloud, pad_radius_m: float, line_spacing_m: float, gap_m: float, angle_step_deg: float,
           clearance_m: float, link_factor: float, start_m: np.ndarray | None, from_start: bool,
           overrun_m: float, min_segment_m: float) -> None:
    if not isinstance(cloud, SurfaceCloud):
        raise InputError(f"the region raster plans on a SurfaceCloud, got {type(cloud).__name__}")
    if cloud.normals is None:
        raise InputError("the region raster needs a cloud with normals: estimate them first")
    r, s = _number("pad_radius_m", pad_radius_m), _number("line_spacing_m", line_spacing_m)
    if not (np.isfinite(r) and r > 0):
        raise ConfigError(f"pad_radius_m must be > 0 m, got {pad_radius_m!r}")
    if not (np.isfinite(s) and 0 < s <= 2.0 * r):
        raise ConfigError(f"line_spacing_m must lie in (0, 2 × pad radius = {2.0 * r:g}] m (farther apart, "
                          f"strips between the lines stay out of the pad's reach), got {line_spacing_m!r}")
    limits = (("gap_m", gap_m, 0.0, np.inf, "the longest slide between segments, ≥ 0 m"),
              ("angle_step_deg", angle_step_deg, 1e-9, 90.0, "in (0, 90] degrees"),
              ("clearance_m", clearance_m, 0.0, np.inf, "the flights' height, ≥ 0 m"),
              ("link_factor", link_factor, 1e-9, np.inf, "cloud spacings, > 0"),
              ("overrun_m", overrun_m, 0.0, np.inf, "the lines' run past the dirt, ≥ 0 m"),
              ("min_segment_m", min_segment_m, 0.0, np.inf, "the shortest segment kept, ≥ 0 m"))
    for name, value, low, high, what in limits:
        v = _number(name, value)
        if not (np.isfinite(v) and low <= v <= high):
            raise ConfigError(f"{name} ({what}) is out of range: got {value!r}")
    if start_m is not None:
        x0 = np.asarray(start_m, dtype=float)
        if x0.shape != (3,) or not np.isfinite(x0).all():
            raise InputError(f"start_m must be a finite point (3,) [m], got {start_m!r}")
    elif from_start:
        raise InputError("from_start needs start_m, the point (3,) [m] the plan begins at")
    if not np.any(cloud.target > 0):
        raise ExplorationError("the cloud's target holds no dirt (every value is 0): nothing to raster; "
                               "set one with SurfaceCloud.with_target or check the capture")


def plan_region_raster(cloud: SurfaceCloud, pad_radius_m: float, line_spacing_m: float, gap_m: float, *,
                       start_m: np.ndarray | None = None, from_start: bool = False, angle_step_deg: float = 15.0,
                       link_factor: float = 1.5, clearance_m: float = 0.02,
                       overrun_m: float | None = None, min_segment_m: float | None = None) -> RegionRasterPlan:
    """The raster over ``cloud``'s dirt (see the module's description).

    Args:
        cloud: the surface with normals and its dirt as target (N,) ≥ 0 (cloud frame, [m]).
        pad_radius_m: the pad's radius [m]: the dirt's dilation, and the reach the lines' spacing must keep.
        line_spacing_m: distance between neighbouring lines [m], at most twice the pad radius
            (:func:`spacing_from_overlap` from the pad's effective width and an overlap).
        gap_m: the longest move between two segments made as a slide in contact [m]; longer ones fly.
        start_m: where the tool is (3,) [m]: the islands are visited from there (default: the centre of the
            largest island).
        from_start: begin the plan at ``start_m`` itself, joined to the first segment like any two segments.
        angle_step_deg: step between the candidate line directions [deg].
        link_factor: points of the region less than this × the cloud spacing apart are one island [-].
        clearance_m: height of a flight above its lift-off and touch-down points [m].
        overrun_m: how far each line runs on past the outermost dirt it covers [m], within the island (which
            reaches a pad radius beyond the dirt); default: the pad radius, so that every dirty point passes
            under the pad's whole length, as in a raster over the whole dilated region. At 0 the pad's centre
            stops over the last dirty point, which passes under half of it, and an island shorter than the pad
            under a fraction.
        min_segment_m: segments shorter than this are dropped [m], as Noether's plane slicer drops segments under
            its ``min_segment_size``: a sliver of the region (a rim the capture sees from outside, a strip between
            holes) would cost a touch-down and a lift-off for a few millimetres of wiping; the dirt only such a
            segment reached counts in ``uncovered``, and the camera's next look decides whether it matters.
            Default: the pad radius.
    """
    overrun_m = pad_radius_m if overrun_m is None else overrun_m
    min_segment_m = pad_radius_m if min_segment_m is None else min_segment_m
    _check(cloud, pad_radius_m, line_spacing_m, gap_m, angle_step_deg, clearance_m, link_factor, start_m, from_start,
           overrun_m, min_segment_m)
    islands = dirty_islands(cloud, pad_radius_m, link_factor)
    rasters = [_raster_island(cloud, isl, line_spacing_m, angle_step_deg, gap_m, clearance_m, pad_radius_m, overrun_m,
                              min_segment_m) for isl in islands]
    if not any(r[0] for r in rasters):  # all slivers: rastered all the same rather than not at all
        rasters = [_raster_island(cloud, isl, line_spacing_m, angle_step_deg, gap_m, clearance_m, pad_radius_m,
                                  overrun_m) for isl in islands]
    kept = [i for i, r in enumerate(rasters) if r[0]]
    dropped = sum(r[3] for r in rasters if not r[0])
    islands, rasters = [islands[i] for i in kept], [rasters[i] for i in kept]
    here = cloud.points[islands[0]].mean(axis=0) if start_m is None else np.asarray(start_m, dtype=float)
    pending = list(range(len(islands)))
    order: list[int] = []
    walk: list[_Segment] = []
    turns = 0
    while pending:  # greedy: the nearest entry of an island not yet visited
        options = [(float(np.linalg.norm(v[0].points[0] - here)), i, v)
                   for i in pending for v in _variants(rasters[i][0])]
        _, i, segs = min(options, key=lambda o: o[0])
        pending.remove(i)
        order.append(i)
        walk.extend(segs)
        turns += len({s.line for s in segs}) - 1
        here = segs[-1].points[-1]
    if from_start:
        tree = cKDTree(cloud.points)
        x0 = np.asarray(start_m, dtype=float)
        walk.insert(0, _Segment(x0[None], cloud.normals[int(tree.query(x0)[1])][None], -1))
    pts, nrm, kind, segment = _join(cloud, walk, gap_m, from_start)
    steps = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    flying = kind[1:] == WAYPOINT_TOUCH_DOWN
    air = sum(air_length(pts[j], nrm[j], pts[j + 1], nrm[j + 1], clearance_m) for j in np.flatnonzero(flying))
    return RegionRasterPlan(
        waypoints=pts, normals=nrm, kind=kind, segment=segment, surface_length_m=float(steps[~flying].sum()),
        air_length_m=float(air), turns=int(turns), lift_offs=int(flying.sum()),
        directions=np.array([rasters[i][1] for i in order]).reshape(-1, 3),
        angles_deg=np.array([rasters[i][2] for i in order]),
        islands=tuple(islands[i][cloud.target[islands[i]] > 0] for i in order), line_spacing_m=float(line_spacing_m),
        uncovered=int(sum(r[3] for r in rasters) + dropped))


def _join(cloud: SurfaceCloud, walk: list[_Segment], gap_m: float,
          from_start: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The segments' points, normals, kinds and segment indices joined into one path: a slide on the surface
    between two segments whose ends lie at most ``gap_m`` [m] apart (and whose straight line stays on the
    captured surface), else a touch-down at the next segment's start. With ``from_start`` the first segment is
    the start point, no line."""
    tree = cKDTree(cloud.points)
    off_surface = max(MAX_LINE_GAP_M, cloud.spacing)
    pts, nrm, kind = [walk[0].points], [walk[0].normals], [np.full(len(walk[0].points), WAYPOINT_LINE, np.int8)]
    kind[0][0] = WAYPOINT_TOUCH_DOWN
    first = -1 if from_start else 0
    segment = [np.full(len(walk[0].points), first)]
    for j, (a, b) in enumerate(pairwise(walk), start=first + 1):
        end, start = a.points[-1], b.points[0]
        seg_kind = np.full(len(b.points), WAYPOINT_LINE, np.int8)
        gap = float(np.linalg.norm(start - end))
        if gap <= gap_m:
            line, leaves = surface_line(cloud, tree, end, start, cloud.spacing)
            if leaves <= off_surface:
                mid = line[1:-1]
                pts.append(mid)
                nrm.append(cloud.normals[tree.query(mid)[1]].reshape(-1, 3))
                kind.append(np.full(len(mid), WAYPOINT_SLIDE, np.int8))
                segment.append(np.full(len(mid), -1))
            else:
                seg_kind[0] = WAYPOINT_TOUCH_DOWN
        else:
            seg_kind[0] = WAYPOINT_TOUCH_DOWN
        pts.append(b.points)
        nrm.append(b.normals)
        kind.append(seg_kind)
        segment.append(np.full(len(b.points), j))
    return np.concatenate(pts), np.concatenate(nrm), np.concatenate(kind), np.concatenate(segment)


def path_distance(waypoints: np.ndarray, query_m: np.ndarray, kind: np.ndarray | None = None,
                  step_m: float = 0.5e-3) -> np.ndarray:
    """Distance [m] from each point ``query_m`` (Q, 3) to the path through ``waypoints`` (M, 3) [m] (the straight
    pieces between them sampled every ``step_m``; with ``kind``, the flights to touch-downs left out)."""
    wp = np.asarray(waypoints, dtype=float).reshape(-1, 3)
    cuts = [] if kind is None else np.flatnonzero(np.asarray(kind)[1:] == WAYPOINT_TOUCH_DOWN) + 1
    samples = np.concatenate([_sampled(part, step_m) for part in np.split(wp, cuts)])
    return cKDTree(samples).query(np.asarray(query_m, dtype=float).reshape(-1, 3))[0]
