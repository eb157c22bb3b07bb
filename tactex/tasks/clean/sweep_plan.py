"""A planned first sweep over the captured dirt: a few long passes instead of HEDAC's first loops.

At the first touch-down the robot knows the whole view's dirt and nothing has been wiped yet, so the
first stretch in contact can be planned instead of followed step by step: a polyline of a few straight
legs on the captured surface, from the touch-down point, that the robot's own Preston wear model
(the same prediction as :class:`~tactex.tasks.wear_model.WearModel`: k_p·F/(π r²) of dirt level per
metre slid under the pad's disc) says wipes most of the view's dirt in the shortest slide. A handful of
long passes is what a person does on a mug's side; HEDAC's step-by-step gradient, started on the middle
of the marking, first loops around it. After the sweep the explorer takes over with the wear model's
view of what is left.

The polyline's corners are searched among the cloud points within a pad radius of the dirt: random
polylines, and the dirt's extreme points (a stroke's ends, an X's tips, pushed out beyond the dirt by the
slide their points need) in every order, then the best few refined by simulated annealing: corners moved, added or
dropped and runs of them reversed at random, a longer slide taken now and then, less often as the search goes on, so
that it does not stop in the first local minimum.
A leg is the chord between two corners brought onto the surface along the nearest cloud point's normal (on
a convex wall: the arc; over a concave one: its floor), raised where the pad's disc would touch the support
the object stands on. A leg whose chord runs beside the surface by more than
:data:`~tactex.tasks.stroke.MAX_LINE_GAP_M` (across a hole in the capture) is not used, nor one whose chord
runs above it by more and whose path on the surface has a step over :data:`MAX_STEP_OVER_CHORD_STEP` of the
chord's or is more than :data:`MAX_SURFACE_DETOUR` times the chord (down into a deep hollow and up again). None
when no polyline of at most ``max_corners`` legs reaches the goal: the explorer then starts from the touch-down
without a planned sweep.

The sweep is planned for the island of dirt the touch-down is on (dirt joined within two pad radii), not
for islands far apart, between which a lift-off and a flight are quicker than a slide, and only where that
island is made of strokes (:func:`stroke_like`): a few long legs then wipe it, each stroke once; a blob as
wide as the pad takes passes side by side, where the explorer's feedback does as well without a plan.

On a cloud finer than :data:`PLAN_GRID_M` the planner works on the dirt merged per cell of that grid and
samples its legs no closer than the grid: its cost then follows the dirt's area, not the cloud's density
(each leg's sample-and-dirt pairs grow with the cube of the density, the island's links with its fourth
power), and the robot holds with torque control paused while it plans. Only the polyline found is measured
on every dirty point, for the corners and the length its goal needs.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from tactex.errors import ConfigError, InputError
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.pointcloud.voxel import voxel_indices
from tactex.tasks.stroke import MAX_LINE_GAP_M

__all__ = ["MAX_CORNERS", "PLAN_GRID_M", "SweepPlan", "dirt_island", "plan_sweep", "stroke_like"]

#: Shortest leg on either side of a corner that turns back (by more than a right angle) [pad radii]: the tool
#: trails the agent and rounds each corner, so an out-and-back jiggle to a stroke's tip shorter than this does not
#: take the pad where the plan's prediction has it.
MIN_LEG_RADII = 0.8
#: Random polylines tried before refining the best [-].
N_RANDOM = 300
#: Refinement trials (a corner moved, added or dropped, or a run of corners reversed), shared by the walks [-].
N_REFINE = 1500
#: Extreme points of the dirt whose orderings seed the search besides the random polylines [-]: an X's four tips
#: and two more (at most 720 orderings of five).
N_EXTREMES = 6
#: How far the sweep's path runs past the point where the wear model reaches its goal [pad radii].
END_BEYOND_RADII = 0.5
#: A point with fewer neighbours than this share of the median count is on the cloud's edge (stroke_like) [-]:
#: within two spacings a point on a grid's straight edge has about 60 % of an interior point's, a corner 40 %.
EDGE_NEIGHBOUR_SHARE = 0.75
#: Annealed walks that refine a polyline, from the best random ones (and one more from the best ordering of the
#: dirt's extremes) [-].
N_WALKS = 3
#: A walk's temperature at its start [m of slide]: a trial this much longer than the polyline it changes is
#: taken with probability 1/e, the temperature falling linearly to zero (then only a trial no longer is taken):
#: simulated annealing. The slide's length has many local minima; a pure descent stops in the first one it meets,
#: and each of a few descents stopping in a different one makes the plan, and the time to clean, vary from one
#: seed to the next.
ANNEAL_START_M = 0.005
#: How far a corner moves in a trial at a walk's end, against its start (about one pad width) [-]: the
#: trials' spread shrinks geometrically, from moves between strokes to fine adjustments along one.
STEP_SHRINK = 0.1
#: Shares of a walk's trials that reverse a run of corners (the order the sweep visits them in), and that
#: drop a corner or add one (a leg split in two), the count kept [-]; the others move one corner. Moving one corner
#: at a time keeps the order the polyline was drawn in and its number of legs up to the goal.
REVERSE_SHARE = 0.15
RECUT_SHARE = 0.15
#: Most candidate corners (cloud points near the dirt, thinned evenly) [-].
MAX_CANDIDATES = 400
#: Most corners a sweep may have after its start [-]: the search's cost grows with them, and a longer sweep
#: is the explorer's job.
MAX_CORNERS = 20
#: Finest grid [m] the planner works on: on a finer cloud the dirt is merged per cell of this edge and the legs
#: are sampled no closer. TEC's 3 mm voxel (``tactex clean``'s default ``--voxel-size-m``): on a default cloud
#: the grid merges nothing, so the search plans on the cloud its parameters suit, and a 3 mm cell is small
#: beside the pad (a disc of 25 mm radius covers ~200 of them).
PLAN_GRID_M = 0.003


def _merged_dirt(points_m: np.ndarray, mass: np.ndarray, spacing_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The dirt (``mass`` > 0 at ``points_m``) as the planner sees it: its points (D, 3) [m], their mass (D,) and
    each dirty point's index into them (``(mass > 0).sum()``,). On a cloud of spacing ``spacing_m`` [m] finer than
    :data:`PLAN_GRID_M` one point per cell of that grid (the cell's dirty points' mass-weighted mean, with
    their mass); else the dirty points themselves."""
    dirty = np.flatnonzero(mass > 0)
    pts, m = points_m[dirty], mass[dirty]
    if spacing_m >= PLAN_GRID_M or dirty.size == 0:
        return pts, m, np.arange(dirty.size)
    cell, _ = voxel_indices(pts, PLAN_GRID_M)
    cell_mass = np.bincount(cell, weights=m)
    cell_pts = np.column_stack([np.bincount(cell, weights=m * pts[:, k]) for k in range(3)]) / cell_mass[:, None]
    return cell_pts, cell_mass, cell


