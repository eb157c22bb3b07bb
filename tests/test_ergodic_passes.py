"""Ring passes of the sweep (tactex.ergodic.passes) and the explorer walking them."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

import tactex.ergodic.guidance as guidance_module
import tactex.ergodic.pass_planner as planner_module
import tactex.ergodic.passes as passes_module
from tactex.ergodic import HedacConfig, HedacExplorer
from tactex.ergodic.passes import SPACING_SHARES, RingPasses
from tactex.errors import ConfigError
from tactex.pointcloud import SurfaceCloud, voxel_down_sample
from tactex.spectral import build_basis

H = 0.003


def _grid(nx: int, ny: int) -> np.ndarray:
    u, v = np.meshgrid(np.arange(nx) * H, np.arange(ny) * H)
    return np.c_[u.ravel(), v.ravel(), np.zeros(u.size)]


def _flat_target(pts: np.ndarray) -> SurfaceCloud:
    """``pts`` (N, 3) on z = 0 as a cloud facing +z, every point target, spaced H."""
    return SurfaceCloud(pts, normals=np.tile([0.0, 0.0, 1.0], (len(pts), 1)), target=np.ones(len(pts)), spacing=H)


def test_waypoints_lie_on_the_middle_lines_of_rings_of_surface_distance_from_the_start():
    pts = _grid(41, 41)
    w = 4.5 * H
    passes = RingPasses(pts, None, pass_spacing_m=w, reach_m=H, voxel_m=H, origin="start")
    start = 20 * 41 + 20  # the centre
    passes.lay(start)
    assert passes.spacing_m[0] in {share * w for share in SPACING_SHARES}
    w = passes.spacing_m[0]  # the spacing the plan chose
    way = np.flatnonzero(passes.ring >= 0)
    assert way.size > 0 and passes.pending[way].all()
    r = np.linalg.norm(pts[way] - pts[start], axis=1)
    k = passes.ring[way]
    # On a plane the surface distance is the Euclidean one; the graph distance overestimates it by < 9 % on a
    # grid with diagonal links (the smoothing pulls it back a little), and the waypoints lie on d = (k + ½) w
    # within half a voxel. Away from the edges and the start (where the smoothing rounds the distance's cone tip
    # off: ring 0 is a disc):
    inner = (r < 0.045) & (k >= 1)
    assert inner.sum() > 20
    r, k = r[inner], k[inner]
    assert np.all(r <= (k + 0.5) * w + 0.5 * H + 1e-9)
    assert np.all(r >= 0.85 * (k + 0.5) * w - 0.5 * H)
    assert set(np.unique(k)) == set(range(1, int(k.max()) + 1))  # no ring skipped
    passes.reset()
    assert not passes.pending.any() and (passes.ring < 0).all()


def test_rings_from_the_edge_run_parallel_to_it_and_a_closed_surface_falls_back_to_the_start():
    pts = _grid(41, 41)
    w = 4.5 * H
    passes = RingPasses(pts, None, pass_spacing_m=w, reach_m=H, voxel_m=H)
    assert passes.origin == "edge"
    passes.lay(0)
    w = passes.spacing_m[0]
    way = np.flatnonzero(passes.ring >= 0)
    to_edge = np.min(np.c_[pts[way, :2], 40 * H - pts[way, :2]], axis=1)  # distance to the square's edge
    k = passes.ring[way]
    inner = (k >= 1) & (to_edge < 0.045)
    # the first pass runs half a spacing in from the edge (its footprint reaches the edge), the next ones a spacing
    # further each (the smoothing bends them a little near the corners)
    assert np.median(np.abs(to_edge[k == 0] - 0.5 * w)) <= H
    assert np.median(np.abs(to_edge[inner] - (k[inner] + 0.5) * w)) <= H
    # a sphere has no edge: its rings start from the start
    rng = np.random.default_rng(0)
    dense = rng.normal(size=(200_000, 3))
    dense *= 0.05 / np.linalg.norm(dense, axis=1)[:, None]
    ball = voxel_down_sample(SurfaceCloud(dense), H).points
    closed = RingPasses(ball, None, pass_spacing_m=w, reach_m=H, voxel_m=H)
    assert closed._outer_edge(np.arange(len(ball))).size == 0  # a few scattered edge-like points are no edge
    closed.lay(0)
    d0 = np.linalg.norm(ball[closed.ring >= 0] - ball[0], axis=1)
    assert np.all(d0[closed.ring[closed.ring >= 0] == 0] < 1.5 * w)
    with pytest.raises(ValueError, match="origin"):
        RingPasses(pts, None, pass_spacing_m=w, reach_m=H, voxel_m=H, origin="middle")


def test_the_next_goal_is_on_the_lowest_pending_ring_and_a_given_up_goal_is_done(monkeypatch):
    monkeypatch.setattr(planner_module, "SPACING_SHARES", (1.0,))  # the rings at w: ring 0 is more than the start
    pts = _grid(41, 41)
    w = 4.5 * H
    passes = RingPasses(pts, None, pass_spacing_m=w, reach_m=H, voxel_m=H, origin="start")
    start = 20 * 41 + 20
    goal = passes.waypoint(pts[start], start)
    j = passes.nearest(goal)
    assert passes.ring[j] == 0
    for _ in range(400):  # walk the goals, marking each: ring 0 is done before any waypoint of ring 2 is taken
        g = passes.waypoint(pts[j], j)
        if g is None:
            break
        j = passes.nearest(g)
        if passes.ring[j] == 2:
            assert not (passes.pending & (passes.ring == 0)).any()
        passes.mark(g)
    assert not passes.pending.any()
    passes.reset()
    g = passes.waypoint(pts[start], start)
    jg = passes.nearest(g)
    passes.drop_goal(abandon=True)
    assert not passes.pending[jg]
    assert passes.pending.any()


def test_links_longer_than_two_voxels_are_not_walked():
    a = _grid(10, 10)
    b = _grid(10, 10) + np.array([10 * H + 3 * H, 0.0, 0.0])  # a 4-voxel gap between the two patches
    pts = np.vstack([a, b])
    passes = RingPasses(pts, None, pass_spacing_m=4.5 * H, reach_m=H, voxel_m=H)
    assert passes.n_parts == 2
    passes.lay(0)
    assert (passes.ring[:100] >= 0).any() and (passes.ring[100:] < 0).all()  # rings are laid per part


def test_sweep_pass_spacing_is_checked():
    with pytest.raises(ConfigError, match="sweep_pass_spacing"):
        HedacConfig(sweep_pass_spacing=2.5)
    with pytest.raises(ConfigError, match="sweep_pass_spacing"):
        HedacConfig(sweep_pass_spacing=-1.0)
    HedacConfig(sweep_pass_spacing=0.0)
    with pytest.raises(ConfigError, match="sweep_pass_origin"):
        HedacConfig(sweep_pass_origin="centre")


def _path_to_goal(ex: HedacExplorer, x0: np.ndarray, goal: float = 0.05, limit_m: float = 4.0) -> float:
    ex.reset(x0)
    while ex.total_path_length < limit_m:
        ex.step()
        if ex.step_count % 10 == 0 and ex.coverage_residual() <= goal:
            return ex.total_path_length
    return np.inf


def test_the_passes_cover_a_square_close_to_the_ideal_path_and_sooner_than_the_potential_alone():
    pts = _grid(40, 40)
    cloud = _flat_target(pts)
    basis = build_basis(cloud, n_eigen=60, n_neighbors=30, cache=False)
    planned = HedacExplorer(cloud, basis, HedacConfig(n_eigen=60))
    alone = HedacExplorer(cloud, basis, HedacConfig(n_eigen=60, sweep_pass_spacing=0.0))
    assert planned._passes is not None and alone._passes is None
    ideal = len(pts) * H**2 / (2.0 * planned.config.agent_radius_m)
    x0 = pts[15 * 40 + 22]
    with_passes = _path_to_goal(planned, x0)
    without = _path_to_goal(alone, x0)
    # a 12 cm square at r_a = 7.5 mm: its edges and corners (a quarter of the path) cost a lot against the ideal
    assert with_passes <= 1.9 * ideal
    assert with_passes < without


def _holed_square() -> np.ndarray:
    """A 40 × 40 grid with four 4 × 4 holes: the rings break into arcs."""
    pts = _grid(40, 40)
    ij = np.round(pts[:, :2] / H).astype(int)
    hole = np.zeros(len(pts), dtype=bool)
    for ci, cj in ((10, 10), (10, 28), (28, 10), (28, 28)):
        hole |= (np.abs(ij[:, 0] - ci) <= 2) & (np.abs(ij[:, 1] - cj) <= 2)
    return pts[~hole]


def test_each_arc_is_walked_along_itself_and_a_closed_ring_is_one_arc(monkeypatch):
    # the rings' own arcs (a clean-up waypoint at a corner is a detour that splits the loop it leaves from)
    monkeypatch.setattr(planner_module, "CLEAN_UP", 0.0)
    pts = _grid(41, 41)
    passes = RingPasses(pts, None, pass_spacing_m=4.5 * H, reach_m=H, voxel_m=H)
    assert passes.order == "tour"
    passes.lay(0)
    tour, arc = passes._tour[0], passes._arc[0]
    assert np.array_equal(np.sort(tour), np.flatnonzero(passes.pending))  # every waypoint once
    # rings from the square's edge are closed square loops: one arc each, walked round without a jump
    rings = passes.ring[tour]
    for a in np.unique(arc):
        assert np.unique(rings[arc == a]).size == 1
    assert np.unique(arc).size == np.unique(rings).size
    step = np.linalg.norm(np.diff(pts[tour], axis=0), axis=1)
    inside = arc[1:] == arc[:-1]
    assert step[inside].max() <= 2.0 * H + 1e-9
    with pytest.raises(ValueError, match="order"):
        RingPasses(pts, None, pass_spacing_m=4.5 * H, reach_m=H, voxel_m=H, order="random")


def _walk_length(passes: RingPasses, pts: np.ndarray, start: int) -> float:
    """Path of an agent that jumps to each goal in turn (the passes' own order, no dynamics)."""
    x, length = pts[start], 0.0
    for _ in range(5000):
        g = passes.waypoint(x, passes.nearest(x))
        if g is None:
            return length
        length += float(np.linalg.norm(g - x))
        x = g
        passes.mark(x)
    raise AssertionError("the goals did not run out")


def test_the_tour_over_the_arcs_is_shorter_than_the_greedy_order(monkeypatch):
    monkeypatch.setattr(planner_module, "SPACING_SHARES", (1.0,))  # the orders compared on the same rings ...
    monkeypatch.setattr(planner_module, "CLEAN_UP", 0.0)  # ... and waypoints (the greedy order has no clean-up)
    pts = _holed_square()
    start = int(np.argmin(np.linalg.norm(pts - pts.mean(axis=0), axis=1)))
    lengths = {}
    for order in ("tour", "greedy"):
        passes = RingPasses(pts, None, pass_spacing_m=4.5 * H, reach_m=H, voxel_m=H, order=order, origin="start")
        lengths[order] = _walk_length(passes, pts, start)
        assert not passes.pending.any()
    # the holes cut the rings into arcs: greedy nearest goes back over covered ground between them
    assert lengths["tour"] < 0.9 * lengths["greedy"]


def _hairpin() -> tuple[np.ndarray, list[np.ndarray]]:
    """A 40 × 20 sheet folded back over itself (the upper sheet 4 voxels above the lower, joined by a half
    cylinder at x = 39 H: 12 mm apart in the air, ~25 cm apart along the surface at x = 3 H), and as arcs the
    columns x = 3, 13, 23, 33 (× H) of each sheet, each ordered along y."""
    sheet = _grid(40, 20)
    gap = 4 * H
    theta = np.deg2rad(np.arange(-60, 61, 30))
    y = np.arange(20) * H
    fold = np.array([(39 * H + 0.5 * gap * np.cos(t), yy, 0.5 * gap * (1.0 + np.sin(t))) for t in theta for yy in y])
    pts = np.vstack([sheet, sheet + np.array([0.0, 0.0, gap]), fold])
    arcs = []
    for z in (0.0, gap):
        for i in (3, 13, 23, 33):
            col = np.flatnonzero(np.isclose(pts[:, 0], i * H) & np.isclose(pts[:, 2], z))
            arcs.append(col[np.argsort(pts[col, 1])])
    return pts, arcs


def test_the_tour_over_the_arcs_goes_by_surface_distance_not_across_a_fold():
    pts, arcs = _hairpin()
    passes = RingPasses(pts, None, pass_spacing_m=4.5 * H, reach_m=H, voxel_m=H)
    assert passes.n_parts == 1  # the sheets are joined round the fold only (12 mm apart: no link across)
    x0 = pts[arcs[0][0]]
    walk = passes._tour_of([a.copy() for a in arcs], x0)
    # every arc once, whole, along itself
    assert np.array_equal(np.sort(np.concatenate(walk)), np.sort(np.concatenate(arcs)))
    for a in walk:
        assert any(np.array_equal(a, b) or np.array_equal(a, b[::-1]) for b in arcs)
    # the lower sheet's arcs first, then round the fold and the upper sheet's, instead of across the gap and back

    def surface_jumps(seq: list[np.ndarray]) -> float:
        d = dijkstra(passes._graph, directed=False, indices=[a[-1] for a in seq[:-1]])
        return float(sum(d[k, b[0]] for k, b in enumerate(seq[1:])))

    assert [bool(pts[a[0], 2] > 0) for a in walk] == [False] * 4 + [True] * 4
    # nearest neighbour by the chord between the arcs' ends goes up across the gap first, a walk round the fold
    here, left, chord = x0, list(range(len(arcs))), []
    while left:
        k, rev = min(((i, r) for i in left for r in (False, True)),
                     key=lambda c: np.linalg.norm(pts[arcs[c[0]][-1 if c[1] else 0]] - here))
        chord.append(arcs[k][::-1] if rev else arcs[k])
        left.remove(k)
        here = pts[chord[-1][-1]]
    assert pts[chord[1][0], 2] > 0
    assert surface_jumps(walk) < 0.5 * surface_jumps(chord)


def test_a_guided_agent_that_stalls_hops_to_the_next_waypoint_of_its_tour():
    pts = _grid(40, 40)
    cloud = _flat_target(pts)
    basis = build_basis(cloud, n_eigen=40, n_neighbors=30, cache=False)
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=40))
    ex.reset(pts[15 * 40 + 22])
    for _ in range(30):
        ex.step()
    passes = ex._passes
    stalled_on = passes._goal
    assert stalled_on >= 0
    cmd = ex._relocate(0, "stall")
    assert cmd is not None and cmd.reason == "stall"
    assert not passes.pending[stalled_on]  # given up
    nxt = passes.next_pending(ex._tpos[ex._near[0]])
    assert passes.pending[nxt] and np.allclose(cmd.point, pts[ex._tidx[nxt]])  # the plan goes on from there
    assert not passes._replan


