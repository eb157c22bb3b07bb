"""TEC §V-A1 pre-processing: crop box, pass-through, statistical outlier removal, colour targets."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.errors import CloudError, ConfigError, InputError, UnitsError
from tactex.perception import AcquisitionConfig, D435I_DEPTH_640x480, acquire_surface, frame_to_cloud
from tactex.perception.synthetic import Plane, Sphere, look_at, render_frame
from tactex.pointcloud import SurfaceCloud, target_from_channel
from tactex.pointcloud.color import HsvRange, hsv_mask, target_from_hsv
from tactex.pointcloud.filters import (
    crop_box,
    crop_box_mask,
    pass_through,
    statistical_outlier_mask,
    statistical_outlier_removal,
)

K = D435I_DEPTH_640x480


def sor_reference(points: np.ndarray, k: int, std_mul: float) -> np.ndarray:
    """PCL StatisticalOutlierRemoval written the slow, obvious way (all pairwise distances)."""
    d = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=2)
    d_sorted = np.sort(d, axis=1)[:, 1: k + 1]  # skip the point itself
    mean_d = d_sorted.mean(axis=1)
    n = mean_d.size
    mu = mean_d.sum() / n
    sigma = np.sqrt(((mean_d - mu) ** 2).sum() / (n - 1))
    return mean_d <= mu + std_mul * sigma


def test_statistical_outlier_removal_matches_pcl_semantics(rng: np.random.Generator) -> None:
    surface = np.c_[rng.uniform(0, 0.1, (400, 2)), rng.normal(0, 0.0005, 400)]
    outliers = np.c_[rng.uniform(0, 0.1, (12, 2)), rng.uniform(0.03, 0.06, 12)]
    pts = np.vstack([surface, outliers])
    for k, mul in ((8, 1.0), (20, 0.5), (30, 2.0)):
        np.testing.assert_array_equal(statistical_outlier_mask(pts, k, mul), sor_reference(pts, k, mul))
    mask = statistical_outlier_mask(pts, 20, 1.0)
    assert not mask[400:].any()  # every planted outlier goes
    out = statistical_outlier_removal(SurfaceCloud(points=pts), 20, 1.0)
    assert len(out) == int(mask.sum())
    np.testing.assert_array_equal(out.points, pts[mask])


def test_statistical_outlier_removal_validates() -> None:
    cloud = SurfaceCloud(points=np.random.default_rng(1).random((30, 3)) * 0.1)
    with pytest.raises(CloudError, match="mean_k=50"):
        statistical_outlier_removal(cloud, 50)
    with pytest.raises(ConfigError, match="mean_k"):
        statistical_outlier_mask(cloud.points, 0)
    with pytest.raises(ConfigError, match="std_mul"):
        statistical_outlier_mask(cloud.points, 5, float("nan"))
    with pytest.raises(UnitsError, match="millimetres"):
        statistical_outlier_mask(cloud.points * 1000.0, 5)
    bad = cloud.points.copy()
    bad[3] = np.nan
    with pytest.raises(CloudError, match="NaN"):
        statistical_outlier_mask(bad, 5)


def test_crop_box_and_pass_through(rng: np.random.Generator) -> None:
    pts = rng.uniform(-0.1, 0.1, (500, 3))
    cloud = SurfaceCloud(points=pts, colors=rng.random((500, 3)))
    lo, hi = np.array([-0.05, -np.inf, 0.0]), np.array([0.05, 0.02, np.inf])
    inside = np.all((pts >= lo) & (pts <= hi), axis=1)
    np.testing.assert_array_equal(crop_box_mask(pts, lo, hi), inside)
    kept = crop_box(cloud, lo, hi)
    np.testing.assert_array_equal(kept.points, pts[inside])
    np.testing.assert_array_equal(kept.colors, cloud.colors[inside])
    assert kept.spacing == cloud.spacing  # removing points keeps the sampling density h
    np.testing.assert_array_equal(crop_box(cloud, lo, hi, negative=True).points, pts[~inside])
    z_in = (pts[:, 2] >= -0.02) & (pts[:, 2] <= 0.03)
    np.testing.assert_array_equal(pass_through(cloud, "z", (-0.02, 0.03)).points, pts[z_in])
    np.testing.assert_array_equal(pass_through(cloud, "z", (-0.02, 0.03), negative=True).points, pts[~z_in])
    with pytest.raises(CloudError, match="removed every"):
        pass_through(cloud, "x", (1.0, 2.0))
    with pytest.raises(ConfigError, match="field 'w'"):
        pass_through(cloud, "w", (0.0, 1.0))
    with pytest.raises(ConfigError, match="low ≤ high"):
        pass_through(cloud, "x", (1.0, 0.0))
    with pytest.raises(ConfigError, match="exceeds"):
        crop_box(cloud, [0.1, 0, 0], [0.0, 1, 1])
    with pytest.raises(ConfigError, match="3 numbers"):
        crop_box(cloud, [0.0, 0.0], [1.0, 1.0])
    with pytest.raises(CloudError, match="SurfaceCloud"):
        crop_box(pts, lo, hi)


def test_open3d_clouds_round_trip_through_filters(rng: np.random.Generator) -> None:
    o3d = pytest.importorskip("open3d")
    pts = rng.uniform(0, 0.1, (200, 3))
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    out = pass_through(pcd, "x", (0.0, 0.05))
    assert isinstance(out, o3d.geometry.PointCloud)
    np.testing.assert_allclose(np.asarray(out.points), pts[pts[:, 0] <= 0.05])


# ----------------------------------------------------------------------------- colour → target
def painted_frame():
    """A plane seen from 0.3 m with a red disc of radius 2 cm painted at (0.01, −0.01)."""
    return render_frame(
        K,
        look_at([0.0, 0.0, 0.3], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0)),
        [Plane((0.0, 0.0, 0.0), (0.1, 0.0, 1.0))],
        paint=lambda p: (p[:, 0] - 0.01) ** 2 + (p[:, 1] + 0.01) ** 2 < 0.02**2,
    )


def test_painted_mark_gives_target_exactly_on_marked_points() -> None:
    frame, mask = painted_frame()
    cloud = frame_to_cloud(frame, in_world=True)
    # frame_to_cloud keeps valid pixels in row-major order: the same order as mask[depth > 0].
    marked = mask[frame.depth_m > 0]
    assert 0 < marked.sum() < marked.size
    for tgt in (target_from_hsv(cloud, HsvRange(), mass=2.0), target_from_channel(cloud, "red", 0.85, mass=2.0)):
        np.testing.assert_array_equal(tgt.target > 0, marked)
        np.testing.assert_array_equal(tgt.target[marked], 2.0)
    # The channel threshold matters: at 0.7 the grey (red = 200/255 = 0.78) is marked too.
    assert (target_from_channel(cloud, "red", 0.7).target > 0).sum() == marked.size


def test_hsv_hue_wraps_and_validates() -> None:
    colors = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.1], [1.0, 0.1, 0.0], [0.0, 1.0, 0.0], [0.5, 0.5, 0.5]])
    # hues: 0°, ~354°, 6°, 120°, grey (s = 0)
    np.testing.assert_array_equal(hsv_mask(colors, HsvRange((340.0, 20.0))), [True, True, True, False, False])
    np.testing.assert_array_equal(hsv_mask(colors, HsvRange((100.0, 140.0))), [False, False, False, True, False])
    np.testing.assert_array_equal(
        hsv_mask(colors, HsvRange((0.0, 360.0), saturation=(0.0, 0.1), value=(0.4, 0.6))),
        [False, False, False, False, True],
    )
    with pytest.raises(ConfigError, match="hue_deg"):
        HsvRange((0.0, 400.0))
    with pytest.raises(ConfigError, match="saturation"):
        HsvRange(saturation=(0.8, 0.2))
    with pytest.raises(InputError, match=r"\[0, 1\]"):
        hsv_mask(colors * 255.0, HsvRange())
    with pytest.raises(InputError, match="no colours"):
        target_from_hsv(SurfaceCloud(points=np.eye(3) * 0.01))
    with pytest.raises(ConfigError, match="mass"):
        target_from_hsv(SurfaceCloud(points=np.eye(3) * 0.01, colors=np.eye(3)), mass=0.0)


def test_acquire_surface_pipeline() -> None:
    frame, mask = painted_frame()
    # Without voxel/SOR the target is exactly the painted pixels (crop keeps everything).
    raw = acquire_surface(frame, AcquisitionConfig(voxel_size_m=0.0, sor_mean_k=0))
    np.testing.assert_array_equal(raw.target > 0, mask[frame.depth_m > 0])
    # With the defaults (3 mm voxels, SOR, HSV): target voxels sit on the painted disc.
    cloud = acquire_surface(frame, AcquisitionConfig(crop_min_m=(-0.05, -0.05, -1.0), crop_max_m=(0.05, 0.05, 1.0)))
    assert cloud.spacing == pytest.approx(0.003)
    assert np.all(np.abs(cloud.points[:, :2]) <= 0.05 + 1e-12)
    tp = cloud.points[cloud.target > 0]
    assert tp.shape[0] > 50
    r = np.hypot(tp[:, 0] - 0.01, tp[:, 1] + 0.01)
    assert r.max() < 0.02 + 0.003  # within one voxel of the disc edge
    # Two views merge into one cloud.
    frame2, _ = render_frame(K, look_at([0.05, 0.0, 0.3], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0)),
                             [Sphere((0.0, 0.0, -0.5), 0.5)], paint=lambda p: p[:, 0] > 0.0)
    merged = acquire_surface([frame2, frame2], AcquisitionConfig(voxel_size_m=0.004, sor_mean_k=0))
    single = acquire_surface(frame2, AcquisitionConfig(voxel_size_m=0.004, sor_mean_k=0))
    np.testing.assert_allclose(merged.points, single.points, atol=1e-12)
    with pytest.raises(ConfigError, match="color_method"):
        AcquisitionConfig(color_method="lab")
    no_rgb, _ = render_frame(K, frame.world_T_camera, [Plane((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))])
    with pytest.raises(InputError, match="needs RGB"):
        acquire_surface(no_rgb)