@dataclass(frozen=True)
class SweepPlan:
    """A planned sweep: ``waypoints`` (M, 3) [m] on the cloud from the touch-down, ``corners`` (K, 3) [m]
    the polyline's corners (the touch-down first), ``length_m`` [m] the slide until the wear model predicts
    ``goal`` of the dirt off (the waypoints end :data:`END_BEYOND_RADII` pad radii beyond the point where it does,
    or at the last corner)."""

    waypoints: np.ndarray
    corners: np.ndarray
    length_m: float
    goal: float


#: Longest a leg's path on the surface may be against its chord, where the chord runs above the surface (across
#: a concave part: a bowl's side) [-]: a leg over a gentle hollow follows its floor; across a deep one (from one
#: side of a bowl to the other) the path dives and climbs, and a lift-off is the quicker way.
MAX_SURFACE_DETOUR = 1.3
#: Longest step of a leg's path on the surface, in steps of its chord [-]. Over a hollow of radius ρ the steps grow
#: by about ρ over the chord's distance from the hollow's centre, so this refuses a chord nearer the centre than
#: half the radius (a leg over more than 120° of a bowl's arc, whose path is 1.2 times the chord): on the bench's
#: bowl such legs turned the tool faster than it follows, and a sweep allowed them was slower to clean. It also
#: refuses a jump of the nearest surface point to another part of the cloud (across a gap).
MAX_STEP_OVER_CHORD_STEP = 2.0


