"""The agent's normal stays on the cloud's outward side (HedacStep._outward_side).

Each step's fitted normal is oriented along the last one. Where a local fit is poor (a bowl's rim in a
noisy capture) the normal can swing far in one step, and orientation by the last normal then carries it
round to the inside of the part: the clean's pressing line came from beneath the bowl's wall and turned
the tool over. The cloud's own normals (oriented to the camera) decide the side.
"""

from __future__ import annotations

import numpy as np
import pytest

from tactex.ergodic import HedacConfig, HedacExplorer
from tactex.ergodic import compiled_step as cs
from tactex.experiments.explore import ExploreConfig, load_explore_cloud
from tactex.pointcloud import SurfaceCloud
from tactex.spectral import build_basis


@pytest.fixture(scope="module")
def bowl():
    cloud, _ = load_explore_cloud("bowl", ExploreConfig(voxel_size_m=0.004))
    return cloud, build_basis(cloud, n_eigen=40, cache=False)


def _nearest_normal(cloud, p: np.ndarray) -> np.ndarray:
    return cloud.normals[int(np.argmin(np.linalg.norm(cloud.points - p, axis=1)))]


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=pytest.mark.skipif(
    not cs.available(), reason="numba (the 'fast' extra) is not installed: the compiled step is not used"))])
def test_a_normal_turned_inside_is_put_back_on_the_outward_side(bowl, compiled):
    cloud, basis = bowl
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=40, compiled=compiled))
    start = cloud.points[np.argmin(np.linalg.norm(cloud.points - cloud.points.mean(axis=0), axis=1))]
    ex.reset(start[None, :])
    for k in range(40):
        # the stored normal flipped before every step: what the last step of a poor fit leaves behind
        ex._nrm_t[0] = tuple((-np.array(ex._nrm_t[0])).tolist())
        (cmd,) = ex.step_all()
        outward = _nearest_normal(cloud, cmd.point)
        assert float(cmd.normal @ outward) > 0.5, f"step {k}: normal {cmd.normal} against the cloud's {outward}"
        # the command's frame stays right-handed about the normal it carries
        np.testing.assert_allclose(np.cross(cmd.tangent_u, cmd.tangent_v), cmd.normal, atol=1e-9)
    if compiled:
        assert ex.compiled_steps >= 30  # the compiled step took the steps the check is about


def test_a_cloud_without_normals_keeps_the_fit_s_orientation(bowl):
    cloud, basis = bowl
    bare = SurfaceCloud(cloud.points, target=cloud.target)
    assert bare.normals is None
    ex = HedacExplorer(bare, basis, HedacConfig(n_eigen=40))
    ex.reset(cloud.points[:1])
    n = (0.0, 0.0, -1.0)
    assert ex._outward_side(n, 0) is n  # nothing to orient by: the fit's own (the last step's) orientation
