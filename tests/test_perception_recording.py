"""Frame recordings (.npz, no pickle), the camera mount, and the RealSense source (with a fake SDK)."""

from __future__ import annotations

import sys
from types import SimpleNamespace

import numpy as np
import pytest

from tactex.errors import InputError, MissingDependencyError, PerceptionError
from tactex.perception import (
    CameraFrame,
    CameraMount,
    D415_DEPTH_640x480,
    D435I_DEPTH_640x480,
    FrameRecorder,
    RealSenseNotFoundError,
    RealSenseSource,
    RecordedFrameSource,
    SurfaceEstimator,
    load_frames,
    save_frames,
)
from tactex.perception.synthetic import Plane, look_at, render_frame

K = D435I_DEPTH_640x480


def frames(n: int = 3, rgb: bool = True) -> list[CameraFrame]:
    out = []
    for k in range(n):
        fr, _ = render_frame(
            K, look_at([0.01 * k, 0.0, 0.3], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0)),
            [Plane((0.0, 0.0, 0.0), (0.0, 0.1, 1.0))], timestamp=0.1 * k,
            paint=(lambda p: p[:, 0] > 0) if rgb else None,
        )
        out.append(fr)
    return out


def test_round_trip(tmp_path) -> None:
    src = frames()
    path = save_frames(tmp_path / "rec.npz", src)
    back = load_frames(path)
    assert len(back) == len(src)
    for a, b in zip(src, back, strict=True):
        np.testing.assert_array_equal(a.depth_m, b.depth_m)
        np.testing.assert_array_equal(a.rgb, b.rgb)
        np.testing.assert_array_equal(a.world_T_camera, b.world_T_camera)
        assert a.timestamp == b.timestamp and a.intrinsics == b.intrinsics
    e1 = SurfaceEstimator().estimate(src[1])
    e2 = SurfaceEstimator().estimate(back[1])
    np.testing.assert_array_equal(e1.normal_world, e2.normal_world)
    with FrameRecorder(tmp_path / "rec2.npz") as rec:
        rec.extend(frames(2, rgb=False))
    replay = RecordedFrameSource(tmp_path / "rec2.npz")
    assert len(replay) == 2 and replay.read().rgb is None and replay.read() is not None and replay.read() is None
    looping = RecordedFrameSource(src, loop=True)
    assert [looping.read().timestamp for _ in range(4)] == [0.0, pytest.approx(0.1), pytest.approx(0.2), 0.0]


def test_recording_errors(tmp_path) -> None:
    with pytest.raises(InputError, match="at least one"):
        save_frames(tmp_path / "x.npz", [])
    mixed = frames(1) + frames(1, rgb=False)
    with pytest.raises(PerceptionError, match="every frame or no frame"):
        save_frames(tmp_path / "x.npz", mixed)
    other = CameraFrame(np.zeros((480, 640), np.float32), D415_DEPTH_640x480, np.eye(4), 0.0)
    with pytest.raises(PerceptionError, match="other intrinsics"):
        save_frames(tmp_path / "x.npz", [*frames(1, rgb=False), other])
    with pytest.raises(InputError, match="does not exist"):
        load_frames(tmp_path / "missing.npz")
    np.savez(tmp_path / "foreign.npz", points=np.zeros((3, 3)))
    with pytest.raises(PerceptionError, match="missing"):
        load_frames(tmp_path / "foreign.npz")
    np.savez(tmp_path / "pickled.npz", depth_m=np.array([{"a": 1}], dtype=object))
    with pytest.raises(PerceptionError, match="not a readable"):
        load_frames(tmp_path / "pickled.npz")  # object arrays need pickle: refused
    (tmp_path / "garbage.npz").write_bytes(b"not a zip")
    with pytest.raises(PerceptionError, match="not a readable"):
        load_frames(tmp_path / "garbage.npz")


def test_camera_mount_composes_eq22() -> None:
    mount = CameraMount.parallel(offset_m=(0.05, 0.0, -0.1), roll_rad=0.3)
    w_T_t = look_at([0.1, 0.2, 0.5], [0.1, 0.25, 0.0])
    w_T_c = mount.world_T_camera(w_T_t)
    np.testing.assert_allclose(w_T_c[:3, 2], w_T_t[:3, 2], atol=1e-12)  # camera z ∥ tool z
    np.testing.assert_allclose(mount.world_T_tool(w_T_c), w_T_t, atol=1e-12)
    # A normal seen in the camera frame maps to the base frame by R_c^0 = R_ee^0 R_c^ee.
    n_c = np.array([0.1, -0.2, -0.97]) / np.linalg.norm([0.1, -0.2, -0.97])
    np.testing.assert_allclose(w_T_c[:3, :3] @ n_c, w_T_t[:3, :3] @ mount.tool_T_camera[:3, :3] @ n_c, atol=1e-12)