def _follows_surface(ds_m: np.ndarray, chord_m: float) -> bool:
    """Whether a leg whose chord runs above the surface may slide on the surface below it: its path's steps
    ``ds_m`` [m] (one per chord sample, the chord's samples ``chord_m`` [m] / ``len(ds_m)`` apart, brought onto the
    surface) are none longer than :data:`MAX_STEP_OVER_CHORD_STEP` chord steps and add up to at most
    :data:`MAX_SURFACE_DETOUR` times the chord."""
    if ds_m.size == 0:
        return True
    step = chord_m / ds_m.size
    return bool(ds_m.max() <= MAX_STEP_OVER_CHORD_STEP * step + 1e-12 and ds_m.sum() <= MAX_SURFACE_DETOUR * chord_m)


class _Predictor:
    """Removal along a polyline, as the wear model would predict it (no margin: the dirt level removed)."""

    def __init__(self, cloud: SurfaceCloud, tree: cKDTree, target: np.ndarray, pad_radius_m: float,
                 removal_per_m: float, step_m: float, support_z_m: float | None, merged: bool = True) -> None:
        """``merged``: the dirt as the search sees it (per :data:`PLAN_GRID_M` cell on a finer cloud); False:
        every dirty point (the legs are sampled on the grid either way)."""
        self.cloud, self.tree = cloud, tree
        self.step = float(step_m) if cloud.spacing >= PLAN_GRID_M else max(float(step_m), PLAN_GRID_M)
        dirt_m, self.mass, _ = _merged_dirt(cloud.points, target, cloud.spacing if merged else np.inf)
        self.total = float(self.mass.sum())
        self.dirt_tree = cKDTree(dirt_m)
        self.radius = float(pad_radius_m)
        self.per_m = float(removal_per_m)
        self.support_z = support_z_m
        self._legs: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None] = {}

    def lowest_z(self, normals: np.ndarray) -> np.ndarray:
        """Lowest height [m] of a pad centre over points with ``normals`` (S, 3): its disc ⟂ the normal stays above
        the support plane (as the commanded line's point is raised in ``tactex clean``); -inf without a support."""
        if self.support_z is None:
            return np.full(len(normals), -np.inf)
        return self.support_z + self.radius * np.sqrt(np.clip(1.0 - normals[:, 2] ** 2, 0.0, 1.0))

    def leg(self, i: int, j: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """The leg from cloud point ``i`` to ``j``: its samples (S, 3) [m] on the surface, each sample's slide
        from the one before (S,) [m], and the (sample, dirty point) pairs under the pad as two index arrays;
        None when its chord leaves the surface."""
        key = (i, j)
        if key not in self._legs:
            pts, nrm = self.cloud.points, self.cloud.normals
            a, b = pts[i], pts[j]
            n = max(int(np.ceil(np.linalg.norm(b - a) / self.step)), 1)
            chord = a + np.linspace(0.0, 1.0, n + 1)[1:, None] * (b - a)
            _, idx = self.tree.query(chord)
            off = chord - pts[idx]
            out = np.einsum("ij,ij->i", off, nrm[idx])  # > 0: above the surface (air)
            side = np.linalg.norm(off - out[:, None] * nrm[idx], axis=1)
            # onto the surface along each nearest point's normal: a smooth line on it (the snapped points
            # themselves zigzag over the voxel grid, a longer slide for the same sweep)
            samples = chord - out[:, None] * nrm[idx]
            samples[:, 2] = np.maximum(samples[:, 2], self.lowest_z(nrm[idx]))
            ds = np.linalg.norm(np.diff(np.vstack([a, samples]), axis=0), axis=1)
            if np.any(side > MAX_LINE_GAP_M) or (np.any(np.maximum(out, 0.0) > MAX_LINE_GAP_M)
                                                  and not _follows_surface(ds, np.linalg.norm(b - a))):
                self._legs[key] = None
            else:
                under = self.dirt_tree.query_ball_point(samples, self.radius)
                counts = np.fromiter((len(u) for u in under), dtype=np.int64, count=len(under))
                s_idx = np.repeat(np.arange(len(samples)), counts)
                d_idx = np.fromiter((k for u in under for k in u), dtype=np.int64, count=int(counts.sum()))
                self._legs[key] = (samples, ds, s_idx, d_idx)
        return self._legs[key]

    def jiggles(self, corners: list[int]) -> bool:
        """Whether the polyline through the cloud points ``corners`` turns back (by more than a right angle) at a
        corner next to a leg shorter than :data:`MIN_LEG_RADII` pad radii."""
        if len(corners) < 3:
            return False
        p = self.cloud.points[corners]
        legs = np.diff(p, axis=0)
        short = np.linalg.norm(legs, axis=1) < MIN_LEG_RADII * self.radius
        back = np.einsum("ij,ij->i", legs[:-1], legs[1:]) < 0.0
        return bool(np.any(back & (short[:-1] | short[1:])))

    def length_to_goal(self, corners: list[int], goal: float) -> float:
        """Slide [m] along the polyline through the cloud points ``corners`` until ``goal`` of the dirt mass
        is predicted off; inf when it never is or a leg leaves the surface."""
        if self.jiggles(corners):
            return np.inf
        ds_all, s_all, d_all = [], [], []
        offset = 0
        for i, j in itertools.pairwise(corners):
            leg = self.leg(i, j)
            if leg is None:
                return np.inf
            _, ds, s_idx, d_idx = leg
            ds_all.append(ds)
            s_all.append(s_idx + offset)
            d_all.append(d_idx)
            offset += len(ds)
        ds = np.concatenate(ds_all)
        s_idx, d_idx = np.concatenate(s_all), np.concatenate(d_all)
        if s_idx.size == 0:
            return np.inf
        # each dirty point's exposure (metres slid over it) in path order; its level falls by per_m per metre
        # down to zero, so the mass it gives up by each sample is mass·(min(1, per_m·E) − min(1, per_m·E_before))
        order = np.lexsort((s_idx, d_idx))
        s_o, d_o = s_idx[order], d_idx[order]
        e = np.cumsum(ds[s_o])
        first = np.concatenate([[True], d_o[1:] != d_o[:-1]])
        base = np.maximum.accumulate(np.where(first, np.concatenate([[0.0], e[:-1]]), -np.inf))
        exposure = e - base
        lost = np.minimum(self.per_m * exposure, 1.0)
        gained = lost - np.where(first, 0.0, np.concatenate([[0.0], lost[:-1]]))
        removed = np.cumsum(np.bincount(s_o, weights=self.mass[d_o] * gained, minlength=len(ds)))
        hit = np.flatnonzero(removed >= goal * self.total)
        if hit.size == 0:
            return np.inf
        return float(np.cumsum(ds)[hit[0]])


def dirt_island(points_m: np.ndarray, target: np.ndarray, here_m: np.ndarray, link_m: float, *,
                spacing_m: float) -> np.ndarray:
    """The island of dirt at ``here_m`` (3,) [m]: a mask (N,) of the points ``points_m`` (N, 3) [m] with dirt
    (``target`` > 0) joined to the dirty point nearest ``here_m`` through dirty points less than ``link_m`` [m]
    apart (all False when there is no dirt). ``spacing_m`` [m]: the points' spacing; on a cloud finer than
    :data:`PLAN_GRID_M` the dirt is joined by its cells of that grid (their means less than ``link_m`` apart)."""
    pts = np.asarray(points_m, dtype=float)
    here_m = np.asarray(here_m, dtype=float)
    if here_m.shape != (3,) or not np.isfinite(here_m).all():
        raise InputError(f"here_m must be a finite point (3,) [m], got {here_m!r}")
    if not (np.isfinite(link_m) and link_m > 0):
        raise ConfigError(f"link_m must be a positive distance [m], got {link_m!r}")
    if not (np.isfinite(spacing_m) and spacing_m >= 0):
        raise ConfigError(f"spacing_m must be a distance ≥ 0 [m], got {spacing_m!r}")
    target = np.asarray(target, dtype=float)
    dirty = np.flatnonzero(target > 0)
    mask = np.zeros(len(pts), dtype=bool)
    if dirty.size == 0:
        return mask
    # each dirty point counts once in its cell's mean, whatever its level
    nodes_m, _, node = _merged_dirt(pts, (target > 0).astype(float), spacing_m)
    tree = cKDTree(nodes_m)
    pairs = tree.query_pairs(float(link_m), output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(nodes_m), len(nodes_m)))
    _, label = connected_components(graph, directed=False)
    seed = int(tree.query(here_m)[1])
    mask[dirty[label[node] == label[seed]]] = True
    return mask