def _plate_and_speck():
    plate = _grid(25, 25)
    speck = np.array([[-6 * H, 12 * H, 0.0], [-6 * H, 13 * H, 0.0], [-7 * H, 12 * H, 0.0]])
    pts = np.vstack([plate, speck])
    cloud = _flat_target(pts)
    return pts, speck, cloud, build_basis(cloud, n_eigen=40, n_neighbors=30, cache=False)


def test_a_speck_across_a_gap_the_agent_may_not_walk_or_hop_is_reached_by_relocating():
    """A few scan points 6 voxels off a plate's edge: one Laplacian part with the plate (their neighbours are plate
    points), but a gap no walk crosses, and beyond the footprint from the edge. With hops switched off, once the rest
    is done the agent lifts off and touches down there."""
    pts, speck, cloud, basis = _plate_and_speck()
    assert basis.n_components == 1
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=40, max_bridge_voxels=0.0))
    assert ex._passes.n_parts == 2
    ex.reset(pts[12 * 25 + 12])
    while ex.untouched_count() > 0 and ex.total_path_length < 3.0:
        ex.step()
    assert ex.untouched_count() == 0
    landed = [np.linalg.norm(speck - r.point, axis=1).min() for r in ex.relocations]
    assert ex.relocations and min(landed) < H


