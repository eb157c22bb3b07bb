"""The basis's cost said before it is built, the size cap with --force, and progress during the basis, the
eigensolver and the pass plan."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tactex.cli import main
from tactex.errors import CloudError
from tactex.pointcloud import SurfaceCloud
from tactex.spectral import build_basis
from tactex.spectral.estimate import MAX_BASIS_POINTS, check_basis_size, estimate_basis, fitting_voxel_m


@pytest.fixture(autouse=True)
def _cache_dir(tmp_path_factory, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TACTEX_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "basis-cache"))


def test_estimate_grows_with_points_and_eigenpairs() -> None:
    small, more_points, more_pairs = estimate_basis(20_000, 200), estimate_basis(80_000, 200), estimate_basis(20_000,
                                                                                                              800)
    assert more_points.seconds > 3.5 * small.seconds and more_points.peak_bytes > 3.5 * small.peak_bytes
    assert more_pairs.seconds > 8 * small.seconds  # the block iterations cost N·p²
    big = estimate_basis(240_000, 1000)
    assert big.peak_bytes > 240_000 * 1000 * 8  # at least the eigenvectors themselves
    assert big.describe().startswith("about ") and big.describe().endswith(" GB") and "min" in big.describe()
    assert "s and" in estimate_basis(5_000, 100).describe() and estimate_basis(5_000, 100).describe().endswith(" MB")


def test_fitting_voxel_leaves_the_cloud_under_the_cap() -> None:
    v, n = fitting_voxel_m(239_075, 0.003)
    assert 0.003 < v <= 0.0034 and n == int(239_075 * (0.003 / v) ** 2) <= 0.95 * MAX_BASIS_POINTS
    assert fitting_voxel_m(400_000, 0.002, 100_000)[0] == pytest.approx(0.0042, abs=1e-4)


def test_fitting_voxel_counted_on_the_points_is_the_smallest_that_fits() -> None:
    from tactex.pointcloud.voxel import voxel_indices

    g = np.arange(0.0, 0.6, 0.003)  # a 200 × 200 grid at 3 mm: 40 000 points
    x, y = np.meshgrid(g, g)
    pts = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    v, n = fitting_voxel_m(len(pts), 0.003, 10_000, pts)
    assert n == voxel_indices(pts, v)[1].size <= 9_500
    assert voxel_indices(pts, v - 1e-4)[1].size > 9_500  # 0.1 mm finer no longer fits
    assert v <= fitting_voxel_m(len(pts), 0.003, 10_000)[0]  # never coarser than the square law


def test_over_the_cap_is_refused_with_the_estimate_and_the_voxel_size() -> None:
    with pytest.raises(CloudError) as err:
        check_basis_size(239_075, 1000, 0.003)
    msg = str(err.value)
    assert "239,075 points, over the 200,000" in msg and "without --force" in msg
    assert "1000 eigenpairs would take about" in msg and "GB (estimated)" in msg
    assert f"voxel_size_m={fitting_voxel_m(239_075, 0.003)[0]:g} (about" in msg
    est = check_basis_size(239_075, 1000, 0.003, force=True)
    assert est == estimate_basis(239_075, 1000)
    assert check_basis_size(MAX_BASIS_POINTS, 200, 0.003).n_points == MAX_BASIS_POINTS  # at the cap: built


def test_explore_refuses_a_cloud_over_the_cap_before_any_work(tmp_path, monkeypatch, capsys) -> None:
    import tactex.spectral.estimate as estimate

    monkeypatch.setattr(estimate, "MAX_BASIS_POINTS", 1_000)
    monkeypatch.setattr(estimate, "PROGRESS_MIN_POINTS", 1_000)  # the phases of a large basis said
    g = np.arange(0.0, 0.12, 0.003)
    x, y = np.meshgrid(g, g)
    pts = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    colors = np.where(pts[:, :1] < 0.03, [1.0, 0.0, 0.0], [0.7, 0.7, 0.7])
    np.savez(tmp_path / "c.npz", points=pts, colors=colors)
    out = tmp_path / "run"
    assert main(["explore", str(tmp_path / "c.npz"), "--out", str(out), "--steps", "5", "--n-eigen", "20"]) == 2
    err = capsys.readouterr().err
    assert "1,600 points, over the 1,000" in err and "or --force" in err
    v = err.split("give --voxel-size-m ")[1].split()[0]
    assert main(["explore", str(tmp_path / "c.npz"), "--out", str(tmp_path / "fits"), "--steps", "5", "--n-eigen",
                 "20", "--voxel-size-m", v, "--quiet"]) == 0  # the voxel size said fits
    assert json.loads((tmp_path / "fits" / "metrics.json").read_text())["n_points"] <= 950
    assert not (out / "metrics.json").exists()
    assert main(["explore", str(tmp_path / "c.npz"), "--out", str(out), "--steps", "5", "--n-eigen", "20",
                 "--force", "--no-cache"]) == 0
    err = capsys.readouterr().err
    assert "basis: Laplacian and 20 eigenpairs of 1600 points: about" in err and "B (estimated) ..." in err
    assert "basis: Laplacian of 1600 points ..." in err and "eigensolver: iteration 1: largest η²" in err


def test_basis_progress_names_each_phase() -> None:
    g = np.linspace(0.0, 0.1, 40)
    x, y = np.meshgrid(g, g)
    cloud = SurfaceCloud(points=np.column_stack([x.ravel(), y.ravel(), 0.01 * np.sin(20 * x.ravel())]))
    lines: list[str] = []
    build_basis(cloud, n_eigen=30, cache=False, eigensolver="hierarchical", progress=lines.append)
    assert lines[0] == "basis: Laplacian of 1600 points ..."
    assert lines[1].startswith("basis: Laplacian ") and "30 eigenpairs (hierarchical eigensolver) ..." in lines[1]
    assert any(line.startswith("eigensolver: ") and "levels of 1600" in line for line in lines)
    assert any(line.startswith("eigensolver: iteration 1: largest η²") for line in lines)


def test_pass_plan_progress_on_a_large_part(monkeypatch) -> None:
    import tactex.ergodic.pass_planner as planner
    from tactex.ergodic import HedacConfig, HedacExplorer

    monkeypatch.setattr(planner, "PROGRESS_MIN_POINTS", 100)  # this test's plate stands for a large part
    g = np.arange(0.0, 0.15, 0.003)
    x, y = np.meshgrid(g, g)
    cloud = SurfaceCloud(points=np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)]), spacing=0.003)
    cloud = cloud.with_target(np.ones(len(cloud)))
    basis = build_basis(cloud, n_eigen=30, cache=False)
    explorer = HedacExplorer(cloud, basis, HedacConfig(agent_radius_m=0.01, n_eigen=30))
    assert explorer.planned_passes
    lines: list[str] = []
    explorer.progress = lines.append
    explorer.reset(cloud.points[0])
    explorer.step()
    assert lines[0].startswith(f"pass plan: {len(cloud)} target points in this part, ")
    assert lines[-1].startswith("pass plan: laid in ")
    explorer.step()
    assert lines[-1].startswith("pass plan: laid in ")  # laid once


def test_time_left_is_reckoned_from_the_steps_after_the_first(monkeypatch) -> None:
    from types import SimpleNamespace

    import tactex.experiments.explore as explore_mod

    clock = [0.0]
    monkeypatch.setattr(explore_mod, "time", SimpleNamespace(perf_counter=lambda: clock[0]))

    class Slow:  # a first step that lays a pass plan (100 s), then 10 ms steps
        path_length = air_path_length = 0.0
        k = 0

        def step(self):
            clock[0] += 100.0 if self.k == 0 else 0.01
            self.k += 1
            return SimpleNamespace(point=np.zeros(3))

        def ergodicity(self) -> float:
            return 0.5

        def coverage_residual(self) -> float:
            return 0.5

    lines: list[str] = []
    explore_mod._walk(Slow(), 20, lines.append)
    assert lines[0].startswith("step 1/20:") and "(the first step: 100.0 s)" in lines[0] and "left" not in lines[0]
    assert lines[1].startswith("step 2/20:") and "(about 0 s left)" in lines[1]  # 18 steps of 10 ms, not 900 s


def test_clean_refuses_a_cloud_over_the_cap_before_the_run(tmp_path, monkeypatch, capsys) -> None:
    import tactex.spectral.estimate as estimate
    from tactex.commands._task import check_cloud_size
    from tactex.tasks.clean.config import CleanConfig

    monkeypatch.setattr(estimate, "MAX_BASIS_POINTS", 1_000)
    g = np.arange(0.0, 0.12, 0.003)
    x, y = np.meshgrid(g, g)
    pts = np.column_stack([0.44 + x.ravel(), y.ravel() - 0.06, np.full(x.size, 0.05)])
    colors = np.where(pts[:, :1] < 0.47, [1.0, 0.0, 0.0], [0.7, 0.7, 0.7])
    np.savez(tmp_path / "c.npz", points=pts, colors=colors)
    out = tmp_path / "clean"
    assert main(["clean", "--cloud", str(tmp_path / "c.npz"), "--out", str(out), "--quiet", "--no-video"]) == 2
    err = capsys.readouterr().err
    assert "1,600 points, over the 1,000" in err and "give --voxel-size-m 0.00" in err and "or --force" in err
    assert not (out / "metrics.json").exists()
    cfg = CleanConfig(cloud=str(tmp_path / "c.npz"))
    check_cloud_size(cfg, force=True)  # --force: no refusal
    check_cloud_size(CleanConfig(cloud=str(tmp_path / "c.npz"), baseline="raster"), force=False)  # no basis
    monkeypatch.setattr(estimate, "MAX_BASIS_POINTS", 2_000)
    check_cloud_size(cfg, force=False)  # under the cap


def test_explore_says_when_the_basis_came_from_the_cache(tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.setenv("TACTEX_CACHE_DIR", str(tmp_path / "basis"))
    g = np.arange(0.0, 0.06, 0.003)
    x, y = np.meshgrid(g, g)
    pts = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    np.savez(tmp_path / "c.npz", points=pts, colors=np.where(pts[:, :1] < 0.03, [1.0, 0.0, 0.0], [0.7, 0.7, 0.7]))
    said = []
    for k in range(2):
        assert main(["explore", str(tmp_path / "c.npz"), "--out", str(tmp_path / f"r{k}"), "--steps", "5",
                     "--n-eigen", "20"]) == 0
        said.append(capsys.readouterr().err)
    assert "eigensolver" in said[0].split("basis: ")[2] and "read from the cache" not in said[0]
    assert "read from the cache" in said[1]