def _extreme_orderings(pred: _Predictor, cloud: SurfaceCloud, near: np.ndarray, cand_tree: cKDTree, start: int,
                       n_corners: int) -> list[list[int]]:
    """Polylines from ``start`` through the dirt's extreme points in every order: a stroke's ends, an X's four
    arm tips, a letter's corners (at most :data:`N_EXTREMES`, by farthest-point sampling of the dirt), each pushed
    out beyond the dirt by the slide its point needs and moved to the nearest candidate corner of ``near`` (found
    in ``cand_tree``); the polylines have ``n_corners`` corners after the start (fewer with fewer extremes).
    Random corners rarely land near all the tips of a thin marking at once, and a sweep that misses one never
    reaches its goal."""
    dirt = pred.dirt_tree.data
    # the farthest from the start first, then farthest from the tips so far (not from the start: the dirt around a
    # touch-down on a tip is cleaned only by a leg out beyond it)
    tips = [int(np.argmax(np.linalg.norm(dirt - cloud.points[start], axis=1)))]
    far = np.full(len(dirt), np.inf)
    for _ in range(N_EXTREMES - 1):
        far = np.minimum(far, np.linalg.norm(dirt - dirt[tips[-1]], axis=1))
        if far.max() < 2.0 * pred.radius:  # the rest of the dirt is within a pad width of a tip
            break
        tips.append(int(np.argmax(far)))
    # a tip is cleaned only if the pad passes beyond it: each tip away from the dirt's middle is pushed out by
    # the slide its point needs under the pad beyond the pad's own radius (at most one more radius)
    mid = dirt.mean(axis=0)
    away = dirt[tips] - mid
    dist = np.linalg.norm(away, axis=1, keepdims=True)
    beyond = min(max(1.0 / pred.per_m - pred.radius, 0.0) + pred.step, pred.radius)
    ends = dirt[tips] + np.where(dist > 2.0 * pred.radius, beyond * away / np.maximum(dist, 1e-12), 0.0)
    corners = np.unique(near[cand_tree.query(ends)[1]])
    k = min(n_corners, len(corners))
    return [[start, *map(int, order)] for order in itertools.permutations(corners.tolist(), k)]


