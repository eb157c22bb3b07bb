"""Bad input to the perception stage: typed errors or invalid estimates with a reason, never NaN as valid."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tactex.errors import CloudError, ConfigError, InputError, PerceptionError, UnitsError
from tactex.perception import (
    CameraFrame,
    CameraIntrinsics,
    CameraMount,
    D435I_DEPTH_640x480,
    RegionGrowingParams,
    SurfaceEstimator,
    SurfaceEstimatorConfig,
    check_pose,
    deproject,
    depth_in_meters,
    frame_to_cloud,
    knn_edges,
    knn_normals,
    local_curvature,
    segment_pca,
    validate_frame,
)
from tactex.perception.synthetic import Plane, look_at, render_frame

K = D435I_DEPTH_640x480
DOWN = look_at([0.0, 0.0, 0.3], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0))


def plane_frame(**kw: object) -> CameraFrame:
    frame, _ = render_frame(K, DOWN, [Plane((0.0, 0.0, 0.0), (0.0, 0.2, 1.0))], **kw)
    return frame


def with_depth(depth: object, intr: CameraIntrinsics = K) -> CameraFrame:
    return CameraFrame(depth, intr, DOWN, 0.0)  # type: ignore[arg-type]


# ----------------------------------------------------------------------------- depth images
@pytest.mark.parametrize(
    ("depth", "match"),
    [
        (np.zeros((480, 640, 1), np.float32), "2-D"),
        (np.zeros((0, 0), np.float32), "0×0"),
        (np.zeros((240, 320), np.float32), "scaled"),
        (np.zeros((480, 640), np.int32), "dtype int32"),
        (np.zeros((480, 640), bool), "dtype bool"),
        ([[0.3] * 640] * 480, "numpy array"),
    ],
)
def test_malformed_depth_raises(depth: object, match: str) -> None:
    with pytest.raises(PerceptionError, match=match):
        SurfaceEstimator().estimate(with_depth(depth))


def test_depth_in_millimetres_is_refused() -> None:
    frame = plane_frame()
    with pytest.raises(UnitsError, match="millimetres"):
        SurfaceEstimator().estimate(dataclasses.replace(frame, depth_m=frame.depth_m * 1000.0))


def test_uint16_raw_depth_is_scaled() -> None:
    frame = plane_frame()
    raw = np.round(frame.depth_m / K.depth_scale).astype(np.uint16)
    np.testing.assert_allclose(depth_in_meters(raw, K), frame.depth_m, atol=K.depth_scale / 2 + 1e-7)
    est = SurfaceEstimator().estimate(dataclasses.replace(frame, depth_m=raw))
    assert est.valid, est.reason


@pytest.mark.parametrize("fill", [0.0, np.nan, np.inf, -0.3, 5.0])
def test_all_invalid_depth_gives_invalid_estimate_with_reason(fill: float) -> None:
    est = SurfaceEstimator().estimate(with_depth(np.full((480, 640), fill, np.float32)))
    assert not est.valid
    assert "no valid depth" in est.reason
    assert np.isnan(est.normal_world).all()
    with pytest.raises(PerceptionError, match="no valid depth"):
        frame_to_cloud(with_depth(np.full((480, 640), fill, np.float32)))


def test_invalid_pixels_are_dropped_never_at_the_origin(rng: np.random.Generator) -> None:
    frame = plane_frame()
    depth = frame.depth_m.copy()
    holes = rng.random(depth.shape) < 0.3
    depth[holes] = rng.choice(np.array([0.0, np.nan, np.inf, 7.0], np.float32), size=int(holes.sum()))
    dp = deproject(depth_in_meters(depth, K), K)
    assert dp.points.shape[0] == int((~holes).sum())
    assert np.isfinite(dp.points).all()
    assert np.linalg.norm(dp.points, axis=1).min() > K.min_depth_m
    cloud = frame_to_cloud(dataclasses.replace(frame, depth_m=depth), in_world=True, stride=3)
    assert np.isfinite(cloud.points).all()
    np.testing.assert_allclose(cloud.points @ np.array([0.0, 0.2, 1.0]), 0.0, atol=1e-6)  # all on the plane
    est = SurfaceEstimator().estimate(dataclasses.replace(frame, depth_m=depth))
    assert est.valid, est.reason


def test_too_few_points_in_the_roi() -> None:
    frame = plane_frame()
    depth = np.zeros_like(frame.depth_m)
    depth[238:242, 318:322] = frame.depth_m[238:242, 318:322]  # a 4×4 px speck under the axis
    est = SurfaceEstimator().estimate(dataclasses.replace(frame, depth_m=depth))
    assert not est.valid and "valid depth points in the region of interest" in est.reason
    with pytest.raises(CloudError, match="at least 17"):
        knn_normals(np.random.default_rng(0).random((10, 3)) * 0.01, k=16)
    with pytest.raises(CloudError, match="too few"):
        knn_edges(np.zeros((5, 3)), k=8)
    knn_est = SurfaceEstimator(SurfaceEstimatorConfig(neighbourhood="knn", knn_k=16, min_cluster_size=3))
    speck = np.zeros_like(frame.depth_m)
    speck[237:243, 317:323] = frame.depth_m[237:243, 317:323]  # 6×6 px: 9 points at stride 2
    est = knn_est.estimate(dataclasses.replace(frame, depth_m=speck))
    assert not est.valid and "too few" in est.reason


def test_no_segment_under_the_tool() -> None:
    # A 4 px speck on the axis (the axis does meet a surface) inside a 15 mm hole of a plane:
    # the plane's segment is farther from the axis than the 10 mm capture radius.
    frame = plane_frame()
    v, u = np.mgrid[0:480, 0:640]
    hole = (u - K.cx) ** 2 + (v - K.cy) ** 2 < (0.015 * K.fx / 0.3) ** 2
    speck = (np.abs(u - K.cx) < 2) & (np.abs(v - K.cy) < 2)
    depth = np.where(hole & ~speck, 0.0, frame.depth_m).astype(np.float32)
    est = SurfaceEstimator().estimate(dataclasses.replace(frame, depth_m=depth))
    assert not est.valid
    assert "no segment under the tool" in est.reason
    assert np.isnan(est.normal_camera).all() and np.isnan(est.theta_rad)


def test_axis_missing_the_surface() -> None:
    frame = plane_frame()
    world_T_tool = np.eye(4)
    world_T_tool[:3, 3] = [0.0, 0.0, 0.1]  # tool z points *up*: away from the surface
    est = SurfaceEstimator().estimate(frame, world_T_tool)
    assert not est.valid and "meets no valid depth" in est.reason


def test_valid_estimates_are_always_finite(rng: np.random.Generator) -> None:
    # Random tilted planes with depth noise and holes: whatever is returned as valid is finite.
    est = SurfaceEstimator()
    n_valid = 0
    for _ in range(12):
        n = rng.normal(size=3)
        n[2] = abs(n[2]) + 0.5
        frame, _ = render_frame(K, DOWN, [Plane((0.0, 0.0, 0.0), tuple(n))])
        depth = frame.depth_m + rng.normal(0.0, 0.002, frame.depth_m.shape).astype(np.float32)
        depth[rng.random(depth.shape) < 0.4] = 0.0
        e = est.estimate(dataclasses.replace(frame, depth_m=depth))
        if e.valid:
            n_valid += 1
            for vec in (e.normal_camera, e.normal_world, e.e1_world, e.e2_world, e.centroid_world):
                assert np.isfinite(vec).all()
            assert np.isfinite(e.curvature) and np.isfinite(e.theta_rad)
        else:
            assert e.reason
    assert n_valid > 0


# ----------------------------------------------------------------------------- poses, rgb, intrinsics
@pytest.mark.parametrize(
    ("pose", "match"),
    [
        (np.eye(3), "shape"),
        (np.full((4, 4), np.nan), "NaN"),
        (np.diag([1.0, 1.0, 2.0, 1.0]), "rotation"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), "rotation"),
        (np.vstack([np.eye(4)[:3], [0.0, 0.0, 1.0, 1.0]]), "last row"),
        ("identity", "of numbers"),
        ([[1, 0, 0, 0], [0, 1, 0]], "of numbers"),
    ],
)
def test_bad_poses_raise(pose: np.ndarray, match: str) -> None:
    with pytest.raises(InputError, match=match):
        check_pose(pose, "T")
    with pytest.raises(InputError, match="world_T_camera"):
        SurfaceEstimator().estimate(CameraFrame(plane_frame().depth_m, K, pose, 0.0))
    with pytest.raises(InputError, match="world_T_tool"):
        SurfaceEstimator().estimate(plane_frame(), pose)
    with pytest.raises(InputError, match="tool_T_camera"):
        CameraMount(pose)


def test_bad_rgb_and_timestamp_raise() -> None:
    frame = plane_frame()
    with pytest.raises(PerceptionError, match="rgb must have shape"):
        validate_frame(dataclasses.replace(frame, rgb=np.zeros((480, 640), np.uint8)))
    with pytest.raises(PerceptionError, match="dtype int64"):
        validate_frame(dataclasses.replace(frame, rgb=np.zeros((480, 640, 3), np.int64)))
    with pytest.raises(PerceptionError, match=r"\[0, 1\]"):
        validate_frame(dataclasses.replace(frame, rgb=np.full((480, 640, 3), 2.0)))
    with pytest.raises(PerceptionError, match="timestamp"):
        validate_frame(dataclasses.replace(frame, timestamp=float("nan")))
    with pytest.raises(PerceptionError, match="CameraFrame"):
        validate_frame(frame.depth_m)  # type: ignore[arg-type]
    with pytest.raises(PerceptionError, match="CameraFrame"):
        SurfaceEstimator().estimate(frame.depth_m)  # type: ignore[arg-type]
    with pytest.raises(PerceptionError, match="stride"):
        deproject(frame.depth_m, K, stride=0)


@pytest.mark.parametrize(
    "kwargs",
    [dict(width=0), dict(fx=-1.0), dict(min_depth_m=2.0, max_depth_m=1.0), dict(cx=float("nan")),
     dict(fy=float("inf")), dict(width=640.5), dict(height=True), dict(depth_scale=0.0),
     dict(depth_scale=float("nan")), dict(max_depth_m=float("inf"))],
)
def test_bad_intrinsics_raise(kwargs: dict) -> None:
    base = dict(width=640, height=480, fx=383.0, fy=383.0, cx=319.5, cy=239.5)
    name = next(iter(kwargs))
    with pytest.raises(PerceptionError, match={"min_depth_m": "depth range", "fx": "focal"}.get(name, name)):
        CameraIntrinsics(**{**base, **kwargs})


@pytest.mark.parametrize("fov", [0.0, 180.0, float("nan")])
def test_intrinsics_from_a_degenerate_field_of_view_raise(fov: float) -> None:
    with pytest.raises(PerceptionError, match="field of view"):
        CameraIntrinsics.from_fov(640, 480, fov)


def test_uint16_depth_with_a_wrong_scale_is_a_units_error() -> None:
    raw = np.full((K.height, K.width), 300, np.uint16)  # 300 mm from a z16 stream
    wrong = dataclasses.replace(K, depth_scale=1.0)
    with pytest.raises(UnitsError, match="depth_scale=1 m/unit"):
        depth_in_meters(raw, wrong)
    np.testing.assert_allclose(depth_in_meters(raw, dataclasses.replace(K, depth_scale=0.001)), 0.3, rtol=1e-6)


def test_intrinsics_array_round_trip_and_check() -> None:
    assert CameraIntrinsics.from_array(K.to_array()) == K
    with pytest.raises(PerceptionError, match="9 finite"):
        CameraIntrinsics.from_array(np.ones(5))
    np.testing.assert_allclose(K.K @ np.array([0.0, 0.0, 1.0]), [K.cx, K.cy, 1.0])


# ----------------------------------------------------------------------------- configs and PCA
@pytest.mark.parametrize(
    "kwargs",
    [
        dict(roi_radius_m=0.0),
        dict(capture_radius_m=float("nan")),
        dict(axis_start_m=float("inf")),
        dict(stride=0),
        dict(max_grid_cells=2.5),
        dict(neighbourhood="octree"),
        dict(knn_k=2),
        dict(smoothness_angle_deg=95.0),
        dict(curvature_threshold=-0.1),
        dict(min_cluster_size=10, max_cluster_size=5),
    ],
)
def test_bad_estimator_config_raises(kwargs: dict) -> None:
    with pytest.raises(ConfigError):
        SurfaceEstimatorConfig(**kwargs)


def test_region_growing_params_validate() -> None:
    with pytest.raises(ConfigError, match="smoothness"):
        RegionGrowingParams(smoothness_angle_deg=0.0)
    with pytest.raises(ConfigError, match="curvature"):
        RegionGrowingParams(curvature_threshold=2.0)
    with pytest.raises(ConfigError, match="cluster"):
        RegionGrowingParams(min_cluster_size=0)


def test_segment_pca_rejects_degenerate_segments() -> None:
    with pytest.raises(CloudError, match="N ≥ 3"):
        segment_pca(np.zeros((2, 3)))
    with pytest.raises(CloudError, match="NaN"):
        segment_pca(np.array([[0.0, 0, 0], [1, 0, 0], [np.nan, 1, 0]]))
    with pytest.raises(CloudError, match="collinear"):
        segment_pca(np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]]) * 0.01)
    with pytest.raises(CloudError, match="trace"):
        local_curvature(np.zeros(3))
    assert local_curvature(np.array([1.0, 1.0, 1.0])) == pytest.approx(1.0 / 3.0)


def test_configs_generate_cli_options() -> None:
    import argparse

    from tactex.config import add_dataclass_arguments, dataclass_from_args
    from tactex.perception import AcquisitionConfig

    parser = argparse.ArgumentParser()
    add_dataclass_arguments(parser, SurfaceEstimatorConfig)
    add_dataclass_arguments(parser, AcquisitionConfig, prefix="acq_")
    args = parser.parse_args(
        ["--roi-radius-m", "0.02", "--neighbourhood", "knn", "--acq-crop-min-m", "-1", "-1", "0", "--acq-color-method",
         "channel"]
    )
    cfg = dataclass_from_args(SurfaceEstimatorConfig, args)
    acq = dataclass_from_args(AcquisitionConfig, args, prefix="acq_")
    assert cfg.roi_radius_m == 0.02 and cfg.neighbourhood == "knn" and cfg.stride == 2
    assert acq.crop_min_m == (-1.0, -1.0, 0.0) and acq.color_method == "channel"
    with pytest.raises(ConfigError, match="neighbourhood"):
        dataclass_from_args(SurfaceEstimatorConfig, parser.parse_args(["--neighbourhood", "mesh"]))
