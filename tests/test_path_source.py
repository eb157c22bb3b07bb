"""The PathSource protocol: what a task follows on the surface (the explorer, the raster, a stroke's path),
and the one loader of a user's cloud file as a target."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.ergodic.config import HedacConfig
from tactex.ergodic.explorer import HedacExplorer
from tactex.errors import InputError
from tactex.pointcloud import SurfaceCloud, save_ply
from tactex.pointcloud.markings import marked_cloud
from tactex.pointcloud.shapes import get_surface
from tactex.pointcloud.target import TargetRule
from tactex.pointcloud.target_file import load_target_file
from tactex.spectral import build_basis
from tactex.tasks.path_source import PathSource, start
from tactex.tasks.raster import RasterPath, WaypointPath
from tactex.tasks.region_raster_path import RegionRasterPath

H = 0.006  # [m] cloud spacing of these small tests


@pytest.fixture(scope="module")
def plate() -> SurfaceCloud:
    return marked_cloud(get_surface("plate"), "X", spacing_m=H)


def _sources(plate: SurfaceCloud) -> dict[str, PathSource]:
    explorer = HedacExplorer(plate, build_basis(plate, n_eigen=30, cache=False),
                             HedacConfig(n_eigen=30, agent_radius_m=0.015, compiled=False))
    stroke = WaypointPath(plate, plate.points[:5], H)
    region = RegionRasterPath(plate, 0.02, 0.03, 0.1, H)
    return {"explorer": explorer, "raster": RasterPath(plate, 0.03, H), "stroke": stroke, "region_raster": region}


def test_explorer_rasters_and_stroke_are_path_sources(plate: SurfaceCloud) -> None:
    for name, path in _sources(plate).items():
        assert isinstance(path, PathSource), name
        x0 = plate.points[np.flatnonzero(plate.target > 0)[0]]
        cmd = start(path, x0)  # the first command, whichever shape reset returns
        assert cmd.point.shape == (3,) and np.isclose(np.linalg.norm(cmd.normal), 1.0), name
        assert path.path_length == 0.0 and len(path.relocations) == 0 and not path.done, name
        for _ in range(3):
            cmd = path.step()
        assert path.path_length > 0.0, name
        path.update_target(plate.target * 0.5, keep_coverage=True)  # the raster and a stroke keep their path
        assert np.all(np.isfinite(path.step().point)), name


def test_a_waypoint_path_ends_and_ignores_the_target(plate: SurfaceCloud) -> None:
    path = WaypointPath(plate, plate.points[:3], 1.0)  # a step longer than the whole path
    start(path, plate.points[0])
    before = path.waypoints.copy()
    path.update_target(np.zeros(len(plate)))
    path.step()
    assert path.done and np.array_equal(path.waypoints, before)


def test_the_cloud_loader_refuses_an_unmarked_file_with_the_callers_hint(tmp_path, plate: SurfaceCloud) -> None:
    bare = tmp_path / "bare.ply"
    save_ply(SurfaceCloud(points=plate.points), bare)
    with pytest.raises(InputError, match=r"--cloud '.*bare.ply' has neither a target nor colours: mark it red"):
        load_target_file(bare, H, TargetRule("auto"), label="--cloud ", unmarked_hint="mark it red")
    # without a hint the target rule decides: the whole surface needs no marking
    loaded = load_target_file(bare, H, TargetRule("all"))
    assert loaded.cloud.n_target == len(loaded.cloud) and loaded.keep_out is None and loaded.read.n_faces == 0


def test_the_cloud_loader_carries_the_keep_out_zone_onto_the_voxels(tmp_path, plate: SurfaceCloud) -> None:
    colors = np.where((plate.points[:, 0] > 0.0)[:, None], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    path = tmp_path / "zoned.ply"
    save_ply(SurfaceCloud(points=plate.points, colors=colors), path)
    loaded = load_target_file(path, 2 * H, TargetRule("auto"), keep_out_channel="blue")
    assert loaded.keep_out is not None and loaded.keep_out.shape == (len(loaded.cloud),)
    assert loaded.keep_out.any() and not loaded.keep_out.all()
    assert np.all(loaded.cloud.points[loaded.keep_out, 0] > -2 * H)  # the zone stays on its side