def stroke_like(points_m: np.ndarray, tree: cKDTree, island: np.ndarray, pad_radius_m: float,
                spacing_m: float) -> bool:
    """Whether the dirt ``island`` (N,) (bool over ``points_m`` (N, 3) [m], spaced ``spacing_m`` [m], whose KD-tree
    is ``tree``) is made of
    strokes a pad of radius ``pad_radius_m`` [m] wipes in one pass along each: 90 % of its points lie within half a
    pad radius of the clean surface around it or of the cloud's edge (a stroke along the view's edge or a hole in
    the capture is still a stroke), so a pass along a stroke's middle slides at least 1.7 pad radii of the disc over
    each of them. Then a few long legs are the quickest way (a planned sweep); over a blob as wide as the pad or
    wider, passes side by side overlap, and the explorer's feedback does as well without a plan. The work is done
    on the cloud within a pad radius of the island."""
    points_m = np.asarray(points_m, dtype=float)
    island = np.asarray(island, dtype=bool)
    if not island.any():
        return False
    lo, hi = points_m[island].min(axis=0) - pad_radius_m, points_m[island].max(axis=0) + pad_radius_m
    around = np.flatnonzero(np.all((points_m >= lo) & (points_m <= hi), axis=1))
    # the cloud's edge: points with clearly fewer neighbours within two spacings than the cloud's interior has
    counts = tree.query_ball_point(points_m[around], 2.0 * spacing_m, return_length=True)
    edge = counts < EDGE_NEIGHBOUR_SHARE * float(np.median(counts))
    clean_or_edge = ~island[around] | edge
    if not clean_or_edge.any():
        return False
    depth, _ = cKDTree(points_m[around][clean_or_edge]).query(points_m[island])
    return bool(np.percentile(depth, 90) <= 0.5 * pad_radius_m)