def test_the_hunt_hops_to_a_speck_across_a_gap_the_laplacian_spans_instead_of_lifting_off():
    """The same speck with hops (max_bridge_voxels 6, the default): the Laplacian's links across the gap are hops,
    and the hunt walks to the plate's edge, slides across in contact and touches the speck: no relocation."""
    pts, speck, cloud, basis = _plate_and_speck()
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=40))
    assert ex._gaps.n_links > 0
    ex.reset(pts[12 * 25 + 12])
    hops = []
    while ex.untouched_count() > 0 and ex.total_path_length < 3.0:
        ex.step()
        if ex.hopping():
            hops.append(ex._bridges[0])
    assert ex.untouched_count() == 0
    assert not ex.relocations
    assert hops and ex.bridges_taken >= 1
    ends = np.array([b.end for b in hops])
    assert np.linalg.norm(ends[:, None] - speck[None], axis=2).min() < 1e-12  # it landed on a speck point
    starts = np.array([b.start for b in hops])
    assert np.all(starts[:, 0] >= -1.5 * H)  # from the plate's edge (x = 0), not from the middle of the gap


def test_a_strip_narrower_than_the_first_ring_is_walked_in_one_pass():
    # A strip 4 points (9 mm) wide, every point on its edge: no ring's middle line and no ridge, so no pass is laid
    # and the hunt walks it nearest first, which along a strip is one pass. (Rings from the start would cross it
    # back and forth: 0.73 m against 0.50 m to residual 0.05 on the bench's 12 x 300 mm strip.)
    pts = _grid(100, 4)
    cloud = _flat_target(pts)
    r_a = 0.0075
    ex = HedacExplorer(cloud, build_basis(cloud, n_eigen=20, n_neighbors=30, cache=False),
                       HedacConfig(agent_radius_m=r_a, n_eigen=20))
    ex.reset(pts[0])
    ex._passes.lay(0)
    assert not (ex._passes.ring >= 0).any()
    ideal = len(pts) * H * H / (2 * r_a)
    while ex.untouched_count() and ex.total_path_length < 3.0 * ideal:
        ex.step()
    assert ex.untouched_count() == 0
    assert ex.total_path_length < 1.5 * 99 * H  # about the strip's length: one pass


