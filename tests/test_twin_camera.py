"""The twin's wrist camera: its wire format, the frames it serves of its own scene (posed from its own
robot state, its dirt as it is), the client's frames posed as a RealSense's, the stream stopped, and the
clean's camera options checked before the robot is reached."""

from __future__ import annotations

import signal
import sys

import numpy as np
import pytest

from tactex.cli import main
from tactex.errors import CameraStreamEnded, ConfigError
from tactex.perception.frame import CameraIntrinsics
from tactex.perception.twin_camera import decode_frame, encode_frame

pytestmark = pytest.mark.timeout(300)


def test_a_frame_survives_the_wire():
    k = CameraIntrinsics(8, 6, 5.0, 5.0, 4.0, 3.0, depth_scale=1e-4)
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.1, 2.0, (6, 8)).astype(np.float32)
    depth[0, 0] = 0.0  # no depth stays no depth
    rgb = rng.integers(0, 256, (6, 8, 3), dtype=np.uint8)
    pose = np.eye(4)
    pose[:3, 3] = [0.5, -0.1, 0.6]
    wire = encode_frame(7, 1.25, pose, depth, rgb, k.depth_scale)
    n = int.from_bytes(wire[:4], "big")
    meta, d, c = decode_frame(wire[4:4 + n], wire[4 + n:], k)
    assert meta["seq"] == 7 and meta["t"] == 1.25 and np.allclose(np.reshape(meta["base_T_camera"], (4, 4)), pose)
    assert np.abs(d - depth).max() <= 0.5e-4 + 1e-7 and d[0, 0] == 0.0
    assert np.array_equal(c, rgb)


@pytest.mark.parametrize(("kw", "match"), [
    ({"camera_port": 1337}, "franky-sim"),
    ({"camera_port": 70000}, "camera_port"),
    ({"camera_width": 4}, "camera_width"),
    ({"camera_rate_hz": 0.0}, "camera_rate_hz"),
    ({"camera_mount_shift_mm": (0.0, 80.0, 0.0)}, "camera_mount_shift_mm"),
    ({"camera_mount_tilt_deg": (float("nan"), 0.0, 0.0)}, "camera_mount_tilt_deg"),
    ({"board": (9, 6), "camera_port": 0}, "board is seen only by the twin's camera"),
    ({"board": (1, 6)}, "board cols"),
    ({"board": (9, 6), "board_square_m": 0.5}, "square_m"),
])
def test_twin_camera_settings_are_checked(kw, match):
    pytest.importorskip("franky_sim", reason="needs the franka extra")
    from tactex.twin.config import TwinConfig

    with pytest.raises(ConfigError, match=match):
        TwinConfig(object_name="plate", **kw)


def test_camera_choice_is_checked():
    from tactex.tasks.robot import RealRobotParams

    with pytest.raises(ConfigError, match="camera must be"):
        RealRobotParams(robot_ip="1.2.3.4", camera="kinect")
    with pytest.raises(ConfigError, match="--camera realsense"):
        RealRobotParams(robot_ip="1.2.3.4", camera="twin", playback="x.db3")
    with pytest.raises(ConfigError, match="capture_frames"):
        RealRobotParams(robot_ip="1.2.3.4", camera="twin", capture_frames=0)


# -- clean's bad input: one line, exit 2, before the robot is reached (no robot listens at 127.0.0.254) --------
def _clean_exit_2(capsys, args: list[str], words: str) -> None:
    code = main(["clean", "--robot", "franka", "--robot-ip", "127.0.0.254", "--quiet", "--no-video", *args])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and words in err, err


