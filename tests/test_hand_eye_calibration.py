"""tactex calibrate hand-eye in simulation: a board of geoms, the arm around it, AX = XB; the mount
recovered within 2 mm and 0.5° from at most 15 poses, and the refusals (too few poses, no board,
one-axis motions) as one line each."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.cli import main
from tactex.errors import InputError

cv2 = pytest.importorskip("cv2", reason="opencv-python-headless is not installed (the realsense extra)")

pytestmark = pytest.mark.timeout(300)


def _rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("method", ["tsai", "park"])
def test_a_moved_mount_is_recovered(method) -> None:
    from tactex.tasks.hand_eye_calibration import HandEyeConfig, calibrate_in_simulation

    result = calibrate_in_simulation(HandEyeConfig(poses=12, method=method), mount_tilt_deg=(2.0, -3.0, 5.0),
                                     mount_shift_m=(0.004, -0.006, 0.01))
    mm, deg = result.error()
    print(f"{method}: {len(result.residuals)} poses, mount off by {mm:.3f} mm and {deg:.4f}°, largest residual "
          f"{max(r.position_mm for r in result.residuals):.3f} mm")
    assert len(result.residuals) <= 15 and mm < 2.0 and deg < 0.5
    assert all(r.position_mm < 2.0 and r.rotation_deg < 0.5 for r in result.residuals)


def test_a_board_painted_into_a_frame_is_the_board_seen_where_nothing_hides_it() -> None:
    from tactex.perception.frame import CameraIntrinsics
    from tactex.sim.board import ChessBoard, overlay_board, render_colour

    board = ChessBoard(centre_m=(0.35, 0.45, 0.0))
    k = CameraIntrinsics(160, 120, 120.0, 120.0, 79.5, 59.5)
    pose = np.eye(4)  # looking straight down at the board's centre from 0.3 m
    pose[:3, :3] = np.diag([1.0, -1.0, -1.0])
    pose[:3, 3] = [0.35, 0.45, 0.3]
    alone = render_colour(board, pose, k)
    table = np.full((k.height, k.width, 3), round(0.4 * 255), dtype=np.uint8)  # the table's grey, as render_colour
    depth = np.full((k.height, k.width), 0.3, dtype=np.float32)  # the table 1 mm under the board's face
    painted = overlay_board(table, depth, board, pose, k)
    assert np.abs(painted.astype(int) - alone.astype(int)).max() <= 1
    assert (painted < 30).mean() > 0.1 and (painted > 230).mean() > 0.1  # dark and light squares in view
    # an object 5 cm in front of the board's left half hides it there, and the frame keeps the object's colour
    front = depth.copy()
    front[:, : k.width // 2] = 0.25
    hidden = overlay_board(np.full_like(table, 200), front, board, pose, k)
    assert (hidden[:, : k.width // 2 - 1] == 200).all() and (hidden[:, k.width // 2 + 1:] < 30).any()


def test_the_command_writes_what_hand_eye_reads(tmp_path, capsys) -> None:
    from tactex.tasks.hand_eye import load_hand_eye

    out = tmp_path / "cam.json"
    assert main(["calibrate", "hand-eye", "--poses", "8", "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "pose  1:" in said and "against the simulated mount" in said
    pose = load_hand_eye(out)
    assert abs(pose[2, 2] - 1.0) < 1e-3  # the tactex tool's camera looks along the tool axis


def _one_line_exit_2(capsys, argv, words) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len([e for e in err if "error" in e]) == 1 and words in err[-1], err


def test_refusals_are_one_line(tmp_path, capsys) -> None:
    out = str(tmp_path / "cam.json")
    _one_line_exit_2(capsys, ["calibrate", "hand-eye", "--poses", "2", "--out", out], "--poses 10 or more")
    _one_line_exit_2(capsys, ["calibrate", "hand-eye", "--method", "magic", "--out", out], "tsai")
    _one_line_exit_2(capsys, ["calibrate", "hand-eye", "--out", str(tmp_path / "cam.txt")], ".json or .npy")


def test_a_board_not_found_names_what_to_check(tmp_path, capsys, monkeypatch) -> None:
    from tactex.sim.board import ChessBoard
    from tactex.tasks import hand_eye_calibration as he

    with pytest.raises(InputError, match=r"found from 0 of 4 poses .* --board 7 4"):
        he.calibrate_in_simulation(he.HandEyeConfig(poses=4), board=ChessBoard(7, 4), scene_board=ChessBoard())
    monkeypatch.setattr(he, "render_colour", lambda board, pose, k: np.full((k.height, k.width, 3), 90, np.uint8))
    _one_line_exit_2(capsys, ["calibrate", "hand-eye", "--poses", "4", "--out", str(tmp_path / "cam.json")],
                     "found from 0 of 4 poses")


def test_rotations_about_one_axis_are_refused() -> None:
    from tactex.sim.board import ChessBoard
    from tactex.tasks.hand_eye_calibration import calibrate_in_simulation, check_motions
    from tactex.tasks.runner import tool_rotation_for_normal

    board = ChessBoard()
    down = tool_rotation_for_normal(np.array([0.0, 0.0, 1.0]))
    poses = []
    for k, roll in enumerate((-30.0, -10.0, 10.0, 30.0)):
        pose = np.eye(4)
        pose[:3, :3] = down @ _rot_z(roll)
        pose[:3, 3] = np.asarray(board.centre_m) + np.array([0.01 * k, 0.0, 0.35]) - pose[:3, :3] @ [-0.07, 0.0, -0.12]
        poses.append(pose)
    with pytest.raises(InputError, match="one axis only"):
        calibrate_in_simulation(board=board, tool_poses=poses)
    still = [np.eye(4)] * 4
    with pytest.raises(InputError, match="barely rotate"):
        check_motions(still)
    tilted = [np.eye(4) for _ in range(3)]
    tilted[1][:3, :3] = _rot_z(20.0)
    tilted[2][:3, :3] = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    check_motions(tilted)


@pytest.mark.parametrize("answer", [None, "done"])
def test_taught_poses_ended_before_the_first_one_say_so(monkeypatch, answer) -> None:
    """--taught whose input ends (EOF) or says 'done' before a pose is taught: said as such, not as a board found
    from 0 of 0 poses; no robot or camera is asked for anything."""
    import tactex.tasks.hand_eye_robot as her
    from tactex.sim.board import ChessBoard
    from tactex.tasks.hand_eye_calibration import HandEyeConfig
    from tactex.tasks.robot import RealRobotParams

    class _Camera:
        def close(self) -> None:
            pass

    def ask(_prompt: str) -> str:
        if answer is None:
            raise EOFError
        return answer

    monkeypatch.setattr(her, "_wrist_camera", lambda *args: _Camera())
    with pytest.raises(InputError, match="no pose was taught: " + ("the end of the input" if answer is None else
                                                                  "'done'")):
        her.calibrate_taught(HandEyeConfig(poses=4), ChessBoard(), RealRobotParams(robot_ip="127.0.0.254",
                                                                                   camera="twin"), ask=ask)
