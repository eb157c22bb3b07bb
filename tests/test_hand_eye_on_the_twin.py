"""tactex calibrate hand-eye --robot franka against tactex twin: the twin's camera sits off tactex's nominal mount
and a chessboard lies on its table; the arm visits the poses through libfranka's protocol, and the calibration
finds the mount within 2 mm and 0.5° from at most 15 poses; the same with poses taught by hand (this test's own
client moves the arm between two presses of Enter, as a person would in guiding mode). Without a board on the
table: one line, exit 2, and torque control ended (a new client takes the robot at once)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("cv2", reason="opencv-python-headless is not installed (the realsense extra)")
pytest.importorskip("pylibfranka", reason="needs the franka extra: EXTRAS='dev fast franka' make test")
pytest.importorskip("franky_sim", reason="needs the franka extra: EXTRAS='dev fast franka' make test")

from tactex.twin.process import TwinProcess

pytestmark = [pytest.mark.franka, pytest.mark.timeout(900)]

#: The late-answer guard's budget on a shared 2-core machine (see tests/test_franka_backend.py) [ms].
TWIN_LATE = ["--late-abort-ms", "5000"]
#: A hang guard on a calibration's end [s], not a time budget.
RUN_WITHIN_S = 600.0
SHIFT_MM = (4.0, -3.0, 6.0)
TILT_DEG = (1.5, -1.0, 2.0)


def _calibrate(twin: TwinProcess, out, *args: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "tactex.cli", "calibrate", "hand-eye", "--robot", "franka", "--robot-ip",
           twin.hostname, "--camera", "twin", "--camera-port", str(twin.camera_port), *TWIN_LATE, "--out", str(out),
           *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=RUN_WITHIN_S)


def test_the_twins_camera_mount_is_recovered_through_the_robot(tmp_path):
    from tactex.perception.mount import mount_offset
    from tactex.sim.scene import SceneConfig
    from tactex.tasks.hand_eye import load_hand_eye
    from tactex.tasks.robot import nominal_tool_T_camera

    args = ["--board", "9", "6", "--camera-mount-shift-mm", *map(str, SHIFT_MM),
            "--camera-mount-tilt-deg", *map(str, TILT_DEG)]
    with TwinProcess("plate", args) as twin:
        done = _calibrate(twin, tmp_path / "cam.json", "--poses", "12")
    assert done.returncode == 0, done.stderr
    found = load_hand_eye(str(tmp_path / "cam.json"))
    truth = nominal_tool_T_camera(SceneConfig(object_name="plate")) @ mount_offset(TILT_DEG, np.array(SHIFT_MM) / 1e3)
    mm = float(np.linalg.norm(found[:3, 3] - truth[:3, 3]) * 1e3)
    rel = truth[:3, :3].T @ found[:3, :3]
    deg = float(np.degrees(np.arccos(np.clip((np.trace(rel) - 1.0) / 2.0, -1.0, 1.0))))
    print(f"twin mount recovered within {mm:.3f} mm and {deg:.4f}°\n{done.stdout}")
    assert mm < 2.0 and deg < 0.5
    poses = done.stdout.count("pose ")
    assert 3 <= poses <= 15 and "board found" in done.stderr


def test_no_board_on_the_twins_table_is_one_line_and_the_robot_is_free(tmp_path):
    from tactex.robots.libfranka_backend import FrankaConfig, LibfrankaBackend

    with TwinProcess("plate") as twin:
        done = _calibrate(twin, tmp_path / "cam.json", "--poses", "3")
        LibfrankaBackend(FrankaConfig(robot_ip=twin.hostname)).close()  # torque control ended: a new client connects
    assert done.returncode == 2, done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert "the board was found from 0 of 3 poses" in last and "--board-centre-m" in last, done.stderr
    assert "Traceback" not in done.stderr and not (tmp_path / "cam.json").exists()


def test_a_robot_stop_mid_calibration_is_a_stopped_run_exit_1_and_nothing_written(tmp_path, monkeypatch, capsys):
    # the robot stops the second move (a reflex, staged): as a clean or a wipe stopped by the robot, exit code 1
    # and "stopped early" (not 2, which says the command was refused before anything ran), and the arm is free
    from tactex.cli import main
    from tactex.errors import RobotReflexError
    from tactex.robots.libfranka_backend import FrankaConfig, LibfrankaBackend
    from tactex.robots.loop import ControlLoop

    moves = []
    move_joints = ControlLoop.move_joints

    def stopping(self, *args, **kwargs):
        moves.append(1)
        if len(moves) == 2:
            self.backend.pause()  # torque control ends, as libfranka ends it on a reflex
            raise RobotReflexError("libfranka ControlException: a reflex, staged by the test")
        return move_joints(self, *args, **kwargs)

    monkeypatch.setattr(ControlLoop, "move_joints", stopping)
    out = tmp_path / "cam.json"
    with TwinProcess("plate", ["--board", "9", "6"]) as twin:
        code = main(["calibrate", "hand-eye", "--robot", "franka", "--robot-ip", twin.hostname, "--camera", "twin",
                     "--camera-port", str(twin.camera_port), *TWIN_LATE, "--out", str(out), "--poses", "3"])
        LibfrankaBackend(FrankaConfig(robot_ip=twin.hostname)).close()  # torque control ended: a new client connects
    err = capsys.readouterr().err
    assert code == 1, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("tactex calibrate: stopped early: RobotReflexError: libfranka ControlException: a reflex")
    assert "(after 1 view(s) of the board; no hand-eye written" in last and not out.exists()


def _hand(twin: TwinProcess, poses):
    """A person's hand on the twin's arm: each call moves it (torque control from this process) to the next pose
    and lets go (the connection closed, the arm resting where it was put)."""
    from tactex.robots.libfranka_backend import FrankaConfig, LibfrankaBackend
    from tactex.robots.loop import ControlLoop
    from tactex.sim.scene import SceneConfig

    scene = SceneConfig(object_name="plate")
    for pose in poses:
        backend = LibfrankaBackend(FrankaConfig(robot_ip=twin.hostname, late_abort_ms=5000.0), tool=scene.tool,
                                   ik_scene=scene)
        try:
            loop = ControlLoop(backend)
            loop.move_joints(backend.solve_ik(pose[:3, 3], pose[:3, :3]), settle_s=0.5)
        finally:
            backend.close()
        yield


def test_taught_poses_recover_the_mount_too(tmp_path):
    from tactex.perception.mount import mount_offset
    from tactex.sim.board import BESIDE_OBJECTS_XY_M, ChessBoard
    from tactex.sim.scene import SceneConfig
    from tactex.tasks.hand_eye import load_hand_eye
    from tactex.tasks.hand_eye_calibration import HandEyeConfig, generated_tool_poses
    from tactex.tasks.robot import nominal_tool_T_camera

    nominal = nominal_tool_T_camera(SceneConfig(object_name="plate"))
    board = ChessBoard(centre_m=(*BESIDE_OBJECTS_XY_M, 0.0))
    poses = generated_tool_poses(board, HandEyeConfig(poses=8, seed=3), nominal)
    args = ["--board", "9", "6", "--camera-mount-shift-mm", *map(str, SHIFT_MM),
            "--camera-mount-tilt-deg", *map(str, TILT_DEG)]
    with TwinProcess("plate", args) as twin:
        cmd = [sys.executable, "-m", "tactex.cli", "calibrate", "hand-eye", "--robot", "franka", "--taught",
               "--robot-ip", twin.hostname, "--camera", "twin", "--camera-port", str(twin.camera_port),
               "--poses", "15", "--out", str(tmp_path / "cam.json")]
        proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)
        said = []
        try:
            for k, _ in enumerate(_hand(twin, poses), start=1):
                proc.stdin.write("\n")
                proc.stdin.flush()
                while f"pose {k}: board" not in (said[-1] if said else ""):  # the view is taken
                    line = proc.stderr.readline()
                    assert line, "".join(said)
                    said.append(line)
            _, err = proc.communicate("done\n", timeout=RUN_WITHIN_S)
        finally:
            if proc.poll() is None:
                proc.kill()
    assert proc.returncode == 0, "".join(said) + err
    assert "".join(said).count("board found") == len(poses)
    found = load_hand_eye(str(tmp_path / "cam.json"))
    truth = nominal @ mount_offset(TILT_DEG, np.array(SHIFT_MM) / 1e3)
    mm = float(np.linalg.norm(found[:3, 3] - truth[:3, 3]) * 1e3)
    rel = truth[:3, :3].T @ found[:3, :3]
    deg = float(np.degrees(np.arccos(np.clip((np.trace(rel) - 1.0) / 2.0, -1.0, 1.0))))
    print(f"taught: twin mount recovered within {mm:.3f} mm and {deg:.4f}° from {len(poses)} poses")
    assert mm < 2.0 and deg < 0.5