# ----------------------------------------------------------------------------- RealSense
def test_realsense_without_the_package(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)  # import fails as if not installed
    with pytest.raises(MissingDependencyError, match=r"pip install 'tactex\[realsense\]'"):
        RealSenseSource()


def fake_rs(n_devices: int, depth_raw: np.ndarray, rgb: np.ndarray) -> SimpleNamespace:
    h, w = depth_raw.shape
    intr = SimpleNamespace(width=w, height=h, fx=383.0, fy=383.0, ppx=319.5, ppy=239.5)
    color = SimpleNamespace(
        get_data=lambda: rgb,
        profile=SimpleNamespace(as_video_stream_profile=lambda: SimpleNamespace(get_intrinsics=lambda: intr)),
    )
    depth = SimpleNamespace(get_data=lambda: depth_raw)
    aligned = SimpleNamespace(get_depth_frame=lambda: depth, get_color_frame=lambda: color)
    sensor = SimpleNamespace(get_depth_scale=lambda: 0.001)
    profile = SimpleNamespace(get_device=lambda: SimpleNamespace(first_depth_sensor=lambda: sensor))
    device = SimpleNamespace(get_info=lambda key: "12345")

    class Pipeline:
        stopped = False

        def start(self, cfg):
            return profile

        def wait_for_frames(self, timeout_ms):
            return "frames"

        def stop(self):
            Pipeline.stopped = True

    class Config:
        def enable_stream(self, *a):
            pass

        def enable_device(self, serial):
            pass

    return SimpleNamespace(
        context=lambda: SimpleNamespace(query_devices=lambda: [device] * n_devices),
        camera_info=SimpleNamespace(serial_number="serial"),
        pipeline=Pipeline,
        config=Config,
        stream=SimpleNamespace(depth="depth", color="color"),
        format=SimpleNamespace(z16="z16", rgb8="rgb8"),
        align=lambda stream: SimpleNamespace(process=lambda frames: aligned),
        Pipeline=Pipeline,
    )


def test_realsense_without_a_device(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "pyrealsense2", fake_rs(0, np.zeros((480, 640), np.uint16), None))
    with pytest.raises(MissingDependencyError, match="no Intel RealSense device") as info:
        RealSenseSource()
    assert isinstance(info.value, RealSenseNotFoundError)
    monkeypatch.setitem(sys.modules, "pyrealsense2", fake_rs(1, np.zeros((480, 640), np.uint16), None))
    with pytest.raises(RealSenseNotFoundError, match="serial 999"):
        RealSenseSource(serial="999")


def test_realsense_frames_feed_the_estimator(monkeypatch: pytest.MonkeyPatch) -> None:
    truth = frames(1)[0]
    raw = np.round(truth.depth_m / 0.001).astype(np.uint16)
    rs = fake_rs(1, raw, truth.rgb)
    monkeypatch.setitem(sys.modules, "pyrealsense2", rs)
    mount = CameraMount.parallel(offset_m=(0.0, 0.0, 0.0))
    w_T_tool = truth.world_T_camera.copy()
    with RealSenseSource(mount=mount, tool_pose_provider=lambda: w_T_tool, clock=lambda: 42.0) as cam:
        frame = cam.read()
    assert rs.Pipeline.stopped
    assert frame.depth_m.dtype == np.float32 and frame.timestamp == 42.0
    np.testing.assert_allclose(frame.depth_m, truth.depth_m, atol=0.0005 + 1e-6)
    np.testing.assert_allclose(frame.world_T_camera, truth.world_T_camera, atol=1e-12)
    assert frame.intrinsics.depth_scale == 0.001 and frame.intrinsics.width == 640
    est = SurfaceEstimator().estimate(frame)
    assert est.valid, est.reason
    n_true = np.array([0.0, 0.1, 1.0]) / np.linalg.norm([0.0, 0.1, 1.0])
    assert np.degrees(np.arccos(est.normal_world @ n_true)) < 1.0