def test_the_tighter_spacing_is_kept_where_the_full_one_leaves_islands_at_the_footprints_edge():
    # On the built-in bowl (steep rim, a middle the innermost ring misses) the full spacing leaves points beyond
    # AT_RISK footprint radii of every waypoint in many islands, each a detour of the hunt later; the tighter plan
    # is longer but leaves far fewer. On a flat square the full spacing stays.
    from tactex.pointcloud.shapes import get_surface

    cloud = get_surface("bowl").sample(H)
    cloud = cloud.with_target(np.ones(len(cloud)))
    r_a = 0.0075
    ex = HedacExplorer(cloud, build_basis(cloud, n_eigen=20, n_neighbors=30, cache=False),
                       HedacConfig(agent_radius_m=r_a, n_eigen=20))
    passes = ex._passes
    part = int(np.bincount(passes.parts).argmax())
    members = np.flatnonzero(passes.parts == part)
    passes.lay(int(members[0]))
    w = HedacConfig().sweep_pass_spacing * r_a
    assert passes.spacing_m[part] == pytest.approx(SPACING_SHARES[1] * w)
    kept = np.flatnonzero(passes.ring >= 0)
    gap_kept = np.min(np.linalg.norm(passes._points[members][:, None] - passes._points[kept][None], axis=2), axis=1)
    assert np.count_nonzero(gap_kept > passes_module.AT_RISK * r_a) < 40
    square = RingPasses(_grid(40, 40), None, pass_spacing_m=w, reach_m=H, voxel_m=H, footprint_m=r_a)
    square.lay(0)
    assert square.spacing_m[0] == pytest.approx(w)


