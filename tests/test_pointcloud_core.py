"""SurfaceCloud validation, voxel grid (Open3D semantics), I/O round trips, target from colour."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.errors import CloudError, ConfigError, InputError, UnitsError
from tactex.pointcloud import (
    SurfaceCloud,
    load_cloud,
    load_ply,
    save_cloud,
    target_from_channel,
    voxel_down_sample,
)
from tests.conftest import TEC_CLOUDS, tec_cloud_path

# Points after 3 mm voxels and target points, from the data README / TEC paper.
EXPECTED_VOXEL = {"bun270_X": (2996, 210), "cup_X": (1511, 162), "plate_shapes": (6228, 1216)}


def grid_cloud(n: int = 10, spacing: float = 0.01) -> SurfaceCloud:
    xs, ys = np.meshgrid(np.arange(n) * spacing, np.arange(n) * spacing)
    pts = np.stack([xs.ravel(), ys.ravel(), np.zeros(n * n)], axis=1)
    return SurfaceCloud(points=pts)


@pytest.mark.shared_data
@pytest.mark.parametrize("name", TEC_CLOUDS)
def test_voxel_grid_reproduces_paper_counts(name: str) -> None:
    cloud = load_ply(tec_cloud_path(name))
    down = target_from_channel(voxel_down_sample(cloud, 0.003), "red", 1.0)
    assert (len(down), down.n_target) == EXPECTED_VOXEL[name]
    assert down.spacing == 0.003


def test_voxel_averages_points_and_colours() -> None:
    pts = np.array([[0.0, 0.0, 0.0], [0.001, 0.0, 0.0], [0.05, 0.0, 0.0]])
    cols = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    with pytest.warns(RuntimeWarning, match="finer than the cloud's own mean spacing"):  # 2 points 5 cm apart
        out = voxel_down_sample(SurfaceCloud(points=pts, colors=cols), 0.01)
    assert len(out) == 2
    np.testing.assert_allclose(out.points[0], [0.0005, 0, 0])
    np.testing.assert_allclose(out.colors[0], [0.5, 0, 0.5])


def test_a_voxel_finer_than_the_cloud_keeps_the_clouds_own_spacing() -> None:
    """On a 5 mm grid a 3 mm voxel changes nothing: h stays 5 mm (it was set to 3 mm, and the agent,
    whose steps are in voxels, then could not step from point to point and never moved)."""
    with pytest.warns(RuntimeWarning, match="finer than the cloud's own mean spacing 5 mm"):
        fine = voxel_down_sample(grid_cloud(spacing=0.005), 0.003)
    assert len(fine) == 100 and fine.spacing == pytest.approx(0.005)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        coarse = voxel_down_sample(grid_cloud(spacing=0.005), 0.012)
    assert coarse.spacing == 0.012


def test_voxel_rejects_bad_size() -> None:
    with pytest.raises(ConfigError, match="voxel size"):
        voxel_down_sample(grid_cloud(), 0.0)


def test_empty_cloud_rejected() -> None:
    with pytest.raises(CloudError, match="empty"):
        SurfaceCloud(points=np.zeros((0, 3)))


def test_wrong_shape_rejected() -> None:
    with pytest.raises(CloudError, match=r"\(N, 3\)"):
        SurfaceCloud(points=np.zeros((5, 2)))


def test_nan_points_rejected_with_index() -> None:
    pts = grid_cloud().points.copy()
    pts[7, 1] = np.nan
    with pytest.raises(CloudError, match="index 7"):
        SurfaceCloud(points=pts)


def test_millimetre_cloud_refused() -> None:
    with pytest.raises(UnitsError, match="millimetres"):
        SurfaceCloud(points=grid_cloud().points * 1000.0)


def test_duplicates_detected_and_removed() -> None:
    pts = np.vstack([grid_cloud().points, grid_cloud().points[:3]])
    with pytest.raises(CloudError, match="duplicates"):
        SurfaceCloud(points=pts)
    cloud = SurfaceCloud(points=pts, spacing=0.01).deduplicated()
    assert len(cloud) == 100


def test_negative_target_and_bad_colours_rejected() -> None:
    c = grid_cloud()
    with pytest.raises(CloudError, match="≥ 0"):
        c.with_target(-np.ones(len(c)))
    with pytest.raises(CloudError, match="255"):
        SurfaceCloud(points=c.points, colors=np.full((len(c), 3), 200.0))


def test_spacing_is_nearest_neighbour_mean() -> None:
    assert grid_cloud(spacing=0.004).spacing == pytest.approx(0.004)


def test_target_from_channel_marks_exactly_the_painted_points() -> None:
    c = grid_cloud()
    cols = np.full((len(c), 3), 0.3)
    painted = np.array([3, 14, 15, 92])
    cols[painted, 0] = 1.0
    out = target_from_channel(SurfaceCloud(points=c.points, colors=cols), "red", 1.0)
    np.testing.assert_array_equal(np.flatnonzero(out.target), painted)
    with pytest.raises(ConfigError, match="valid: red, green, blue"):
        target_from_channel(SurfaceCloud(points=c.points, colors=cols), "alpha")
    with pytest.raises(InputError, match="no colours"):
        target_from_channel(c)


@pytest.mark.parametrize("suffix", [".ply", ".npz"])
def test_round_trip(tmp_path, suffix: str) -> None:
    c = grid_cloud()
    rng = np.random.default_rng(0)
    cols = np.round(rng.uniform(0, 1, (len(c), 3)) * 255) / 255
    normals = np.tile([0.0, 0.0, 1.0], (len(c), 1))
    src = SurfaceCloud(points=c.points, colors=cols, normals=normals, target=rng.uniform(0, 1, len(c)))
    back = load_cloud(save_cloud(src, tmp_path / f"c{suffix}"))
    np.testing.assert_allclose(back.points, src.points)
    np.testing.assert_allclose(back.colors, src.colors, atol=1e-9)
    np.testing.assert_allclose(back.normals, src.normals)
    np.testing.assert_allclose(back.target, src.target)


def test_pcd_reader(tmp_path) -> None:
    pts = grid_cloud().points.astype(np.float32)
    header = (
        "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
        f"WIDTH {len(pts)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(pts)}\nDATA ascii\n"
    )
    body = "\n".join(" ".join(f"{v:.6f}" for v in p) for p in pts)
    path = tmp_path / "c.pcd"
    path.write_text(header + body + "\n")
    back = load_cloud(path)
    np.testing.assert_allclose(back.points, pts, atol=1e-6)


def test_unknown_suffix_and_missing_file() -> None:
    with pytest.raises(InputError, match="supported"):
        load_cloud("cloud.xyz")
    with pytest.raises(InputError, match="does not exist"):
        load_cloud("/nonexistent/cloud.ply")


def test_negative_or_nan_spacing_refused() -> None:
    pts = grid_cloud().points
    for bad in (-0.003, float("nan")):
        with pytest.raises(CloudError, match="spacing"):
            SurfaceCloud(points=pts, spacing=bad)
