"""TEC's loop on a Franka with its wrist camera, over the real protocols against ``tactex twin``: capture,
clean, back to the camera, re-measure, with the twin's own count of the dirt; and its camera faults (the
twin's stream stopped mid-run, a RealSense recording that ends mid-run), each a named fault with torque
control ended, the data saved and exit 1.

Each run is real time on the twin (tens of seconds of robot time); the faults force an early trip back to
the camera (``--vision-max-steps``) so that they come soon.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip("pylibfranka", reason="needs the franka extra: EXTRAS='dev fast franka' make test")
pytest.importorskip("franky_sim", reason="needs the franka extra: EXTRAS='dev fast franka' make test")

from tactex.twin.process import TwinProcess

pytestmark = [pytest.mark.franka, pytest.mark.timeout(900)]

#: The late-answer guard's budget on a shared 2-core machine (see tests/test_franka_backend.py) [ms].
TWIN_LATE = ["--late-abort-ms", "5000"]
#: A hang guard on a run's end [s], not a time budget.
RUN_WITHIN_S = 600.0
#: How long after a stalled tick a torque-rate clip is the stall's [s]: the controller answers the jumped state
#: within a few ticks (a burst of 5 after a 6 ms stall on a loaded machine).
STALL_ECHO_S = 0.05


def _clean(twin: TwinProcess, out, *args: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "tactex.cli", "clean", "--robot", "franka", "--robot-ip", twin.hostname, *TWIN_LATE,
           "--quiet", "--no-video", "--out", str(out), *args]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _finish(proc: subprocess.Popen) -> tuple[int, str]:
    try:
        _, err = proc.communicate(timeout=RUN_WITHIN_S)
    finally:
        if proc.poll() is None:
            proc.kill()
    return proc.returncode, err


def test_tec_loop_on_the_twin_with_its_camera(tmp_path):
    with TwinProcess("plate") as twin:
        out = tmp_path / "plate"
        code, err = _finish(_clean(twin, out, "--camera", "twin", "--camera-port", str(twin.camera_port)))
        status = twin.status()
    assert code == 0, err
    m = json.loads((out / "metrics.json").read_text())
    assert m["aborted"] == "" and m["target_source"] == "camera" and m["dirt_truth"] == "twin"
    # the run's dirt is the twin's own count (the status file is written every 0.5 s, after the run's last ask)
    assert m["dirt_removed_fraction"] == pytest.approx(status["dirt_removed_fraction"], abs=0.005)
    assert m["dirt_removed_fraction"] >= 0.95
    assert m["vision_updates"] >= 1 and m["captures"] == m["vision_updates"] + 1
    assert m["force_within_20pct_fraction"] >= 0.9
    # the arm's wrench estimate is what the flange feels through the sponge, not the pad's contact force,
    # whose steps over the height field jump (tactex.twin.wrench)
    assert m["max_contact_force_n"] <= 2.0 * m["force_set_point_n"]
    # a restart of torque control after a capture's or an IK's pause stepped the torque (8 clipped ticks on
    # the way back to the camera) before it was blended in from the robot's own command; runs since clip
    # none. A machine loaded enough to stall the loop (or the twin beside it) still clips in the ticks after a
    # stall, whose state jumped: those are the machine's, the others the program's
    # the events mark where a burst of clipped ticks began (the count counts the ticks); the run keeps the times
    # of its first stalls only, so a burst after the last one kept, when more were counted, cannot be judged
    bursts = [e["t"] for e in json.loads((out / "events.json").read_text()) if e["kind"] == "torque_rate_limit"]
    stalls = np.asarray(m["loop_stalls_t_s"])
    assert len(bursts) <= m["torque_rate_clip_ticks"] and (len(bursts) == 0) == (m["torque_rate_clip_ticks"] == 0)
    kept_until = stalls[-1] if m["loop_stalls"] > len(stalls) else np.inf
    judged = [t for t in bursts if t <= kept_until]
    ours = [t for t in judged if not np.any((stalls <= t + 1e-9) & (t - stalls <= STALL_ECHO_S))]
    assert len(ours) <= 4, (bursts, m["torque_rate_clip_ticks"], m["loop_stalls"], stalls.tolist())
    assert m["capture_time_s"] > 0.0 and len(m["capture_times_s"]) == m["captures"]


def _wait_for(twin: TwinProcess, predicate, what: str, timeout_s: float = 300.0) -> None:
    status = twin.wait_status(predicate, timeout_s=timeout_s)
    assert predicate(status), f"{what} never came: {status}"


def _fault_metrics(out, code: int, err: str, fault: str) -> dict:
    assert code == 1, err
    assert "stopped early" in err and fault in err, err
    m = json.loads((out / "metrics.json").read_text())
    assert m["aborted"].startswith(fault) and m["partial"] is True
    assert (out / "series.npz").is_file() and m["captures"] >= 1  # what ran before the fault is kept
    return m


def _robot_free(twin: TwinProcess) -> None:
    """Torque control has ended and the connection is closed: a new client takes the robot at once."""
    from tactex.robots.libfranka_backend import FrankaConfig, LibfrankaBackend

    LibfrankaBackend(FrankaConfig(robot_ip=twin.hostname)).close()


def test_the_twins_camera_stopping_mid_run_is_a_named_fault(tmp_path):
    with TwinProcess("plate", ["--camera-width", "320", "--camera-height", "240"]) as twin:
        out = tmp_path / "run"
        proc = _clean(twin, out, "--camera", "twin", "--camera-port", str(twin.camera_port), "--vision-max-steps",
                      "60")
        try:
            # the first capture is done and the robot cleans: then the camera goes silent
            _wait_for(twin, lambda st: st.get("camera_frames_sent", 0) >= 3 and st.get("contact_force_n", 0) > 5.0,
                      "contact after the first capture")
            twin.kill(signal.SIGUSR2)
            code, err = _finish(proc)
        finally:
            if proc.poll() is None:
                proc.kill()
        _robot_free(twin)
    m = _fault_metrics(out, code, err, "CameraStreamEnded")
    assert "sent no frame" in m["aborted"] and m["contact_time_s"] > 0.0


def _recording_of_the_capture_view(path, frames: int):
    """A RealSense recording of ``frames`` identical frames of the plate seen from the clean's capture pose."""
    from tactex.perception.rs_recording import RecordedPair, write_realsense_recording
    from tactex.robots.mujoco_backend import MujocoBackend
    from tactex.tasks.clean import CleanConfig, _capture_pose

    cfg = CleanConfig(object_name="plate")
    scene = cfg.scene()
    pos, rot = _capture_pose(scene, cfg)
    sim = MujocoBackend(scene)
    try:
        sim.reset(q0=sim.solve_ik(pos, rot))
        frame = sim.render_depth()
    finally:
        sim.close()
    pair = RecordedPair(frame.depth_m, frame.rgb)
    return write_realsense_recording(path, [pair] * frames, frame.intrinsics, frame.intrinsics, np.eye(4))


