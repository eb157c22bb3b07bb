"""The real-robot parts that need no robot: the Net F/T protocol (client and server on loopback),
the vision process, the small LAPACK solve of the 1 kHz path, the control-core option."""

from __future__ import annotations

import errno
import os
import signal
import struct
import time

import numpy as np
import pytest

from tactex.cli import main
from tactex.control.linalg import solve
from tactex.errors import ConfigError, SensorFault
from tactex.robots.check import check_robot, link_verdict
from tactex.robots.cpu_latency import CpuLatencyRequest
from tactex.robots.libfranka_backend import FrankaConfig, pin_control_thread
from tactex.robots.netft import (
    CMD_START_REALTIME,
    RECORD_SIZE,
    NetFTClient,
    NetFTServer,
    pack_record,
    pack_request,
    parse_netft_address,
    unpack_record,
    unpack_request,
)
from tactex.robots.wrench import NetFTWrenchSource

WRENCH = np.array([1.5, -2.0, 15.0, 0.1, -0.2, 0.03])


# -- Net F/T ------------------------------------------------------------------------------------------
def test_rdt_request_and_record_round_trip():
    assert unpack_request(pack_request(CMD_START_REALTIME, 0)) == (CMD_START_REALTIME, 0)
    with pytest.raises(ValueError, match="header"):
        unpack_request(b"\x00\x01\x00\x02\x00\x00\x00\x00")
    rec = pack_record(7, 9, 0, WRENCH, 1e6, 1e6)
    assert len(rec) == RECORD_SIZE == 36
    rdt, ft, status, w = unpack_record(rec, 1e6, 1e6)
    assert (rdt, ft, status) == (7, 9, 0)
    np.testing.assert_allclose(w, WRENCH, atol=1e-6)
    # counts saturate at int32 instead of wrapping
    _, _, _, big = unpack_record(pack_record(1, 1, 0, np.full(6, 1e9), 1e6, 1e6), 1e6, 1e6)
    assert np.all(big > 2000.0)


@pytest.mark.parametrize(("text", "expected"), [("192.168.1.1", ("192.168.1.1", 49152)),
                                                ("127.0.0.1:5000", ("127.0.0.1", 5000))])
def test_netft_address(text, expected):
    assert parse_netft_address(text) == expected


@pytest.mark.parametrize("text", ["", ":5000", "h:0", "h:x"])
def test_netft_address_errors_name_the_option(text):
    with pytest.raises(ConfigError, match="netft:"):
        parse_netft_address(text)


def _until(read, done, hang_s: float = 20.0):
    """``read()`` again until ``done(value)``: a loaded machine delays the stream's threads, so a test
    waits for what it checks instead of for a fixed time (``hang_s`` [s] is a hang guard)."""
    t_end = time.monotonic() + hang_s
    while True:
        value = read()
        if done(value):
            return value
        assert time.monotonic() < t_end, f"still {value!r} after {hang_s} s"
        time.sleep(0.005)


def test_netft_stream_over_loopback_tares_and_reports_a_dead_stream():
    reading = {"w": WRENCH.copy()}
    server = NetFTServer(lambda: reading["w"], port=0).start()
    client = NetFTClient("127.0.0.1", server.address[1], tare_samples=20, timeout_s=0.05)
    try:
        client.start()
        w, age = client.latest()
        np.testing.assert_allclose(w, 0.0, atol=1e-5)  # tared at the start reading
        reading["w"] = WRENCH + np.array([0.0, 0.0, 5.0, 0, 0, 0])
        w, age = _until(lambda: client.latest(), lambda r: abs(r[0][2] - 5.0) < 1e-5)
        assert age < 0.05  # a fresh reading
        server.paused.set()
        time.sleep(0.1)
        w, _ = _until(lambda: client.latest(), lambda r: client.lost)  # silent for more than timeout_s
        assert np.isnan(w).all()
        n_paused = client.records
        server.paused.clear()
        _until(lambda: client.latest(), lambda r: not client.lost)
        _until(lambda: client.latest(), lambda r: client.records > n_paused + 20)  # streaming again
    finally:
        client.close()
        server.close()


def test_netft_age_is_taken_when_the_socket_was_read():
    """A reading fresh when the socket was last read stays valid however long the caller then waits
    (the robot's late cycle is not the sensor's dropout); the next read finds the stream silent."""
    server = NetFTServer(lambda: WRENCH.copy(), port=0).start()
    client = NetFTClient("127.0.0.1", server.address[1], tare_samples=0, timeout_s=0.05)
    try:
        client.start()
        client.poll()
        server.paused.set()
        time.sleep(0.1)  # longer than timeout_s, without looking at the socket
        w, age = client.latest(poll=False)
        assert np.isfinite(w).all() and age < 0.05
        w, age = client.latest()  # looks now: nothing arrived for 0.1 s
        assert np.isnan(w).all() and age > 0.05
    finally:
        client.close()
        server.close()