def test_the_hunt_goes_to_the_nearest_untouched_point_along_the_surface_and_reaches_specks_across_a_gap():
    # A U: two legs 3 voxels wide, 4 voxels apart (no walking link across), joined at x = 30..32 voxels.
    leg_a = _grid(33, 3)
    leg_b = leg_a + np.array([0.0, 7 * H, 0.0])
    bridge = _grid(3, 4) + np.array([30 * H, 3 * H, 0.0])
    speck = np.array([[5 * H, -4 * H, 0.0]])  # 4 voxels off leg A's edge: its own walking part
    pts = np.vstack([leg_a, leg_b, bridge, speck])
    passes = RingPasses(pts, None, pass_spacing_m=4.5 * H, reach_m=H, voxel_m=H)
    here = 0  # leg A at x = 0
    across = len(leg_a)  # leg B at x = 0: 7 voxels away in a straight line, ~70 along the surface
    along = 15  # leg A at x = 15 voxels
    cand = np.zeros(len(pts), dtype=bool)
    cand[[across, along]] = True
    assert passes.closest(here, cand) == along
    only_speck = np.zeros(len(pts), dtype=bool)
    only_speck[-1] = True
    assert passes.closest(here, only_speck) == -1  # not on the walking part, no touch allowed
    assert not passes.touchable(here, only_speck, 2.5 * H)
    assert passes.touchable(here, only_speck, 5.0 * H)
    g = passes.closest(here, only_speck, touch_m=5.0 * H)
    assert g == len(pts) - 1
    # the agent steers along leg A first, to the point the speck is reached from, then at the speck
    x = pts[here]
    for _ in range(200):
        aim = passes.route(x, g)
        if np.array_equal(aim, pts[g]):
            break
        assert abs(aim[1]) <= 2 * H + 1e-12  # on leg A
        x = x + (aim - x) * min(1.0, H / max(float(np.linalg.norm(aim - x)), 1e-12))
    else:
        raise AssertionError("the route never turned to the speck")
    assert np.linalg.norm(x - pts[g]) <= 5.0 * H


def test_the_hunt_reaches_points_over_hops_and_hops_at_the_near_end_of_the_first_one():
    # Three squares in a row, 5 voxels apart (no walking link across): A - B - C, hops A4-B0 and B4-C0 only.
    a, b, c = _grid(5, 5), _grid(5, 5) + np.array([9 * H, 0.0, 0.0]), _grid(5, 5) + np.array([18 * H, 0.0, 0.0])
    pts = np.vstack([a, b, c])
    hop_pairs = [(2 * 5 + 4, 25 + 2 * 5 + 0), (25 + 2 * 5 + 4, 50 + 2 * 5 + 0)]  # middle rows, facing edges
    rows, cols = zip(*hop_pairs, strict=True)
    hops = coo_matrix((np.ones(2), (rows, cols)), shape=(len(pts), len(pts)))
    without = RingPasses(pts, None, pass_spacing_m=4.5 * H, reach_m=H, voxel_m=H)
    passes = RingPasses(pts, None, pass_spacing_m=4.5 * H, reach_m=H, voxel_m=H, hops=hops)
    assert passes.n_parts == 3  # hops join parts for the hunt, not for the passes
    in_c = np.zeros(len(pts), dtype=bool)
    in_c[50:] = True
    assert without.closest(0, in_c) == -1 and not without.touchable(0, in_c, 0.0)
    assert passes.touchable(0, in_c, 0.0)
    g = passes.closest(0, in_c)
    assert g == 50 + 2 * 5 + 0  # C's point nearest over A, the hop, B and the second hop
    # on the way: first to the near end of the first hop (A's edge), and only there the hop is due, to B
    x = pts[0]
    assert passes.hop_due(x) == -1
    for _ in range(50):
        aim = passes.route(x, g)
        hop = passes.hop_due(x)
        if hop >= 0:
            break
        x = x + (aim - x) * min(1.0, H / max(float(np.linalg.norm(aim - x)), 1e-12))
    else:
        raise AssertionError("the hop never came due")
    assert hop == hop_pairs[0][1]
    assert np.linalg.norm(x - pts[hop_pairs[0][0]]) <= passes_module.HOP_REACH * H + 1e-12
    # from B's side the next closest() leads to the second hop
    assert passes.closest(hop, in_c) == g and passes.hop_due(pts[hop_pairs[1][0]]) == hop_pairs[1][1]


