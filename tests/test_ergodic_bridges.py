"""Scan-hole bridges: gap links of the Laplacian and the agent's hop across them."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from tactex.ergodic import HedacConfig, HedacExplorer
from tactex.ergodic.bridges import Bridge, gap_links
from tactex.pointcloud import SurfaceCloud, load_ply, target_from_channel, voxel_down_sample
from tactex.spectral import build_basis

from .conftest import tec_cloud_path, tec_initial_positions

MAX_STEPS = 2000  # a parked agent must fail the test, not hang it
H = 0.003  # [m]
GAP = 0.012  # [m] a 4-voxel scan hole: too wide to walk at max_off_cloud = 1 voxel


def _two_strips(gap_m: float = GAP) -> SurfaceCloud:
    """Two 3 mm grids on z = 0, the right one 14 voxels + gap_m along x; the target on its far half."""
    rng = np.random.default_rng(3)
    u, v = np.meshgrid(np.arange(15) * H, np.arange(30) * H)
    left = np.c_[u.ravel(), v.ravel(), np.zeros(u.size)]
    right = left + np.array([14 * H + gap_m, 0.0, 0.0])
    pts = np.vstack([left, right]) + rng.uniform(-1e-4, 1e-4, (2 * u.size, 3)) * [1, 1, 0]
    return SurfaceCloud(pts, target=(pts[:, 0] > 14 * H + gap_m + 0.02).astype(float), spacing=H)


@pytest.fixture(scope="module")
def strips():
    cloud = _two_strips()
    return cloud, build_basis(cloud, n_eigen=60, n_neighbors=40, cache=False)


def test_gap_links_are_the_laplacian_links_across_the_hole(strips):
    cloud, basis = strips
    pts = cloud.points
    links = gap_links(pts, basis.L, cKDTree(pts), max_off_m=H, max_length_m=6 * H)
    assert links.n_links > 0
    edge = 14 * H
    for j in np.flatnonzero(links.has):
        far = links.far[links.ptr[j] : links.ptr[j + 1]]
        # every link joins the two strips, and is a link of the Laplacian
        assert np.all((pts[j, 0] < edge + 1e-3) != (pts[far, 0] < edge + 1e-3))
        assert np.all(basis.L[j, far].toarray() != 0.0)
        assert np.all(np.linalg.norm(pts[far] - pts[j], axis=1) <= 6 * H)
    # the links are symmetric: j lists k exactly when k lists j
    pairs = {(j, int(k)) for j in np.flatnonzero(links.has) for k in links.far[links.ptr[j] : links.ptr[j + 1]]}
    assert pairs == {(k, j) for j, k in pairs}


def test_gap_links_none_when_disabled_too_short_or_without_a_hole(strips):
    cloud, basis = strips
    pts, tree = cloud.points, cKDTree(cloud.points)
    assert gap_links(pts, basis.L, tree, H, 0.0).n_links == 0  # max_bridge = 0
    assert gap_links(pts, basis.L, tree, H, 3 * H).n_links == 0  # shorter than the hole
    assert gap_links(pts, None, tree, H, 6 * H).n_links == 0  # a basis without its Laplacian
    solid = _two_strips(gap_m=0.0)  # one continuous grid: the walk reaches everything
    solid_basis = build_basis(solid, n_eigen=10, n_neighbors=40, cache=False)
    assert gap_links(solid.points, solid_basis.L, cKDTree(solid.points), H, 6 * H).n_links == 0


def test_the_agent_hops_the_hole_only_when_allowed(strips):
    cloud, basis = strips
    start = np.array([0.02, 0.045, 0.0])
    result = {}
    for max_bridge in (0.0, 6.0):
        ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=60, max_bridge=max_bridge))
        (prev,) = ex.reset(start)
        v_max = ex.config.max_velocity * H
        for _ in range(250):
            cmd = ex.step()
            assert np.all(np.isfinite(cmd.point)) and abs(np.linalg.norm(cmd.normal) - 1.0) < 1e-9
            assert np.linalg.norm(cmd.point - prev.point) <= v_max * (1 + 1e-9)
            # walking: within a voxel of the cloud; hopping: on the chord, over the hole's middle at most
            assert ex._tree.query(cmd.point)[0] <= (H if max_bridge == 0.0 else GAP / 2 + H) * (1 + 1e-9)
            prev = cmd
        result[max_bridge] = (ex.bridges_taken, ex.coverage_residual())
    assert result[0.0] == (0, 1.0)  # stuck at the rim: the target is never touched
    assert result[6.0][0] >= 1 and result[6.0][1] < 0.5


def test_a_hop_in_progress_accepts_measured_positions(strips):
    """Closed loop during a hop: the robot's measured point replaces the agent, the hop goes on."""
    cloud, basis = strips
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=60))
    ex.reset(np.array([0.02, 0.045, 0.0]))
    for _ in range(400):
        cmd = ex.step()
        if ex._bridges[0] is not None:
            break
    else:
        pytest.fail("no hop started")
    measured = cmd.point + np.array([0.0, 0.0, 0.001])  # 1 mm above the chord
    for _ in range(10):
        cmd = ex.step(measured_position=measured)
        assert np.all(np.isfinite(cmd.point))
        measured = cmd.point
    assert cmd.point[0] > 14 * H + GAP  # it arrived on the far strip


def test_bridge_normal_blends_along_the_chord_and_survives_opposite_ends():
    up, side = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    b = Bridge(7, np.zeros(3), np.array([0.01, 0.0, 0.0]), up, side)
    np.testing.assert_allclose(b.normal_at(np.zeros(3)), up)
    np.testing.assert_allclose(b.normal_at(np.array([0.01, 0.0, 0.0])), side)
    np.testing.assert_allclose(b.normal_at(np.array([0.005, 0.0, 0.0])), (up + side) / np.sqrt(2.0))
    np.testing.assert_allclose(b.normal_at(np.array([0.02, 0.0, 0.0])), side)  # clamped past the end
    flip = Bridge(7, np.zeros(3), np.array([0.01, 0.0, 0.0]), up, -up)
    n = flip.normal_at(np.array([0.005, 0.0, 0.0]))  # opposite normals: no 0/0
    assert np.all(np.isfinite(n)) and abs(np.linalg.norm(n) - 1.0) < 1e-12


def test_on_the_tec_bunny_an_agent_started_on_its_base_reaches_the_x():
    """The bunny scan's base is joined to its body only by 15 mm links of the Laplacian: the
    authors' start 9 walked at most one voxel off the cloud and never touched the X (residual 1.0
    at every path length). With hops it is covering the X within 1 m of path."""
    bunny = target_from_channel(voxel_down_sample(load_ply(tec_cloud_path("bun270_X")), H), "red", 1.0)
    start = tec_initial_positions("bun270_X")[9]
    basis = build_basis(bunny, n_eigen=60, n_neighbors=40, cache=False)
    residual = {}
    for max_bridge in (0.0, 6.0):
        ex = HedacExplorer(bunny, basis, HedacConfig(n_eigen=60, max_bridge=max_bridge))
        ex.reset(start)
        while ex.path_length < 1.0 and ex.step_count < MAX_STEPS:
            ex.step()
        residual[max_bridge] = (ex.bridges_taken, ex.coverage_residual())
    assert residual[0.0] == (0, 1.0)
    assert residual[6.0][0] >= 1 and residual[6.0][1] < 0.3, residual
