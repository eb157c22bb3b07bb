"""The pass plan and the sweep step on large parts: the limited surface distances, the compiled searches, the
2-opt scan, the sweep source's running image, and a plan laid the large way on a small part (the same
waypoints, every target point within the footprint's reach, a tour about as short as the exact one)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

import tactex.ergodic.pass_planner as planner_module
import tactex.ergodic.pass_tour as tour_module
import tactex.ergodic.sweep as sweep_module
from tactex.ergodic import compiled_graph
from tactex.ergodic.pass_tour import Distances, _first_gain, node_matrix
from tactex.ergodic.passes import LEFTOVER, RingPasses
from tactex.ergodic.sweep import SweepSource

H = 0.003


def _wavy(nx: int = 60, ny: int = 45, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.arange(nx) * H, np.arange(ny) * H)
    u = u.ravel() + rng.uniform(-0.15, 0.15, u.size) * H
    v = v.ravel() + rng.uniform(-0.15, 0.15, v.size) * H
    return np.c_[u, v, 0.01 * np.sin(u / 0.02) * np.cos(v / 0.03)]


def _graph(pts: np.ndarray):
    pairs = cKDTree(pts).query_pairs(1.8 * H, output_type="ndarray")
    length = np.linalg.norm(pts[pairs[:, 0]] - pts[pairs[:, 1]], axis=1)
    g = coo_matrix((length, (pairs[:, 0], pairs[:, 1])), shape=(len(pts), len(pts))).tocsr()
    return g.maximum(g.T), pairs, length


def test_the_limited_search_equals_scipys_within_the_limit():
    pts = _wavy()
    g, _, _ = _graph(pts)
    search = compiled_graph.limited_search(g)
    for v in (0, 700, 2000):
        exact = dijkstra(g, directed=False, indices=v)
        reached, d = search(v, 0.02)
        assert np.array_equal(np.sort(reached), np.flatnonzero(exact <= 0.02))
        assert np.array_equal(d, exact[reached])  # the same sums: bit for bit
        assert np.all(np.diff(d) >= 0.0)  # in order of distance


def test_limited_surface_distances_are_exact_near_and_a_lower_bound_beyond():
    pts = _wavy()
    g, _, _ = _graph(pts)
    limit = 0.02
    dist = Distances(pts, g, limit)
    idx = np.arange(len(pts))
    for v in (5, 1500):
        exact = dijkstra(g, directed=False, indices=v)
        got = dist.surface(v, idx)
        near = exact <= limit
        assert np.array_equal(got[near], exact[near])
        chord = np.linalg.norm(pts - pts[v], axis=1)
        assert np.allclose(got[~near], np.maximum(chord[~near], limit))
        assert np.all(got[~near] <= exact[~near])  # never more than the walk
    assert np.array_equal(Distances(pts, g).surface(5, idx), dijkstra(g, directed=False, indices=5))


@pytest.mark.parametrize("compiled", [True, False])
def test_the_small_graph_search_equals_scipys(compiled):
    pts = _wavy(30, 20)
    g, pairs, length = _graph(pts)
    small = compiled_graph.SmallGraph(len(pts), pairs[:, 0], pairs[:, 1], length, compiled=compiled)
    assert np.array_equal(small.distances(3), dijkstra(g, directed=False, indices=3))
    keep = np.flatnonzero(pts[:, 0] > 0.03)
    sub = small.sub(keep)
    assert np.array_equal(sub.distances(0), dijkstra(g[keep][:, keep], directed=False, indices=0))


def _first_gain_loop(dist, start, entry, out):
    """The 2-opt scan arc by arc (the reference the block scan must equal)."""
    n = entry.size
    before = np.r_[start, out[:-1]]
    for i in range(n - 1):
        j = np.arange(i + 1, n)
        old = dist[before[i], entry[i]]
        new = dist[before[i], out[j]]
        nxt = np.r_[entry[j[:-1] + 1], 0]
        old_after = dist[out[j], nxt]
        new_after = dist[entry[i], nxt]
        old_after[-1] = new_after[-1] = 0.0
        gain = old + old_after - new - new_after
        k = int(gain.argmax())
        if gain[k] > 1e-9:
            return i, int(j[k])
    return None


@pytest.mark.parametrize("seed", range(5))
def test_the_block_scan_of_2_opt_finds_the_move_the_arc_by_arc_scan_finds(seed):
    rng = np.random.default_rng(seed)
    n = 40
    p = rng.uniform(size=(2 * n + 1, 2))
    dist = np.linalg.norm(p[:, None] - p[None], axis=2)
    perm = rng.permutation(2 * n) + 1
    entry, out = perm[:n], perm[n:]
    assert _first_gain(dist, 0, entry, out) == _first_gain_loop(dist, 0, entry, out)
    assert _first_gain(dist, 0, entry, out, block_elements=1) == _first_gain_loop(dist, 0, entry, out)  # a row a block
    order = np.argsort(p[1:, 0])  # an already good tour: no move, or the same one
    entry, out = order[0::2][:n] + 1, order[1::2][:n] + 1
    assert _first_gain(dist, 0, entry, out) == _first_gain_loop(dist, 0, entry, out)


def test_a_plan_laid_the_large_way_has_the_same_waypoints_covers_the_part_and_a_tour_as_short(monkeypatch):
    pts = _wavy(70, 50)
    start = len(pts) // 3

    def lay() -> RingPasses:
        passes = RingPasses(pts, None, pass_spacing_m=4.5 * H, reach_m=H, voxel_m=H, footprint_m=2.5 * H)
        passes.lay(start)
        return passes

    exact = lay()
    monkeypatch.setattr(planner_module, "EXACT_POINTS", 100)  # this part counts as large
    large = lay()
    assert np.array_equal(np.sort(large._tour[0]), np.sort(exact._tour[0])) or (
        abs(large._tour[0].size - exact._tour[0].size) <= 0.02 * exact._tour[0].size)
    # every target point within the footprint's reach of a waypoint (what the clean-up guarantees)
    gap = cKDTree(pts[large._tour[0]]).query(pts)[0]
    assert gap.max() <= LEFTOVER * large.footprint_m + 1e-12
    assert large._tour_length(0) <= 1.1 * exact._tour_length(0)


def test_the_sweep_sources_running_image_equals_the_full_one(monkeypatch):
    pts = _wavy(40, 30)
    rng = np.random.default_rng(1)
    rows = rng.normal(size=(len(pts), 12))
    p = np.full(len(pts), 1.0 / len(pts))
    full = SweepSource(pts, p, 2 * H, 3 * H, 0.02, image_rows=rows)
    monkeypatch.setattr(sweep_module, "INCREMENTAL_POINTS", 0)
    run = SweepSource(pts, p, 2 * H, 3 * H, 0.02, image_rows=rows)
    assert run.incremental and not full.incremental
    s_full, s_run = np.empty(len(pts)), np.empty(len(pts))
    for k in range(300):
        x = pts[(37 * k) % len(pts)]
        full.mark(x)
        run.mark(x)
        if k % 100 == 99:
            run.rebuild()
        a, b = full.image(s_full), run.image(s_run)
        assert np.allclose(run.at(np.arange(len(pts))), s_full, rtol=1e-12, atol=1e-15)
        assert run.at(np.array([-1]))[0] == 0.0  # off the target
        assert np.allclose(b, a, rtol=1e-9, atol=1e-12)
    assert np.array_equal(run.done, full.done)


def test_the_node_matrix_equals_the_rows_it_stands_for():
    pts = _wavy()
    g, _, _ = _graph(pts)
    dist = Distances(pts, g, 0.02)
    nodes = np.arange(0, len(pts), 37)
    for along, way in ((False, dist.chord), (True, dist.surface)):
        rows = np.array([way(int(v), nodes) for v in nodes])
        assert np.allclose(node_matrix(nodes, dist, along), rows, rtol=1e-15, atol=0.0)


def test_an_explorer_with_the_running_image_walks_as_the_one_without(monkeypatch):
    from tactex.ergodic import HedacConfig, HedacExplorer
    from tactex.pointcloud import SurfaceCloud
    from tactex.spectral import build_basis

    pts = _wavy(30, 24)
    cloud = SurfaceCloud(pts, target=np.ones(len(pts)), spacing=H)
    basis = build_basis(cloud, n_eigen=30, cache=False)
    runs = {}
    for name, limit in (("full", 10**9), ("running", 0)):
        monkeypatch.setattr(sweep_module, "INCREMENTAL_POINTS", limit)
        ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=30, compiled=False))
        assert ex._sweep.incremental == (name == "running")
        ex.reset(pts[len(pts) // 3])
        runs[name] = (np.array([ex.step().point for _ in range(150)]), ex.potential, ex.source)
    (p0, u0, s0), (p1, u1, s1) = runs["full"], runs["running"]
    assert np.allclose(s1, s0, rtol=1e-9, atol=1e-15)
    assert np.allclose(u1, u0, rtol=1e-6, atol=1e-9)
    # the passes steer: round-off in the potential leaves the path where it is
    assert np.abs(p1 - p0).max() < 1e-6


def test_the_compiled_ring_orders_equal_the_python_ones(monkeypatch):
    pytest.importorskip("numba")
    monkeypatch.setattr(planner_module, "EXACT_POINTS", 100)  # this part counts as large
    pts = _wavy(70, 50)
    arcs = {}
    for compiled in (True, False):
        passes = RingPasses(pts, None, pass_spacing_m=4.5 * H, reach_m=H, voxel_m=H, origin="start")
        passes.compiled_arcs = compiled
        passes.lay(len(pts) // 3)
        idx = np.flatnonzero(passes.pending)
        arcs[compiled] = passes._arcs(idx)
    assert len(arcs[True]) == len(arcs[False]) > 10
    assert any(a.size > 2 * 16 for a in arcs[True])  # loops and long runs among them
    for a, b in zip(arcs[True], arcs[False], strict=True):
        assert np.array_equal(a, b)


def _two_opt_reference(walk, start, dist, at):
    """2-opt with the arc-by-arc scan over every arc each pass (what two_opt must equal)."""
    for _ in range(tour_module.TWO_OPT_PASSES):
        entry = np.array([at[int(a[0])] for a in walk])
        out = np.array([at[int(a[-1])] for a in walk])
        move = _first_gain_loop(dist, at[start], entry, out)
        if move is None:
            break
        i, j = move
        walk[i:j + 1] = [a[::-1] for a in walk[i:j + 1][::-1]]
    return walk


@pytest.mark.parametrize("seed", range(4))
def test_two_opt_with_its_known_rows_equals_the_full_scan(seed):
    rng = np.random.default_rng(seed)
    p = rng.uniform(size=(121, 3))
    arcs = [np.array([1 + 2 * k, 2 + 2 * k]) for k in range(60)]
    chord = lambda v, idx: np.linalg.norm(p[idx] - p[v], axis=1)  # noqa: E731
    nodes = np.arange(121)
    dist = np.array([chord(v, nodes) for v in nodes])
    at = {v: v for v in range(121)}
    got = tour_module.two_opt([a.copy() for a in arcs], 0, chord)
    want = _two_opt_reference([a.copy() for a in arcs], 0, dist, at)
    assert all(np.array_equal(a, b) for a, b in zip(got, want, strict=True))


def test_the_explorers_metrics_equal_the_metrics_modules():
    from tactex.ergodic import HedacConfig, HedacExplorer
    from tactex.ergodic.metrics import coverage_residual, normalized_ergodicity
    from tactex.pointcloud import SurfaceCloud
    from tactex.spectral import build_basis

    pts = _wavy(30, 24)
    rng = np.random.default_rng(3)
    cloud = SurfaceCloud(pts, target=rng.uniform(0.0, 2.0, len(pts)) * (rng.uniform(size=len(pts)) > 0.3), spacing=H)
    basis = build_basis(cloud, n_eigen=30, cache=False)
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=30))
    ex.reset(pts[len(pts) // 2])
    for k in range(60):
        if k:
            ex.step()
        for normalize in ("l2", "integral"):
            want = normalized_ergodicity(ex.target, ex.coverage, ex._mass, normalize)
            assert ex.ergodicity(normalize) == pytest.approx(want, rel=1e-12, abs=1e-15)  # other sums' round-off
        assert ex.coverage_residual() == pytest.approx(coverage_residual(ex.target, ex.coverage), rel=1e-12, abs=1e-15)
    with pytest.raises(Exception, match="normalize"):
        ex.ergodicity("max")


def test_the_explorers_metrics_are_exactly_one_before_any_coverage():
    from tactex.ergodic import HedacConfig, HedacExplorer
    from tactex.pointcloud import SurfaceCloud
    from tactex.spectral import build_basis

    pts = _wavy(30, 24)
    rng = np.random.default_rng(4)
    cloud = SurfaceCloud(pts, target=rng.uniform(0.1, 2.0, len(pts)), spacing=H)
    ex = HedacExplorer(cloud, build_basis(cloud, n_eigen=30, cache=False), HedacConfig(n_eigen=30))
    ex.reset(pts[0])
    assert ex.coverage_residual() == 1.0
    assert ex.ergodicity() == 1.0