def test_clean_camera_bad_input_is_one_line_and_exit_2(tmp_path, capsys):
    out = ["--out", str(tmp_path / "run")]
    _clean_exit_2(capsys, ["--camera", "none", *out], "--camera realsense")
    _clean_exit_2(capsys, ["--camera", "twin", "--hand-eye", str(tmp_path / "none.json"), *out], "not a file")
    bad = tmp_path / "bad.json"
    bad.write_text("[[1, 0, 0], [0, 1")
    _clean_exit_2(capsys, ["--camera", "twin", "--hand-eye", str(bad), *out], "JSON")
    skew = tmp_path / "skew.npy"
    np.save(skew, np.eye(4) * 2.0)
    _clean_exit_2(capsys, ["--camera", "twin", "--hand-eye", str(skew), *out], "rigid")
    _clean_exit_2(capsys, ["--camera", "realsense", "--playback", str(tmp_path / "none.db3"), *out], "not a file")


def test_clean_with_a_playback_that_is_not_a_recording(tmp_path, capsys):
    try:
        import pyrealsense2  # noqa: F401
    except ImportError as exc:
        pytest.skip(f"pyrealsense2 cannot be imported here: {exc}")
    fake = tmp_path / "fake.db3"
    fake.write_text("not a recording\n")
    _clean_exit_2(capsys, ["--camera", "realsense", "--playback", str(fake), "--out", str(tmp_path / "run")],
                  "not a RealSense recording")


def test_clean_with_realsense_without_pyrealsense2(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)  # the import fails as if it were not installed
    _clean_exit_2(capsys, ["--camera", "realsense", "--out", str(tmp_path / "run")], "tactex[realsense]")


# -- the twin's camera -------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def plate():
    pytest.importorskip("pylibfranka", reason="needs the franka extra")
    pytest.importorskip("franky_sim", reason="needs the franka extra")
    from tactex.twin.process import TwinProcess

    with TwinProcess("plate", ["--camera-width", "320", "--camera-height", "240"]) as proc:
        yield proc


def test_the_twin_serves_its_scene_posed_as_the_robot_reports(plate):
    from tactex.perception.mount import CameraMount
    from tactex.perception.twin_camera import TwinCameraSource, twin_status
    from tactex.robots.read_pose import read_tool_pose
    from tactex.sim.scene import SceneConfig
    from tactex.tasks.robot import nominal_tool_T_camera

    base_T_tool = read_tool_pose(plate.hostname)
    mount = CameraMount(nominal_tool_T_camera(SceneConfig(object_name="plate")))
    with TwinCameraSource(plate.hostname, plate.camera_port, mount=mount,
                          tool_pose_provider=lambda: base_T_tool) as source:
        frames = [source.read() for _ in range(3)]
        rendered = source.rendered_pose
    assert source.intrinsics.width == 320 and source.intrinsics.height == 240
    # the client poses the frame from the robot's state and the nominal mount; the twin rendered it from the
    # camera on its own arm: the same pose
    posed = frames[-1].world_T_camera
    assert np.linalg.norm(posed[:3, 3] - rendered[:3, 3]) < 1e-3
    angle = np.degrees(np.arccos(np.clip((np.trace(posed[:3, :3].T @ rendered[:3, :3]) - 1) / 2, -1, 1)))
    assert angle < 0.2
    # the plate is below the camera and its red marking is in view
    rgb = frames[-1].rgb.reshape(-1, 3).astype(int)
    red = (rgb[:, 0] > 150) & (rgb[:, 1] < 100) & (rgb[:, 2] < 100)
    assert (frames[-1].depth_m > 0).mean() > 0.5 and red.sum() > 100
    status = twin_status(plate.hostname, plate.camera_port)
    assert status["dirt_removed_fraction"] == 0.0 and status["camera_frames_sent"] >= 3


def test_a_stopped_twin_camera_is_a_named_fault(plate):
    from tactex.perception.twin_camera import TwinCameraSource

    source = TwinCameraSource(plate.hostname, plate.camera_port, timeout_s=1.0)
    try:
        source.read()
        plate.process.send_signal(signal.SIGUSR2)  # the twin's frames stop; the connection stays open
        try:
            with pytest.raises(CameraStreamEnded, match="sent no frame within 1 s"):
                for _ in range(100):  # the frames already on their way are still read
                    source.read()
        finally:
            plate.process.send_signal(signal.SIGUSR2)  # and on again
        source.read()  # the stream opens again
    finally:
        source.close()
