"""The RealSense path without a device: a rendered scene written as a RealSense recording (depth z16
and colour rgb8 at different intrinsics, the cameras 15 mm apart as on a D435), played back through
the RealSenseSource a live camera uses, and captured with ``tactex capture``."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from tactex.cli import main
from tactex.perception.frame import CameraIntrinsics
from tactex.perception.synthetic import Plane, look_at, render_depth, render_frame


def _pyrealsense2_or_skip():
    try:
        import pyrealsense2
    except ImportError as exc:
        if "libusb" in str(exc):
            pytest.skip(f"pyrealsense2 needs the system library libusb-1.0 (apt-get install libusb-1.0-0): {exc}")
        pytest.skip(f"pyrealsense2 is not installed (the realsense extra): {exc}")
    return pyrealsense2


pytestmark = pytest.mark.timeout(120)

#: The scene: a tilted plane with a red disc on it (robot base frame, metres).
NORMAL = np.array([0.45, -0.25, 1.0]) / np.linalg.norm([0.45, -0.25, 1.0])
MARK = np.array([0.58, 0.05, 0.08])
MARK_RADIUS_M = 0.03
PLANE = Plane(tuple(MARK), tuple(NORMAL))
COLOR_K = CameraIntrinsics(320, 240, 307.0, 307.0, 161.0, 121.5)
DEPTH_K = CameraIntrinsics(320, 240, 191.5, 191.5, 158.0, 118.0)
BASE_T_COLOR = look_at([0.5, -0.04, 0.45], [0.5, 0.0, 0.08], up=(1.0, 0.0, 0.0))
COLOR_T_DEPTH = np.eye(4)
COLOR_T_DEPTH[:3, 3] = [-0.015, 0.0, 0.0]
BOX = ["0.2", "-0.4", "-0.1", "0.8", "0.4", "0.4"]


def _in_mark(points: np.ndarray) -> np.ndarray:
    return np.linalg.norm(points - MARK, axis=1) < MARK_RADIUS_M


def _write(path, pairs: int = 3):
    _pyrealsense2_or_skip()
    from tactex.perception.rs_recording import RecordedPair, write_realsense_recording

    depth, _, _ = render_depth(DEPTH_K, BASE_T_COLOR @ COLOR_T_DEPTH, [PLANE])
    color, _ = render_frame(COLOR_K, BASE_T_COLOR, [PLANE], paint=_in_mark)
    return write_realsense_recording(path, [RecordedPair(depth, color.rgb)] * pairs, DEPTH_K, COLOR_K, COLOR_T_DEPTH)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    return _write(tmp_path_factory.mktemp("rs") / "scene.db3")


def _mark_error(cloud) -> tuple[float, float]:
    """Distance [m] of the red points' centroid from the mark's centre, and the angle [deg] of their
    mean normal from the plane's."""
    from tactex.pointcloud.target import target_from_color

    red = target_from_color(cloud, "red").target > 0.5
    assert red.sum() > 50, f"only {red.sum()} red points"
    centre = cloud.points[red].mean(axis=0)
    n = cloud.normals[red].mean(axis=0)
    angle = np.degrees(np.arccos(np.clip(n @ NORMAL / np.linalg.norm(n), -1.0, 1.0)))
    return float(np.linalg.norm(centre - MARK)), float(angle)