def test_netft_without_a_box_is_a_named_fault():
    client = NetFTClient("127.0.0.1", 9, tare_samples=1)  # the discard port: nothing answers
    with pytest.raises(SensorFault, match="sent no data"):
        client.start(wait_s=0.3)


def test_netft_source_removes_the_tool_weight_at_any_orientation():
    """Tared hanging down, the source reads zero contact wrench when the tool is turned sideways."""
    mass, com, tcp = 0.42, np.array([0.0, 0.0, 0.06]), 0.16
    g = np.array([0.0, 0.0, -9.81])
    down = np.diag([1.0, -1.0, -1.0])

    class Fake:
        bias = np.zeros(6)

        def __init__(self):
            self.raw = np.zeros(6)

        def start(self):
            self.bias = self.raw.copy()

        def poll(self):
            return 0

        def latest(self, poll=True):
            return self.raw - self.bias, 0.0

        def close(self):
            pass

    def raw_weight(rot):  # what a real sensor reads with no contact: minus the weight and its moment
        w = mass * (rot.T @ g)
        return np.concatenate([-w, -np.cross(com, w)])

    fake = Fake()
    fake.raw = raw_weight(down)
    source = NetFTWrenchSource(fake, mass, com, tcp)
    source.start(world_R_tool=down)
    c, s = np.cos(np.pi / 2), np.sin(np.pi / 2)
    side = down @ np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])
    fake.raw = raw_weight(side)
    np.testing.assert_allclose(source.wrench_tool(None, side), 0.0, atol=1e-9)
    fake.raw = raw_weight(down) + np.array([0.0, 0.0, 12.0, 0, 0, 0])  # pressing 12 N along tool z
    assert source.wrench_tool(None, down)[2] == pytest.approx(12.0)
    # prefetched after a command with that state's orientation: the next tick gets that wrench once,
    # whatever orientation it passes; the tick after computes its own again
    fake.raw = raw_weight(side)
    source.prefetch(side)
    fake.raw = raw_weight(down) + np.array([0.0, 0.0, 5.0, 0, 0, 0])  # a record that came after the prefetch
    np.testing.assert_allclose(source.wrench_tool(None, down), 0.0, atol=1e-9)
    assert source.wrench_tool(None, down)[2] == pytest.approx(5.0)
    fake.raw = np.full(6, np.nan)  # a lost stream is NaN either way, and counted once per tick
    source.prefetch(down)
    assert np.isnan(source.wrench_tool(None, down)).all() and source.lost_ticks == 1


# -- vision process -----------------------------------------------------------------------------------
def test_vision_process_estimates_the_panel_and_a_dead_worker_is_a_fault():
    from tactex.robots.vision_process import VisionProcess
    from tactex.tasks.runner import TOOL_DOWN

    vp = VisionProcess({"kind": "sim", "scene": {"object_name": "sine_panel"},
                        "estimator": {"max_grid_cells": 2000, "axis_start_m": -0.02}})
    try:
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = TOOL_DOWN, [0.5, 0.0, 0.12]
        estimate = None
        t_end = time.monotonic() + 20.0
        while estimate is None and time.monotonic() < t_end:
            vp.publish_pose(0.0, pose)
            estimate = vp.latest()
            time.sleep(0.01)
        assert estimate is not None and estimate.valid
        assert estimate.normal_world[2] > 0.9  # the panel's crest under the tool faces up
        # the loop's cheaper publish writes what publish_pose writes
        from tactex.robots.vision_process import _P_SEQ, _P_T, _read

        pose[:3, 3] = [0.51, -0.02, 0.13]
        vp.publish_pose(1.5, pose)
        _, by_pose = _read(vp._buf, _P_SEQ, _P_T, 17)
        vp.publish_tool(2.5, pose[:3, :3], pose[:3, 3])
        _, by_tool = _read(vp._buf, _P_SEQ, _P_T, 17)
        assert by_tool[0] == 2.5 and by_pose[0] == 1.5
        np.testing.assert_array_equal(by_tool[1:], by_pose[1:])
        np.testing.assert_array_equal(by_tool[1:], pose.reshape(16))
        os.kill(vp.proc.pid, signal.SIGKILL)
        vp.proc.wait(timeout=5)
        with pytest.raises(SensorFault, match="vision process stopped"):
            vp.check()
    finally:
        vp.close()


