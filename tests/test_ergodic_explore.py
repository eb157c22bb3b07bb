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
    """A jittered 3 mm grid on z = 0 with two target blobs (the agent relocates between them)."""
    rng = np.random.default_rng(0)
    u, v = np.meshgrid(np.arange(40) * H, np.arange(40) * H)
    pts = np.c_[u.ravel(), v.ravel(), np.zeros(u.size)] + rng.uniform(-2e-4, 2e-4, (u.size, 3)) * [1, 1, 0]
    pts -= pts.mean(axis=0)
    target = ((np.linalg.norm(pts - [0.03, 0.03, 0.0], axis=1) < 0.012)
              | (np.linalg.norm(pts - [-0.03, -0.03, 0.0], axis=1) < 0.012)).astype(float)
    cloud = SurfaceCloud(pts, target=target, spacing=H)
    return cloud, build_basis(cloud, n_eigen=60, cache=False)


@pytest.mark.parametrize("compiled", [True, False])
def test_explore_is_the_run_of_an_explorer_stepped_by_hand(plane, compiled):
    cloud, basis = plane
    cfg = HedacConfig(n_eigen=60, compiled=compiled, progress_steps=40)
    x0 = np.array([-0.04, 0.04, 0.0])
    steps = 400
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
    # the run means something: it covers target and relocates between the blobs
    assert run.coverage_residual[-1] < run.coverage_residual[0]
    assert any(isinstance(c, RelocationCommand) for c in run.commands)


def test_explore_with_no_steps_is_the_start(plane):
    cloud, basis = plane
    run = explore(cloud, basis, np.array([0.0, 0.0, 0.001]), 0, HedacConfig(n_eigen=60))
    assert run.points.shape == (1, 3) and run.coverage_residual.shape == (0,)
    assert run.points[0, 2] == pytest.approx(0.0, abs=1e-3)  # projected onto the surface
    assert np.array_equal(run.velocities[0], np.zeros(3))


@pytest.mark.parametrize("steps", [-1, 2.5, True, "10"])
def test_explore_refuses_a_bad_step_count(plane, steps):
    cloud, basis = plane
    with pytest.raises(InputError, match="steps must be an integer"):
        explore(cloud, basis, np.zeros(3), steps, HedacConfig(n_eigen=60))


def test_explore_takes_one_start(plane):
    cloud, basis = plane
    with pytest.raises(InputError, match=r"x0 must be one point of shape \(3,\).*got shape \(2, 3\)"):
        explore(cloud, basis, np.zeros((2, 3)), 5, HedacConfig(n_eigen=60))
