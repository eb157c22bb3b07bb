"""The sweep source for whole-surface targets (tactex.ergodic.sweep) and its choice by the explorer."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.ergodic import HedacConfig, HedacExplorer
from tactex.ergodic.sweep import SweepSource, uniform_whole_target
from tactex.errors import ConfigError
from tactex.pointcloud import SurfaceCloud
from tactex.spectral import build_basis

H = 0.003


def _grid(nx: int, ny: int) -> np.ndarray:
    u, v = np.meshgrid(np.arange(nx) * H, np.arange(ny) * H)
    return np.c_[u.ravel(), v.ravel(), np.zeros(u.size)]


def _explorer(target: np.ndarray, pts: np.ndarray, **cfg) -> HedacExplorer:
    cloud = SurfaceCloud(pts, normals=np.tile([0.0, 0.0, 1.0], (len(pts), 1)), target=target, spacing=H)
    basis = build_basis(cloud, n_eigen=60, n_neighbors=30, cache=False)
    return HedacExplorer(cloud, basis, HedacConfig(n_eigen=60, **cfg))


def test_uniform_whole_target_is_one_level_on_every_point_outside_the_keep_out_zone():
    assert uniform_whole_target(np.full(5, 0.3))
    assert not uniform_whole_target(np.array([1.0, 1.0, 0.0, 1.0]))
    assert not uniform_whole_target(np.array([1.0, 0.5, 1.0]))
    keep_out = np.array([False, False, True, False])
    assert uniform_whole_target(np.array([1.0, 1.0, 0.0, 1.0]), keep_out)


def test_mark_makes_done_exactly_the_points_within_the_planning_radius():
    pts = _grid(20, 20)
    src = SweepSource(pts, np.full(len(pts), 1.0 / len(pts)), plan_radius_m=2.2 * H, frontier_radius_m=1.5 * H,
                      base=0.1)
    x = pts[210] + np.array([0.0, 0.0, 0.001])
    src.mark(x)
    expected = np.linalg.norm(pts - x, axis=1) <= 2.2 * H
    np.testing.assert_array_equal(src.done, expected)
    src.reset()
    assert not src.done.any()


def test_source_is_zero_on_done_points_sums_to_one_and_prefers_the_edge_of_the_covered_region():
    pts = _grid(30, 30)
    src = SweepSource(pts, np.full(len(pts), 1.0 / len(pts)), plan_radius_m=2.5 * H, frontier_radius_m=3.0 * H,
                      base=0.05)
    s = np.empty(len(pts))
    inner = np.flatnonzero((np.abs(pts[:, 0] - 0.045) < 1e-9) & (np.abs(pts[:, 1] - 0.045) < 1e-9))[0]
    corner = 0
    src.source(s)
    assert s.sum() == pytest.approx(1.0)
    assert s[corner] > 2.0 * s[inner]  # the cloud's edge counts as covered ground
    centre = pts[inner] + np.array([0.012, 0.0, 0.0])
    src.mark(centre)
    assert src.source(s) > 0.0
    assert s.sum() == pytest.approx(1.0)
    assert np.all(s[src.done] == 0.0) and src.done.any()
    d = np.linalg.norm(pts - centre, axis=1)
    next_to_done = np.flatnonzero(~src.done & (d <= 3.5 * H))
    open_far = np.flatnonzero((np.abs(pts[:, 0] - 0.045) < 1e-9) & (np.abs(pts[:, 1] - 0.045) < 1e-9))
    assert s[next_to_done].min() > s[open_far].max()
    for x in pts:  # everything done: no source left
        src.mark(x)
    assert src.source(s) == 0.0


def test_auto_sweeps_a_whole_surface_target_and_keeps_eq_1_2_for_a_marked_one():
    pts = _grid(25, 25)
    whole = _explorer(np.ones(len(pts)), pts)
    assert whole.source_mode == "sweep" and not whole.compiled
    marked = _explorer((pts[:, 0] > 0.04).astype(float), pts)
    assert marked.source_mode == "ergodic"
    assert _explorer(np.ones(len(pts)), pts, source_mode="ergodic")._sweep is None
    assert _explorer((pts[:, 0] > 0.04).astype(float), pts, source_mode="sweep")._sweep is not None


def test_a_target_update_switches_the_source_both_ways():
    pts = _grid(25, 25)
    ex = _explorer((pts[:, 0] > 0.04).astype(float), pts)
    compiled = ex.compiled
    ex.reset(pts[300])
    ex.update_target(np.ones(len(pts)))
    assert ex.source_mode == "sweep" and not ex.compiled
    ex.step()
    ex.update_target((pts[:, 0] > 0.04).astype(float))
    assert ex.source_mode == "ergodic" and ex.compiled == compiled
    ex.step()


def test_sweep_touches_every_point_of_a_patch():
    pts = _grid(25, 25)
    ex = _explorer(np.ones(len(pts)), pts)
    ex.reset(pts[0] + np.array([0.0, 0.0, 0.001]))
    for _ in range(600):
        ex.step()
        if ex.untouched_count() == 0:
            break
    assert ex.untouched_count() == 0
    assert ex.coverage_residual() == 0.0
    # every point the agent came within the planning radius of is done, and was touched by the footprint
    assert np.all(ex.coverage[ex._tidx[ex._sweep.done]] > 0.0)


def test_sweep_options_are_checked():
    with pytest.raises(ConfigError, match="source_mode"):
        HedacConfig(source_mode="lawn")
    with pytest.raises(ConfigError, match="sweep_base"):
        HedacConfig(sweep_base=0.0)
    with pytest.raises(ConfigError, match="sweep_base"):
        HedacConfig(sweep_base=1.5)
    with pytest.raises(ConfigError, match="sweep_plan_ratio"):
        HedacConfig(sweep_plan_ratio=-1.0)