def _trial(walk: list[int], rng: np.random.Generator, spread_m: float, near: np.ndarray, cand_tree: cKDTree,
           points_m: np.ndarray) -> list[int]:
    """A polyline changed at random from ``walk`` (cloud point indices into ``points_m`` (N, 3) [m], the start
    first and kept): a run of corners reversed (:data:`REVERSE_SHARE` of the trials), a corner dropped and one added
    beyond the last or one added within a leg and the last dropped (:data:`RECUT_SHARE`), else one corner moved. A
    new or moved corner is the candidate of ``near`` (found in ``cand_tree``) nearest a normal draw of spread
    ``spread_m`` [m] around where it goes."""
    def land(at_m: np.ndarray) -> int:
        return int(near[cand_tree.query(at_m + rng.normal(0.0, spread_m, 3))[1]])

    k = int(rng.integers(1, len(walk)))
    trial = list(walk)
    u = rng.random() if REVERSE_SHARE + RECUT_SHARE > 0.0 else 1.0  # no draw when every trial moves a corner
    if u < REVERSE_SHARE and len(walk) > 3:
        a, b = sorted(rng.choice(np.arange(1, len(walk)), 2, replace=False))
        trial[a:b + 1] = trial[a:b + 1][::-1]
    elif u < REVERSE_SHARE + RECUT_SHARE and len(walk) > 2:
        if rng.random() < 0.5:
            del trial[k]
            trial.append(land(points_m[trial[-1]]))
        else:
            trial.insert(k, land(0.5 * (points_m[trial[k - 1]] + points_m[trial[k]])))
            trial.pop()
    else:
        trial[k] = land(points_m[walk[k]])
    return trial


def _uphill_taken(longer_m: float, temperature_m: float, rng: np.random.Generator) -> bool:
    """Whether the annealing takes a trial ``longer_m`` [m] (> 0, inf: it never reaches its goal) longer than the
    polyline it changes, at ``temperature_m`` [m]: with probability exp(−longer/temperature)."""
    if not (temperature_m > 0.0 and np.isfinite(longer_m)):
        return False
    return bool(rng.random() < np.exp(-longer_m / temperature_m))


