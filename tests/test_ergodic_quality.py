"""Exploration quality mechanisms of the HEDAC explorer, each found by diagnosing a stalled agent.

These are behavioural checks on small synthetic clouds (fast, no data files): the agent must head
for uncovered target mass it can see, and must not be parked by its own footprint.
"""

from __future__ import annotations

import numpy as np
import pytest

from tactex.ergodic import HedacConfig, HedacExplorer
from tactex.pointcloud import SurfaceCloud, load_ply, target_from_channel, voxel_down_sample
from tactex.spectral import build_basis

from .conftest import tec_cloud_path, tec_initial_positions

MAX_STEPS = 2000  # a parked agent must fail the test, not hang it
H = 0.003  # [m] voxel of the TEC experiments
HEADING_COS = 0.9  # "heads for it": the first step within ~25° of the direction to the target


def _grid(n_side: int = 40, seed: int = 0) -> np.ndarray:
    """A jittered 3 mm grid on z = 0, centred on the origin."""
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.arange(n_side) * H, np.arange(n_side) * H)
    pts = np.c_[u.ravel(), v.ravel(), np.zeros(u.size)] + rng.uniform(-2e-4, 2e-4, (u.size, 3)) * [1, 1, 0]
    return pts - pts.mean(axis=0)


@pytest.mark.parametrize("angle", np.linspace(0.0, 2.0 * np.pi, 4, endpoint=False))
def test_agent_heads_for_uncovered_target_at_the_rim_of_its_neighbourhood(angle):
    """A few target points 6 mm away, inside the n_N = 20 fit neighbourhood (≈ 7.5 mm) but outside a
    2 mm footprint: the raw source term is a spike at the rim of the fit. A cubic through it slopes
    *away* from it at the agent (the released code only escapes this because its ill-conditioned
    monomials truncate the cubic); the explorer must step towards the target."""
    pts = _grid()
    spot = 0.006 * np.array([np.cos(angle), np.sin(angle), 0.0])
    target = (np.linalg.norm(pts - spot, axis=1) < 0.0025).astype(float)
    cloud = SurfaceCloud(pts, target=target, spacing=H)
    basis = build_basis(cloud, n_eigen=60, cache=False)
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=60, agent_radius_m=0.002))
    (start,) = ex.reset(np.zeros(3))
    step = ex.step().point - start.point
    heading = spot - start.point
    assert step @ heading / (np.linalg.norm(step) * np.linalg.norm(heading)) > HEADING_COS


def test_plane_slope_is_the_weighted_least_squares_plane(rng):
    from tactex.ergodic.explorer import _plane_slope

    uv = rng.uniform(-1.0, 1.0, (20, 2))
    x = np.c_[np.ones(20), uv]
    w = rng.uniform(0.4, 1.0, 20)
    y = rng.uniform(0.0, 1.0, 20) * (rng.uniform(size=20) > 0.7)
    a = (x * w[:, None]).T @ x
    expected = np.linalg.lstsq(x * np.sqrt(w)[:, None], y * np.sqrt(w), rcond=None)[0][1:]
    upper = a[np.triu_indices(3)].tolist()  # a00, a01, a02, a11, a12, a22
    rhs = ((x * w[:, None]).T @ y).tolist()
    np.testing.assert_allclose(_plane_slope(*upper, *rhs), expected, rtol=1e-10, atol=1e-12)
    collinear = np.c_[np.ones(20), uv[:, 0], 2.0 * uv[:, 0]]
    rank_deficient = (collinear.T @ collinear)[np.triu_indices(3)].tolist()
    assert _plane_slope(*rank_deficient, 1.0, 0.5, 1.0) is None  # rank-deficient block


CUP_FLOOR = 0.176  # √(5/162): five isolated target points 3–6 cm from the X
CUP_RESIDUAL_AT_HALF_METRE = 0.2  # every start done with the X after 0.5 m of path (was up to 0.66)


def _tec_cup_runs(normalization: str) -> list[tuple[float, float]]:
    """Residual at 0.5 m and 1 m of path from each of the authors' ten cup starts (n_K = 60)."""
    cup = target_from_channel(voxel_down_sample(load_ply(tec_cloud_path("cup_X")), H), "red", 1.0)
    starts = tec_initial_positions("cup_X")
    basis = build_basis(cup, n_eigen=60, n_neighbors=40, cache=False)
    ex = HedacExplorer(cup, basis, HedacConfig(n_eigen=60, coverage_normalization=normalization))
    out = []
    for x0 in starts:
        ex.reset(x0)
        marks = []
        for metres in (0.5, 1.0):
            while ex.path_length < metres and ex.step_count < MAX_STEPS:
                ex.step()
            marks.append(ex.coverage_residual())
        out.append((marks[0], marks[1]))
    return out


def test_on_the_tec_cup_every_start_covers_the_whole_target():
    """TEC cup, the authors' ten starts: after 0.5 m of path every agent is done with the X (before
    the raw source got its own plane fit, agents at the X's crossing were held there by the spikes'
    cubic slope: residual up to 0.66), and after 1 m every target point, the five strays included,
    has been inside a footprint (coverage normalised over the target, the default)."""
    runs = _tec_cup_runs("target")
    assert max(r for r, _ in runs) <= CUP_RESIDUAL_AT_HALF_METRE, runs
    assert max(r for _, r in runs) == 0.0, runs


def test_eq2_domain_normalisation_leaves_the_cups_strays_for_later():
    """Eq. 2 literally (coverage normalised over the whole cloud): the footprint mass spent off the
    thin X keeps every covered X point in deficit, and after 1 m no start has reached the five
    strays — the reason the target normalisation is the default."""
    runs = _tec_cup_runs("domain")
    assert min(r for _, r in runs) >= CUP_FLOOR - 1e-3, runs
    assert max(r for r, _ in runs) <= CUP_RESIDUAL_AT_HALF_METRE, runs


def test_on_the_tec_bunny_every_start_touches_every_target_point_within_a_metre():
    """TEC bunny, the authors' ten starts (n_K = 60): after 1 m of path every target point, the four
    strays 3.6–6.8 cm from the X included, has been inside a footprint. This needs the
    target normalisation, the raw source seen over the whole ball and hops across the scan holes
    that cut off the base (before: starts 2 and 9 scored 1.0, the others stopped at √(4/210) = 0.138)."""
    bunny = target_from_channel(voxel_down_sample(load_ply(tec_cloud_path("bun270_X")), H), "red", 1.0)
    starts = tec_initial_positions("bun270_X")
    ex = HedacExplorer(bunny, build_basis(bunny, n_eigen=60, n_neighbors=40, cache=False), HedacConfig(n_eigen=60))
    residuals = []
    for x0 in starts:
        ex.reset(x0)
        while ex.path_length < 1.0 and ex.step_count < MAX_STEPS:
            ex.step()
        residuals.append(ex.coverage_residual())
    assert max(residuals) == 0.0, residuals