def _clean_on_a_recording(tmp_path, frames: int, *args: str):
    """``tactex clean --camera realsense`` on the twin's plate, playing a recording of ``frames`` frames of the
    capture view; (run folder, exit code, stderr), the robot checked free afterwards."""
    try:
        import pyrealsense2  # noqa: F401
    except ImportError as exc:
        pytest.skip(f"pyrealsense2 cannot be imported here: {exc}")
    recording = _recording_of_the_capture_view(tmp_path / "plate.db3", frames)
    with TwinProcess("plate", camera_port=0) as twin:
        out = tmp_path / "run"
        t0 = time.monotonic()
        code, err = _finish(_clean(twin, out, "--camera", "realsense", "--playback", str(recording), *args))
        assert time.monotonic() - t0 < RUN_WITHIN_S
        _robot_free(twin)
    return out, code, err


def test_a_recording_that_ends_mid_run_is_a_named_fault(tmp_path):
    # frames for one capture of three, and one more: the re-measurement's capture runs out
    out, code, err = _clean_on_a_recording(tmp_path, 4, "--capture-frames", "3", "--vision-max-steps", "60")
    m = _fault_metrics(out, code, err, "CameraStreamEnded")
    assert "recording" in m["aborted"] and m["captures"] == 1 and m["contact_time_s"] > 0.0


def test_a_recording_that_ends_in_the_first_capture_keeps_the_moves_to_the_camera(tmp_path):
    # two frames for a capture of three: the first capture runs out, before any cloud exists
    out, code, err = _clean_on_a_recording(tmp_path, 2, "--capture-frames", "3")
    assert code == 1, err
    assert "stopped early" in err and "CameraStreamEnded" in err, err
    m = json.loads((out / "metrics.json").read_text())
    assert m["aborted"].startswith("CameraStreamEnded") and m["partial"] is True
    assert m["captures"] == 0 and m["target_source"] == "camera" and m["n_points"] == 0
    # the move to the capture pose is kept, and the report says why it has no cloud
    with np.load(out / "series.npz", allow_pickle=False) as z:
        assert len(z["t"]) > 0 and float(z["t"][-1]) > 0.5
    assert not (out / "cloud.npz").exists()
    assert "no cloud: the run stopped before its first capture" in (out / "report.html").read_text()


def test_a_twin_camera_port_that_does_not_answer_is_named_before_the_robot_is_touched(tmp_path, capsys):
    import socket

    from tactex.cli import main

    with socket.socket() as s:  # a port nobody serves
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    # no twin runs either: had the robot been connected first, its refusal would be the error
    code = main(["clean", "--robot", "franka", "--robot-ip", "127.0.0.1", "--camera", "twin", "--camera-port",
                 str(port), "--quiet", "--no-video", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 2 and f"127.0.0.1:{port}" in err and "Franka" not in err, err
