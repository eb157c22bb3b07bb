"""The one-shot explore() beside HedacExplorer: the same run as stepping an explorer by hand."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.ergodic import Exploration, HedacConfig, HedacExplorer, explore
from tactex.ergodic.relocation import RelocationCommand
from tactex.errors import InputError
from tactex.pointcloud import SurfaceCloud
from tactex.spectral import build_basis

H = 0.003  # [m] voxel


@pytest.fixture(scope="module")
def plane():
    """Two jittered 3 mm grids 3 cm apart, all target: the agent covers one and relocates to the other."""
    rng = np.random.default_rng(0)
    u, v = np.meshgrid(np.arange(14) * H, np.arange(14) * H)
    one = np.c_[u.ravel(), v.ravel(), np.zeros(u.size)]
    pts = np.r_[one, one + np.array([0.07, 0.0, 0.0])] + rng.uniform(-2e-4, 2e-4, (2 * u.size, 3)) * [1, 1, 0]
    pts -= pts.mean(axis=0)
    cloud = SurfaceCloud(pts, target=np.ones(len(pts)), spacing=H)
    return cloud, build_basis(cloud, n_eigen=40, cache=False)


@pytest.mark.parametrize("compiled", [True, False])
def test_explore_is_the_run_of_an_explorer_stepped_by_hand(plane, compiled):
    cloud, basis = plane
    cfg = HedacConfig(n_eigen=40, compiled=compiled, source_mode="ergodic")  # ergodic: the compiled step runs
    x0 = cloud.points[0]
    steps = 300
    run = explore(cloud, basis, x0, steps, cfg)

    ex = HedacExplorer(cloud, basis, cfg)
    cmds = list(ex.reset(x0))
    residual = []
    for _ in range(steps):
        cmds.append(ex.step())
        residual.append(ex.coverage_residual())
    assert isinstance(run, Exploration)
    assert run.points.shape == run.velocities.shape == run.normals.shape == (steps + 1, 3)
    assert np.array_equal(run.points, [c.point for c in cmds])
    assert np.array_equal(run.velocities, [c.velocity for c in cmds])
    assert np.array_equal(run.normals, [c.normal for c in cmds])
    assert np.array_equal(run.coverage_residual, residual)
    assert np.array_equal(run.explorer.coverage, ex.coverage)
    assert run.explorer.path_length == ex.path_length
    assert [type(c) for c in run.commands] == [type(c) for c in cmds]
    # the run means something: it covers the target, relocating between the grids, compiled when asked
    assert run.coverage_residual[-1] < 0.1 * run.coverage_residual[0]
    assert any(isinstance(c, RelocationCommand) for c in run.commands)
    assert (run.explorer.compiled_steps > 0) == (compiled and run.explorer.compiled)


def test_explore_with_no_steps_is_the_start(plane):
    cloud, basis = plane
    run = explore(cloud, basis, cloud.points[5] + [0.0, 0.0, 0.001], 0, HedacConfig(n_eigen=40))
    assert run.points.shape == (1, 3) and run.coverage_residual.shape == (0,)
    assert run.points[0, 2] == pytest.approx(0.0, abs=1e-3)  # projected onto the surface
    assert np.array_equal(run.velocities[0], np.zeros(3))


@pytest.mark.parametrize("steps", [-1, 2.5, True, "10"])
def test_explore_refuses_a_bad_step_count(plane, steps):
    cloud, basis = plane
    with pytest.raises(InputError, match="steps must be an integer"):
        explore(cloud, basis, cloud.points[0], steps, HedacConfig(n_eigen=40))


def test_explore_takes_one_start(plane):
    cloud, basis = plane
    with pytest.raises(InputError, match=r"x0 must be one point of shape \(3,\).*got shape \(2, 3\)"):
        explore(cloud, basis, np.zeros((2, 3)), 5, HedacConfig(n_eigen=40))