def test_missed_points_are_those_no_pending_waypoint_covers_on_the_agents_part():
    pts = np.vstack([_grid(30, 30), _grid(3, 3) + np.array([40 * H, 0.0, 0.0])])  # a square and a speck 10 voxels off
    passes = RingPasses(pts, None, pass_spacing_m=4.5 * H, reach_m=H, voxel_m=H, footprint_m=2.5 * H)
    passes.lay(0)
    way = np.flatnonzero(passes.pending)
    x = pts[15 * 30 + 15]
    every = np.ones(len(pts), dtype=bool)
    near = np.linalg.norm(pts - x, axis=1) <= 5.0 * H
    # while the passes are pending every point lies within a footprint radius of one: nothing is missed
    assert passes.missed(x, 15 * 30 + 15, every, 5.0 * H).size == 0
    passes.pending[way] = False  # the passes walked past
    got = passes.missed(x, 15 * 30 + 15, every, 5.0 * H)
    assert set(got.tolist()) == set(np.flatnonzero(near).tolist())
    d = np.linalg.norm(pts[got] - x, axis=1)
    assert np.all(np.diff(d) >= 0)  # nearest first
    # not a candidate (touched), or on another part: not missed
    some = every.copy()
    some[got[0]] = False
    assert got[0] not in passes.missed(x, 15 * 30 + 15, some, 5.0 * H)
    assert passes.missed(pts[-1], 15 * 30 + 15, every, 5.0 * H).size == 0
    # one pending waypoint covers the points within a footprint radius of it
    w = int(way[np.argmin(np.linalg.norm(pts[way] - x, axis=1))])
    passes.pending[w] = True
    left = passes.missed(x, 15 * 30 + 15, every, 5.0 * H)
    assert np.all(np.linalg.norm(pts[left] - pts[w], axis=1) > 2.5 * H)


def test_on_a_pass_the_agent_steps_aside_to_a_point_the_passes_missed_and_gives_up_one_it_cannot_touch():
    pts = _grid(40, 40)
    cloud = _flat_target(pts)
    basis = build_basis(cloud, n_eigen=40, n_neighbors=30, cache=False)
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=40))
    ex.reset(pts[20 * 40 + 20])
    passes = ex._passes
    here = ex.positions[0]
    near = int(ex._tpos[ex._near[0]])
    r_a = ex.config.agent_radius_m
    assert passes.waypoint(here, near) is not None  # laid, on a pass
    # everything touched but point j, 1.5 footprint radii off; a pending waypoint within r_a of j covers it later
    dist = np.linalg.norm(pts - here, axis=1)
    j = int(np.argmin(np.abs(dist - 1.5 * r_a)))
    ex._cov[ex._tidx] = 2.0 * ex._p_t.max()
    ex._cov[ex._tidx[j]] = 0.0
    passes.pending[:] = False
    w = int(np.argmin(np.where(passes.ring >= 0, np.linalg.norm(pts - pts[j], axis=1), np.inf)))
    assert np.linalg.norm(pts[w] - pts[j]) <= r_a
    passes.pending[w] = True
    assert ex._missed(here, near) is None
    # the passes walked past it: the agent steers at it
    passes.pending[w] = False
    aims = [ex._missed(here, near) for _ in range(guidance_module.REPAIR_STEPS)]
    assert all(a is not None and np.allclose(a, pts[j]) for a in aims)
    # still untouched after REPAIR_STEPS looks (across a fold, off an edge): left to the hunt, not given up
    assert ex._missed(here, near) is None
    assert not ex._given_up[j]
    # out of REPAIR_RADIUS: not a step aside
    ex.reset(pts[20 * 40 + 20])
    far = int(np.argmin(np.abs(dist - (guidance_module.REPAIR_RADIUS + 0.5) * r_a)))
    ex._cov[ex._tidx] = 2.0 * ex._p_t.max()
    ex._cov[ex._tidx[far]] = 0.0
    passes.waypoint(here, near)
    passes.pending[:] = False
    assert ex._missed(here, near) is None


def test_the_steps_aside_cover_a_square_on_a_shorter_path_than_the_hunt_alone():
    pts = _grid(40, 40)
    cloud = _flat_target(pts)
    basis = build_basis(cloud, n_eigen=40, n_neighbors=30, cache=False)

    def run(radius: float) -> tuple[float, int]:
        guidance_module.REPAIR_RADIUS = radius
        ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=40))
        ex.reset(pts[7 * 40 + 31])
        while ex.untouched_count() and ex.path_length < 2.0:
            ex.step()
        return ex.path_length, ex.untouched_count()

    keep = guidance_module.REPAIR_RADIUS
    try:
        off, on = run(0.0), run(keep)
    finally:
        guidance_module.REPAIR_RADIUS = keep
    assert on[1] == 0 and off[1] == 0
    # the steps aside cost a fraction of a footprint each; the hunt comes back for each point from afar (measured
    # 1.23 m with them, 1.53 m without)
    assert on[0] < 0.9 * off[0]