def test_playback_places_the_mark_and_its_normal(recording, tmp_path, capsys) -> None:
    from tactex.pointcloud.io import load_ply

    out = tmp_path / "scan.ply"
    assert main(["capture", "--camera", "realsense", "--playback", str(recording), "--camera-pose",
                 str(_pose(tmp_path)), "--box", *BOX,
                 "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "target: red by hue" in said and "points are target" in said
    cloud = load_ply(out)
    assert cloud.normals is not None and cloud.colors is not None
    distance, angle = _mark_error(cloud)
    print(f"playback capture: mark {distance * 1e3:.2f} mm, normal {angle:.2f}°")
    assert distance < 0.003, f"mark {distance * 1e3:.2f} mm from where the scene put it"
    assert angle < 2.0, f"normal {angle:.2f}° off"


def _pose(tmp_path):
    path = tmp_path / "base_T_camera.json"
    path.write_text(json.dumps(BASE_T_COLOR.tolist()))
    return path


def test_the_source_aligns_depth_to_colour(recording) -> None:
    """The same recording read without alignment (depth taken as if on the colour grid) puts the
    mark centimetres off: the playback test above holds only because the source aligns."""
    _pyrealsense2_or_skip()
    from types import SimpleNamespace

    from tactex.perception.mount import CameraMount
    from tactex.perception.realsense import RealSenseSource
    from tactex.tasks.capture import CaptureConfig, frames_to_cloud

    cfg = CaptureConfig(box_m=tuple(float(v) for v in BOX))
    with RealSenseSource(mount=CameraMount(BASE_T_COLOR), playback=recording) as source:
        aligned = source.read()
    assert aligned.intrinsics.fx == pytest.approx(COLOR_K.fx) and aligned.depth_m.shape == (240, 320)
    with RealSenseSource(mount=CameraMount(BASE_T_COLOR), playback=recording) as source:
        source._align = SimpleNamespace(process=lambda frames: frames)  # a source that forgot to align
        unaligned = source.read()
    good, _ = _mark_error(frames_to_cloud([aligned], cfg))
    bad, _ = _mark_error(frames_to_cloud([unaligned], cfg))
    print(f"mark error aligned {good * 1e3:.2f} mm, unaligned {bad * 1e3:.2f} mm")
    assert good < 0.003 and bad > 0.01, (good, bad)


def test_a_recording_that_ends_mid_capture_is_a_sensor_fault(recording, tmp_path, capsys) -> None:
    from tactex.errors import CameraStreamEnded
    from tactex.perception.mount import CameraMount
    from tactex.perception.realsense import RealSenseSource
    from tactex.tasks.capture import CaptureConfig, capture_cloud

    with RealSenseSource(mount=CameraMount(BASE_T_COLOR), playback=recording) as source, \
            pytest.raises(CameraStreamEnded, match=r"after \d of the 5 frames of the capture: .*recording .* ended"):
        capture_cloud(source, CaptureConfig(views=5))
    out = tmp_path / "scan.ply"
    code = main(["capture", "--camera", "realsense", "--playback", str(recording), "--camera-pose",
                 str(_pose(tmp_path)), "--views", "5", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 1 and len(err.strip().splitlines()) == 1 and "ended" in err and "of the 5 frames" in err, err
    assert not out.exists()


def _one_line_exit_2(capsys, argv: list[str], words: str) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("tactex capture: error:") and words in err, err


def test_bad_input_is_one_line_and_exit_2(recording, tmp_path, capsys) -> None:
    pose = _pose(tmp_path)
    out = str(tmp_path / "scan.ply")
    base = ["capture", "--camera", "realsense", "--out", out]
    _one_line_exit_2(capsys, [*base, "--playback", str(recording), "--camera-pose", str(tmp_path / "none.json")],
                     "is not a file")
    bad = tmp_path / "bad.json"
    bad.write_text("[[1, 0, 0], [0, 1")
    _one_line_exit_2(capsys, [*base, "--playback", str(recording), "--camera-pose", str(bad)], "not a JSON")
    skew = tmp_path / "skew.npy"
    np.save(skew, np.eye(4) * 2.0)
    _one_line_exit_2(capsys, [*base, "--playback", str(recording), "--camera-pose", str(skew)], "rigid transform")
    fake = tmp_path / "fake.db3"
    fake.write_text("not a recording\n")
    _one_line_exit_2(capsys, [*base, "--playback", str(fake), "--camera-pose", str(pose)], "not a RealSense recording")
    _one_line_exit_2(capsys, [*base, "--playback", str(recording)], "needs the camera's pose")
    _one_line_exit_2(capsys, [*base, "--playback", str(recording), "--camera-pose", str(pose), "--box", "1", "0",
                              "0", "0", "1", "1"], "--box")


def test_realsense_without_pyrealsense2(tmp_path, capsys, monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)  # the import fails as if it were not installed
    _one_line_exit_2(capsys, ["capture", "--camera", "realsense", "--camera-pose", str(_pose(tmp_path)), "--out",
                              str(tmp_path / "scan.ply")], "pip install 'tactex[realsense]'")
