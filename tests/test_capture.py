"""tactex capture on the simulated scene, the capture's settings, and the tool pose read from a Franka state."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from tactex.cli import main
from tactex.errors import ConfigError

pytestmark = pytest.mark.timeout(300)


def test_sim_capture_writes_a_base_frame_scan_with_normals(tmp_path, capsys) -> None:
    from tactex.pointcloud.io import load_ply

    out = tmp_path / "scan.ply"
    assert main(["capture", "--camera", "sim", "--object", "plate", "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "target: red by hue" in said and "points are target" in said
    cloud = load_ply(out)
    assert cloud.colors is not None and cloud.normals is not None and cloud.n_target == 0
    assert cloud.points[:, 2].min() >= 0.002  # the table is cut away
    # ... and the plate's well is kept: its middle, 4 mm above the table, is in the scan
    assert np.min(np.linalg.norm(cloud.points[:, :2] - [0.5, 0.0], axis=1)) < 0.005
    assert np.median(cloud.normals[:, 2]) > 0.9  # the plate's inside, normals up towards the camera
    # the plate sits at 0.5 0 0: the scan is in the robot base frame
    np.testing.assert_allclose(np.median(cloud.points[:, :2], axis=0), [0.5, 0.0], atol=0.02)


def test_capture_settings_are_checked(tmp_path, capsys) -> None:
    from tactex.tasks.capture import CaptureConfig

    with pytest.raises(ConfigError, match="box_m"):
        CaptureConfig(box_m=(0, 0, 0, 1, 1, 0))
    with pytest.raises(ConfigError, match="in metres"):
        CaptureConfig(box_m=(0, 0, 0, 1000, 1000, 1000))
    with pytest.raises(ConfigError, match="views"):
        CaptureConfig(views=0)
    out = str(tmp_path / "scan.ply")
    for argv, words in (
        (["--camera", "sim", "--playback", "x.db3", "--out", out], "--camera sim takes its pose"),
        (["--camera", "sim", "--out", str(tmp_path / "scan.txt")], "PLY"),
    ):
        assert main(["capture", *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and words in err, err
    with pytest.raises(SystemExit) as info:  # not offered yet
        main(["capture", "--camera", "twin", "--out", out])
    assert info.value.code == 2 and "invalid choice" in capsys.readouterr().err


def test_the_tool_pose_from_a_franka_state() -> None:
    from tactex.robots.libfranka_backend import flange_T_tcp
    from tactex.robots.read_pose import base_T_tool_from_state
    from tactex.sim.tool import ToolGeometry

    c, s = np.cos(0.3), np.sin(0.3)
    base_T_flange = np.array([[c, -s, 0, 0.4], [s, c, 0, 0.1], [0, 0, 1, 0.5], [0, 0, 0, 1.0]])
    flange_T_ee = np.eye(4)
    flange_T_ee[2, 3] = 0.1034  # whatever end effector Desk has set
    col_major = lambda m: m.T.reshape(16).tolist()  # noqa: E731
    state = SimpleNamespace(O_T_EE=col_major(base_T_flange @ flange_T_ee), F_T_EE=col_major(flange_T_ee))
    tool = ToolGeometry()
    np.testing.assert_allclose(base_T_tool_from_state(state, tool), base_T_flange @ flange_T_tcp(tool), atol=1e-12)


@pytest.mark.franka
def test_the_tool_pose_read_from_the_twin_is_the_arms() -> None:
    """The pose read from the twin's state (whatever end effector it reports) is where tactex's own
    kinematics put the TCP at the twin's joint positions."""
    pylibfranka = pytest.importorskip("pylibfranka", reason="needs the franka extra")
    pytest.importorskip("franky_sim", reason="needs the franka extra")
    from tactex.robots.mujoco_backend import MujocoBackend
    from tactex.robots.read_pose import read_tool_pose
    from tactex.robots.scheduling import Scheduling, kept_scheduling
    from tactex.sim.scene import SceneConfig
    from tactex.twin.process import TwinProcess

    with TwinProcess("plate") as twin:
        before = Scheduling.current()
        base_T_tool = read_tool_pose(twin.hostname)
        assert Scheduling.current() == before  # libfranka raised the thread to real time; it is given back
        with kept_scheduling():
            q = np.asarray(pylibfranka.Robot(twin.hostname, pylibfranka.RealtimeConfig.kIgnore).read_once().q)
    sim = MujocoBackend(SceneConfig(object_name="plate"))
    fk = sim.reset(q0=q).ee_pose
    sim.close()
    np.testing.assert_allclose(base_T_tool[:3, 3], fk[:3, 3], atol=1e-3)
    np.testing.assert_allclose(base_T_tool[:3, :3], fk[:3, :3], atol=1e-3)


def test_views_around_the_object_are_merged() -> None:
    from tactex.sim.scene import SceneConfig
    from tactex.tasks.capture import CaptureConfig, SimCaptureSource, capture_cloud

    scene = SceneConfig(object_name="bowl", camera_width=320, camera_height=240)
    one = capture_cloud(SimCaptureSource(scene), CaptureConfig(views=1))
    three = capture_cloud(SimCaptureSource(scene), CaptureConfig(views=3))
    assert len(three) > len(one)
    # every point near the merged cloud's lies within a voxel of the single view's where they overlap
    from scipy.spatial import cKDTree

    d, _ = cKDTree(three.points).query(one.points)
    assert np.median(d) < 0.003