def test_vision_process_runs_at_normal_priority_under_a_real_time_loop():
    """The worker does not inherit a SCHED_FIFO control loop's priority (it would run each frame to
    its end ahead of everything on its core)."""
    from tactex.robots.vision_process import VisionProcess

    before = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
    except (PermissionError, OSError):
        pytest.skip("needs permission for SCHED_FIFO (root or an rtprio limit)")
    try:
        vp = VisionProcess({"kind": "sim", "scene": {"object_name": "sine_panel"}})
    finally:
        os.sched_setscheduler(0, before[0], before[1])
    try:
        assert os.sched_getscheduler(vp.proc.pid) == os.SCHED_OTHER
    finally:
        vp.close()


def test_vision_process_refuses_an_unknown_source():
    from tactex.robots.vision_process import VisionProcess

    with pytest.raises(ConfigError, match="sim' or 'realsense"):
        VisionProcess({"kind": "webcam"})


# -- the 1 kHz path -----------------------------------------------------------------------------------
def test_small_solve_is_numpys_answer_and_refuses_a_singular_matrix(rng):
    a = rng.normal(size=(7, 7))
    a = a @ a.T + np.eye(7)
    b = rng.normal(size=7)
    np.testing.assert_allclose(solve(a, b), np.linalg.solve(a, b), rtol=1e-12, atol=1e-14)
    bm = rng.normal(size=(7, 3))
    np.testing.assert_allclose(solve(a, bm), np.linalg.solve(a, bm), rtol=1e-12, atol=1e-14)
    a_copy = a.copy()
    solve(a, b)
    assert np.array_equal(a, a_copy)  # inputs untouched
    with pytest.raises(np.linalg.LinAlgError):
        solve(np.zeros((3, 3)), np.ones(3))


def test_control_cpu_option():
    assert pin_control_thread(-1) == "not pinned"
    with pytest.raises(ConfigError, match="control_cpu"):
        FrankaConfig(robot_ip="1.2.3.4", control_cpu=(os.cpu_count() or 1))
    with pytest.raises(ConfigError, match="control_cpu"):
        FrankaConfig(robot_ip="1.2.3.4", control_cpu=True)


def _s32(value: int) -> bytes:
    return struct.pack("=i", value)  # what the kernel's PM QoS node reads


@pytest.fixture
def qos_device(tmp_path, monkeypatch):
    """A regular file standing in for /dev/cpu_dma_latency (accepted as the device)."""
    from tactex.robots import cpu_latency

    device = tmp_path / "cpu_dma_latency"
    device.write_bytes(b"")
    monkeypatch.setattr(cpu_latency, "_is_pm_qos_device", lambda fd: True)
    return device


def test_cpu_latency_request_writes_the_bound_and_holds_it_until_released(qos_device):
    request = CpuLatencyRequest(0, device=str(qos_device))
    assert request.held and "≤ 0 µs" in request.description
    fd = request._fd
    os.fstat(fd)  # open while held
    assert qos_device.read_bytes() == _s32(0)
    request.release()
    request.release()  # idempotent
    assert not request.held
    with pytest.raises(OSError):
        os.fstat(fd)
    CpuLatencyRequest(25, device=str(qos_device)).release()
    assert qos_device.read_bytes() == _s32(25)


def test_cpu_latency_request_goes_on_without_the_device_and_checks_its_value(tmp_path, qos_device):
    missing = CpuLatencyRequest(0, device=str(tmp_path / "absent"))
    assert not missing.held and "not limited" in missing.description and "absent" in missing.description
    assert not missing.permission_denied
    off = CpuLatencyRequest(-1, device=str(qos_device))
    assert not off.held and off.description == "idle states not limited"
    assert qos_device.read_bytes() == b""  # no request made
    for bad in (1.5, -2, 2**31, True):
        with pytest.raises(ConfigError, match="cpu_latency_us"):
            CpuLatencyRequest(bad)
        with pytest.raises(ConfigError, match="cpu_latency_us"):
            FrankaConfig(robot_ip="1.2.3.4", cpu_latency_us=bad)


def test_cpu_latency_request_holds_nothing_on_a_plain_file_or_a_fifo(tmp_path):
    plain = tmp_path / "plain"
    plain.write_bytes(b"")
    request = CpuLatencyRequest(0, device=str(plain))
    assert not request.held and "not a PM QoS device" in request.description
    assert plain.read_bytes() == b""
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    request = CpuLatencyRequest(0, device=str(fifo))  # no reader: must not block
    assert not request.held