def test_a_stall_in_the_hunt_touches_down_where_the_hops_reach_before_a_part_they_do_not():
    """Plate A between square B (3 voxels off its right edge: hops) and square C (10 voxels off its left edge: no
    link). With A done and the agent stalled at A's left edge, C is the nearer untouched target, but the stall
    lands on B: the hops' side is finished before a flight to a part they do not reach (the one flight left)."""
    a = _grid(20, 20)
    b = _grid(6, 6) + np.array([22 * H, 7 * H, 0.0])
    c = _grid(6, 6) + np.array([-15 * H, 7 * H, 0.0])
    pts = np.vstack([a, b, c])
    cloud = _flat_target(pts)
    ex = HedacExplorer(cloud, build_basis(cloud, n_eigen=40, n_neighbors=30, cache=False), HedacConfig(n_eigen=40))
    ex.reset(pts[10 * 20])  # A's left edge
    passes = ex._passes
    t_a = np.arange(400)
    t_b, t_c = np.arange(400, 436), np.arange(436, 472)
    every = np.ones(len(pts), dtype=bool)
    side = passes.reach_mask(int(t_a[0]), every)
    assert side[t_b].all() and not side[t_c].any()
    ex._cov[ex._tidx[t_a]] = 2.0 * ex._p_t[t_a]  # A covered
    passes.pending[:] = False
    cmd = ex._relocate(0, "stall")
    assert cmd is not None and cmd.reason == "stall"
    lands = int(np.argmin(np.linalg.norm(pts - cmd.point, axis=1)))
    assert lands in set(ex._tidx[t_b].tolist())
    # with nothing left on the hops' side the stall flies to C
    ex._cov[ex._tidx[t_b]] = 2.0 * ex._p_t[t_b]
    ex._x[0] = pts[10 * 20]
    ex._near[0] = 10 * 20
    cmd = ex._relocate(0, "stall")
    assert int(np.argmin(np.linalg.norm(pts - cmd.point, axis=1))) in set(ex._tidx[t_c].tolist())


def test_the_plan_covers_the_sliver_where_the_rings_from_the_edge_meet(monkeypatch):
    """A strip 36 mm wide: the rings from its edges meet along its middle line (the medial axis), where the first
    ring's middle lines lie 1.7 footprint radii away and the second ring has no middle line. The plan's clean-up
    waypoints cover that sliver (every point within a footprint radius of a waypoint), and they are on the tour."""
    pts = _grid(60, 12)
    r_a = 0.0075

    def plan():
        passes = RingPasses(pts, None, pass_spacing_m=1.8 * r_a, reach_m=2.5 * H, voxel_m=H, footprint_m=r_a)
        passes.lay(0)
        way = np.flatnonzero(passes.pending)
        gap = np.min(np.linalg.norm(pts[:, None] - pts[way][None], axis=2), axis=1)
        return passes, way, gap

    monkeypatch.setattr(planner_module, "CLEAN_UP", 0.0)
    _, _, gap = plan()
    left = pts[gap > r_a]
    assert len(left) > 50  # the sliver the rings leave ...
    # ... along the middle of the strip (and its medial axis's branches into the corners)
    assert np.mean(np.abs(left[:, 1] - 5.5 * H) <= 1.5 * H) > 0.7
    monkeypatch.undo()
    passes, way, gap = plan()
    assert gap.max() <= passes_module.LEFTOVER * r_a
    clean = np.fromiter(passes._clean, dtype=np.intp)
    assert clean.size > 5 and np.mean(np.abs(pts[clean, 1] - 5.5 * H) <= 1.5 * H) > 0.7
    assert set(way.tolist()) == set(passes._tour[0].tolist())  # every waypoint, the clean-up's too, on the tour


def test_a_clean_up_waypoint_whose_points_are_touched_is_skipped():
    pts = _grid(60, 12)
    r_a = 0.0075
    passes = RingPasses(pts, None, pass_spacing_m=1.8 * r_a, reach_m=2.5 * H, voxel_m=H, footprint_m=r_a)
    passes.lay(0)
    tour = passes._tour[0]
    first = next(i for i, j in enumerate(tour.tolist()) if j in passes._clean)
    passes.pending[tour[:first]] = False  # the tour walked up to the first clean-up waypoint
    passes._at[0] = first
    c = int(tour[first])
    x = pts[c] + np.array([3 * r_a, 0.0, 0.0])  # off the tour's pass: it steers at the next entry
    untouched = np.ones(len(pts), dtype=bool)
    passes.waypoint(x, 0, lambda: untouched)
    assert passes.pending[c] and passes._goal == c
    untouched[passes._clean[c]] = False  # a step aside touched what it was for
    passes.waypoint(x, 0, lambda: untouched)
    assert not passes.pending[c] and passes._goal != c