def plan_sweep(cloud: SurfaceCloud, tree: cKDTree, target: np.ndarray, start_m: np.ndarray,
               pad_radius_m: float, removal_per_m: float, step_m: float, goal: float = 0.95,
               max_corners: int = 5, max_length_m: float = np.inf, support_z_m: float | None = None,
               seed: int = 0) -> SweepPlan | None:
    """The shortest sweep found from ``start_m`` (3,) [m] that the wear model predicts takes ``goal`` (0–1) of
    the dirt ``target`` (N,) (mass per cloud point) off, with at most ``max_corners`` corners after the start
    and no longer than ``max_length_m`` [m]; None when none does.

    ``removal_per_m`` [dirt level/m]: the level a point under the pad loses per metre slid (k_p·F/(π r²));
    ``step_m`` [m]: the spacing of the path's samples (the agent's step); ``support_z_m`` [m]: the height of the
    plane the object stands on (the pad's centre is kept high enough for its disc to clear it, as ``tactex clean``
    raises its commanded point; None: no support); ``seed``: the search's draws."""
    target = np.asarray(target, dtype=float)
    if target.shape != (len(cloud),):
        raise InputError(f"target must have shape ({len(cloud)},), got {target.shape}")
    if not (np.isfinite(target).all() and (target >= 0).all()):
        raise InputError("target must be a finite dirt mass ≥ 0 per cloud point")
    if tree.n != len(cloud):
        raise InputError(f"the KD-tree holds {tree.n} points, the cloud {len(cloud)}: build it on the cloud's points")
    start_m = np.asarray(start_m, dtype=float)
    if start_m.shape != (3,) or not np.isfinite(start_m).all():
        raise InputError(f"start_m must be a finite point (3,) [m], got {start_m!r}")
    if cloud.normals is None:
        raise InputError("a sweep is planned on a cloud with normals")
    if not (0.0 < goal < 1.0):
        raise ConfigError(f"the sweep's goal must be within (0, 1), got {goal!r}")
    if isinstance(max_corners, bool) or not isinstance(max_corners, (int, np.integer)) \
            or not 1 <= max_corners <= MAX_CORNERS:
        raise ConfigError(f"a sweep has 1–{MAX_CORNERS} corners after the start, got {max_corners!r}")
    if np.isnan(max_length_m) or max_length_m <= 0:
        raise ConfigError(f"max_length_m must be a positive length [m] (inf: no limit), got {max_length_m!r}")
    for name, v in (("pad_radius_m", pad_radius_m), ("removal_per_m", removal_per_m), ("step_m", step_m)):
        if not (np.isfinite(v) and v > 0):
            raise ConfigError(f"{name} must be a positive number, got {v!r}")
    if not np.any(target > 0):
        return None
    pred = _Predictor(cloud, tree, target, pad_radius_m, removal_per_m, step_m, support_z_m)
    start = int(tree.query(start_m)[1])
    # candidate corners: the cloud points within a pad radius of the dirt (the pad's centre may pass beside
    # a stroke of dirt) where the pad clears the support, at most MAX_CANDIDATES of them drawn at random
    dist, _ = pred.dirt_tree.query(cloud.points, distance_upper_bound=pad_radius_m)
    near = np.flatnonzero((dist <= pad_radius_m) & (cloud.points[:, 2] >= pred.lowest_z(cloud.normals)))
    if near.size == 0:
        return None
    rng = np.random.default_rng(seed)
    if near.size > MAX_CANDIDATES:
        near = np.sort(rng.choice(near, MAX_CANDIDATES, replace=False))
    cand_tree = cKDTree(cloud.points[near])
    n_corners = int(max_corners)
    drawn: list[tuple[float, list[int]]] = []
    for _ in range(N_RANDOM):
        corners = [start, *rng.choice(near, n_corners).tolist()]
        length = pred.length_to_goal(corners, goal)
        if length < np.inf:
            drawn.append((length, corners))
    drawn.sort(key=lambda d: d[0])
    ordered = [(pred.length_to_goal(c, goal), c) for c in _extreme_orderings(pred, cloud, near, cand_tree, start,
                                                                             n_corners)]
    # a few annealed refinements, from the best random polylines and the best ordering of the extremes
    starts = [*drawn[:N_WALKS], min(ordered, key=lambda d: d[0], default=(np.inf, []))]
    starts = [(length, corners) for length, corners in starts if length < np.inf]
    if not starts:
        return None
    best_len, best = min(starts, key=lambda d: d[0])
    n_trials = N_REFINE // len(starts)
    for length0, corners0 in starts:
        walk, walk_len = corners0, length0
        for n in range(n_trials):
            done = n / n_trials
            # a corner moves about a pad width at first, STEP_SHRINK of it at the end
            trial = _trial(walk, rng, 2.0 * pad_radius_m * STEP_SHRINK**done, near, cand_tree, cloud.points)
            length = pred.length_to_goal(trial, goal)
            if length <= walk_len or _uphill_taken(length - walk_len, ANNEAL_START_M * (1.0 - done), rng):
                walk, walk_len = trial, length
                if walk_len < best_len:
                    best, best_len = walk, walk_len
    if not best_len <= max_length_m:
        return None
    # the corners the goal needs (the rest of the polyline is not driven), measured on every dirty point: a
    # cell's points share one exposure in the search, which overstates the removal at the pad's rim a little
    if cloud.spacing < PLAN_GRID_M:
        pred = _Predictor(cloud, tree, target, pad_radius_m, removal_per_m, step_m, support_z_m, merged=False)
        best_len = pred.length_to_goal(best, goal)
        if not best_len <= max_length_m:
            return None
    used = [best[0]]
    for k in range(1, len(best)):
        used.append(best[k])
        if pred.length_to_goal(used, goal) < np.inf:
            break
    waypoints = [cloud.points[used[0]][None]]
    for i, j in itertools.pairwise(used):
        waypoints.append(pred.leg(i, j)[0])
    path = np.concatenate(waypoints)
    # the last leg ends where the goal is reached, plus END_BEYOND_RADII of the pad (the pad's centre trails the
    # agent, and rounds the corners): beyond, it would slide over what is already clean
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    path = path[: int(np.searchsorted(along, best_len + END_BEYOND_RADII * pad_radius_m, side="right")) + 1]
    return SweepPlan(path, cloud.points[used], float(best_len), float(goal))