def test_cpu_latency_request_says_when_permission_is_missing(tmp_path, monkeypatch):
    from tactex.robots import cpu_latency

    def refuse(path, flags):  # what a user without the udev rule gets (root may open any file)
        raise PermissionError(errno.EACCES, "Permission denied", path)

    monkeypatch.setattr(cpu_latency.os, "open", refuse)
    request = CpuLatencyRequest(0, device=str(tmp_path / "cpu_dma_latency"))
    assert not request.held and request.permission_denied and "Permission denied" in request.description


# -- the link check's verdict (no robot needed) ---------------------------------------------------
def _link_metrics(ticks=1000, lost=0, success=1.0, compute_p999=150.0):
    return {"loop_ticks": ticks, "lost_cycles": lost, "min_command_success_rate": success,
            "loop_compute_us": {"p99.9": compute_p999}}


def test_link_verdict_fails_on_lost_cycles_and_success_rate_and_warns_on_compute():
    assert link_verdict(_link_metrics(lost=1), 1.0) == ([], [])  # 1 of 1001: 0.0999 %
    problems, _ = link_verdict(_link_metrics(lost=2), 1.0)
    assert len(problems) == 1 and "2 cycles lost" in problems[0] and "allowed 0.1 %" in problems[0]
    assert link_verdict(_link_metrics(lost=2), 1.0, max_lost_fraction=0.05) == ([], [])
    problems, _ = link_verdict(_link_metrics(success=0.9), 1.0)
    assert len(problems) == 1 and "success rate fell to 0.900" in problems[0]
    assert link_verdict(_link_metrics(success=0.9), 1.0, min_success_rate=0.85) == ([], [])
    problems, warnings = link_verdict(_link_metrics(compute_p999=400.0), 1.0)
    assert problems == [] and len(warnings) == 1 and "400 µs" in warnings[0]


@pytest.mark.parametrize("value", ["-1", "100", "nan"])
def test_robot_check_rejects_a_bad_lost_share_before_connecting(value, capsys):
    # 127.0.0.254 has no robot: the check must refuse the option before it tries to connect
    code = main(["robot", "check", "--robot-ip", "127.0.0.254", "--max-lost-percent", value])
    err = capsys.readouterr().err
    assert code == 2 and "--max-lost-percent must be in [0, 100)" in err and "127.0.0.254" not in err
    with pytest.raises(ConfigError, match="lost cycles must be in"):
        check_robot(FrankaConfig(robot_ip="127.0.0.254"), max_lost_fraction=float(value))


@pytest.mark.parametrize("value", ["-0.1", "1.5", "nan"])
def test_robot_check_rejects_a_bad_success_rate_before_connecting(value, capsys):
    code = main(["robot", "check", "--robot-ip", "127.0.0.254", "--min-success-rate", value])
    err = capsys.readouterr().err
    assert code == 2 and "--min-success-rate must be in [0, 1]" in err and "127.0.0.254" not in err
    with pytest.raises(ConfigError, match="success rate must be in"):
        check_robot(FrankaConfig(robot_ip="127.0.0.254"), min_success_rate=float(value))


def test_robot_check_passes_its_limits_to_the_check(monkeypatch, capsys):
    import tactex.robots.check as check

    seen = {}

    def fake_check(cfg, duration_s, note=None, max_lost_fraction=None, min_success_rate=None, bare=None):
        seen.update(max_lost_fraction=max_lost_fraction, min_success_rate=min_success_rate, bare=bare)
        raise ConfigError("stop here")

    monkeypatch.setattr(check, "check_robot", fake_check)
    code = main(["robot", "check", "--robot-ip", "127.0.0.254", "--max-lost-percent", "2", "--min-success-rate",
                 "0.8"])
    assert code == 2 and "stop here" in capsys.readouterr().err
    assert seen == {"max_lost_fraction": pytest.approx(0.02), "min_success_rate": 0.8, "bare": False}
    code = main(["robot", "check", "--robot-ip", "127.0.0.254", "--bare"])
    assert code == 2 and seen["bare"] is True


def test_scheduling_is_given_back_as_it_was():
    from tactex.robots.scheduling import Scheduling

    before = Scheduling.current()
    assert before is not None and before.cpus
    try:
        os.sched_setaffinity(0, {min(before.cpus)})
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
    except (PermissionError, OSError):
        before.restore()
        pytest.skip("needs permission for SCHED_FIFO (root or an rtprio limit)")
    assert Scheduling.current() != before
    assert before.restore() == []
    assert Scheduling.current() == before