def test_on_a_pass_the_agent_touches_a_speck_it_passes_instead_of_coming_back_for_it(monkeypatch):
    """Three scan points 2.5 voxels off a square plate's edge (a part of their own the hops join to the plate): the
    first ring along that edge passes within two footprint radii of them, and the agent hops over and back then,
    before the plate's passes end; without that the hunt comes back for them at the end, on a longer path."""
    plate = _grid(25, 25)
    speck = np.array([[-2.5 * H, 12 * H, 0.0], [-2.5 * H, 13 * H, 0.0], [-3.5 * H, 12 * H, 0.0]])
    pts = np.vstack([plate, speck])
    cloud = _flat_target(pts)
    basis = build_basis(cloud, n_eigen=40, n_neighbors=30, cache=False)

    def run():
        ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=40))
        assert ex._passes.n_parts == 2
        ex.reset(pts[12 * 25 + 12])
        on = ex._tpos[np.arange(len(plate), len(pts))]
        pending = None
        while ex.untouched_count() > 0 and ex.total_path_length < 3.0:
            ex.step()
            if pending is None and not ex._untouched()[on].any():
                pending = int(ex._passes.pending.sum())
        assert ex.untouched_count() == 0 and not ex.relocations
        return pending, ex.total_path_length

    pending, path = run()
    monkeypatch.setattr(guidance_module, "SPECK_POINTS", 0.0)
    pending_off, path_off = run()
    assert pending_off == 0  # without: touched in the hunt after the passes
    assert pending > 10  # with: touched while the passes still had waypoints to walk
    assert path < 0.95 * path_off


def test_a_clean_up_waypoint_is_done_only_close_to_it_not_at_the_passes_reach():
    """The passes' waypoints are done at ``reach_m`` (the agent goes on along its pass); a clean-up waypoint's points
    lie at the footprint's edge from the passes, so it is done only within CLEAN_REACH footprint radii."""
    pts = _grid(60, 12)
    r_a = 0.0075
    passes = RingPasses(pts, None, pass_spacing_m=1.8 * r_a, reach_m=r_a, voxel_m=H, footprint_m=r_a)
    passes.lay(0)
    c = next(iter(passes._clean))
    assert passes.pending[c]
    passes.mark(pts[c] + np.array([0.0, 0.8 * r_a, 0.0]))  # within the passes' reach
    assert passes.pending[c]
    passes.mark(pts[c] + np.array([0.0, 0.9 * passes_module.CLEAN_REACH * r_a, 0.0]))
    assert not passes.pending[c]


def test_a_clean_up_waypoint_stays_the_goal_until_the_agent_is_close_to_it():
    """Walking the tour, the agent's place on it does not pass a clean-up waypoint it came within the passes'
    reach of but not within CLEAN_REACH; each clean-up waypoint is an arc of its own in either tour."""
    pts = _grid(60, 12)
    r_a = 0.0075
    passes = RingPasses(pts, None, pass_spacing_m=1.8 * r_a, reach_m=r_a, voxel_m=H, footprint_m=r_a)
    passes.lay(0)
    part = int(passes._part[0])
    tour, arc = passes._tour[part], passes._arc[part]
    centres = [int(c) for c in passes._clean]
    assert centres
    for c in centres:  # an arc of one
        assert np.count_nonzero(arc == arc[np.flatnonzero(tour == c)[0]]) == 1
    idx = np.flatnonzero(passes.pending & (passes._part == part))
    passes._plan_arcs(part, idx, pts[0])  # the nearest-neighbour tour over everything: still arcs of one
    tour_nn, arc_nn = passes._tour[part], passes._arc[part]
    for c in centres:
        assert np.count_nonzero(arc_nn == arc_nn[np.flatnonzero(tour_nn == c)[0]]) == 1
    passes._tour[part], passes._arc[part] = tour, arc
    c = centres[0]
    passes._at[part] = int(np.flatnonzero(tour == c)[0])
    x = pts[c] + np.array([0.0, 0.8 * r_a, 0.0])  # within the passes' reach, not within CLEAN_REACH
    goal = passes.waypoint(x, int(passes.nearest(x)))
    assert passes.pending[c] and np.allclose(goal, pts[c])


def test_clean_up_waypoints_lie_only_where_the_agent_may_stand():
    pts = _grid(60, 12)
    r_a = 0.0075
    free = RingPasses(pts, None, pass_spacing_m=1.8 * r_a, reach_m=r_a, voxel_m=H, footprint_m=r_a)
    free.lay(0)
    centres = pts[list(free._clean)]
    allowed = pts[:, 0] < np.median(centres[:, 0])  # half of the strip's clean-up sliver is not allowed
    held = RingPasses(pts, None, pass_spacing_m=1.8 * r_a, reach_m=r_a, voxel_m=H, footprint_m=r_a, allowed=allowed)
    held.lay(int(np.flatnonzero(allowed)[0]))
    assert held._clean and all(allowed[c] for c in held._clean)
