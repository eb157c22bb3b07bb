"""``tactex twin``: franky-sim with our scene, driven over libfranka's protocol by pylibfranka, and
its wrist F/T over Net F/T. One twin process serves the module (start-up ~5 s); every test is a
few seconds of wall time.

The twin holds a flat plane raised to 5 cm under the TCP's start pose (so a press is short), fully
marked (so any rub removes dirt).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest

REASON = "needs the franka extra: EXTRAS='dev fast franka' make test"
plf = pytest.importorskip("pylibfranka", reason=REASON)
pytest.importorskip("franky_sim", reason=REASON)

from tactex.robots.netft import NetFTClient  # noqa: E402
from tactex.robots.scheduling import kept_scheduling  # noqa: E402
from tactex.sim.tool import ToolGeometry, flange_R_tool  # noqa: E402
from tactex.twin.config import TwinConfig  # noqa: E402
from tactex.twin.process import TwinProcess  # noqa: E402

pytestmark = pytest.mark.franka

TOOL = ToolGeometry()  # the twin's default tool
PLANE_TOP_Z = 0.41  # plane object at z = 0.40 (+ its 1 cm lift) [m]
FORCE_TOLERANCE = 0.2  # relative agreement of the two wrench sources and the command [-]
PRESS_N = 15.0  # commanded force [N] (VA-UFIC)
WRONG_LOAD_KG = 0.5  # a load declared this much heavier than the tool [kg]
NO_CONTACT_N = 0.05  # the robot's wrench estimate without contact stays below this [N, N·m]
STREAM_HANG_GUARD_S = 30.0  # a Net F/T stream that sends nothing for this long has stopped [s]


@pytest.fixture(scope="module", autouse=True)
def _scheduling_given_back():
    """These tests drive libfranka directly, which raises the thread to SCHED_FIFO 99 when it connects and
    starts control; the rest of the session (and every process it starts) must not run at that priority."""
    with kept_scheduling():
        yield


@pytest.fixture(scope="module")
def twin():
    with TwinProcess("plane", ["--object-position", "0.554", "0", "0.40", "--marking", "full"]) as proc:
        yield proc


@pytest.fixture(scope="module")
def robot(twin):
    r = plf.Robot(twin.hostname, plf.RealtimeConfig.kIgnore)
    state = r.read_once()
    f_T_ne = np.asarray(state.F_T_NE).reshape(4, 4, order="F")
    f_T_tcp = np.eye(4)
    f_T_tcp[:3, :3] = flange_R_tool()
    f_T_tcp[2, 3] = TOOL.tcp_offset_m
    r.set_EE((np.linalg.inv(f_T_ne) @ f_T_tcp).T.reshape(16).tolist())
    mass, com = TOOL.calibrated_mass_properties()
    r.set_load(float(mass), (flange_R_tool() @ com).tolist(), (np.eye(3) * 1e-3).reshape(9).tolist())
    for _ in range(20):  # the first state read after a command can be one from before it
        r.read_once()
    yield r


def _pose(state) -> np.ndarray:
    return np.asarray(state.O_T_EE).reshape(4, 4, order="F")


def _impedance_loop(robot, model, duration_s: float, target, ft: NetFTClient | None = None):
    """Cartesian impedance (translation 600 N/m, rotation 30 N·m/rad) on the start pose, with
    ``target(t, p0) -> (pd (3,), f_z_world or None)``: with a force, z is force-controlled (damped).
    Returns per-tick rows [t, z, K_F_ext z, Net F/T z, commanded force]."""
    kt, kr = 600.0, 30.0
    dt_, dr = 2 * np.sqrt(kt), 2 * np.sqrt(kr)
    ctrl = robot.start_torque_control()
    state, _ = ctrl.readOnce()
    t0 = state.time.to_sec()
    p0, r0 = _pose(state)[:3, 3].copy(), _pose(state)[:3, :3].copy()
    rows = []
    while True:
        state, _ = ctrl.readOnce()
        t = state.time.to_sec() - t0
        pose = _pose(state)
        p, rot = pose[:3, 3], pose[:3, :3]
        jac = np.asarray(model.zero_jacobian(state)).reshape(6, 7, order="F")
        v = jac @ np.asarray(state.dq)
        pd, fz = target(t, p0)
        e_o = 0.5 * sum(np.cross(rot[:, i], r0[:, i]) for i in range(3))
        force = np.r_[kt * (pd - p) - dt_ * v[:3], kr * e_o - dr * v[3:]]
        if fz is not None:
            force[2] = fz - 100.0 * v[2]
        tau = jac.T @ force + np.asarray(model.coriolis(state))
        cmd = plf.Torques(np.clip(tau, -80, 80).tolist())
        ft_z = ft.latest()[0][2] if ft is not None else np.nan
        rows.append([t, p[2], state.K_F_ext_hat_K[2], ft_z, -fz if fz is not None else 0.0])
        if t >= duration_s:
            cmd.motion_finished = True
        ctrl.writeOnce(cmd)
        if cmd.motion_finished:
            return np.array(rows)


def test_twin_config_checks():
    with pytest.raises(Exception, match="unknown object"):
        TwinConfig(object_name="nope")
    with pytest.raises(Exception, match="ft_port"):
        TwinConfig(ft_port=70000)
    with pytest.raises(Exception, match="realtime_factor"):
        TwinConfig(realtime_factor=-1.0)
    with pytest.raises(Exception, match="joint_friction_residual"):
        TwinConfig(joint_friction_residual=1.5)
    for window in (0.0, 1.0, float("nan")):
        with pytest.raises(Exception, match="command_window_ms"):
            TwinConfig(command_window_ms=window)


def test_tool_joints_do_not_inherit_frankys_arm_defaults():
    """The sponge's slide joint sits in franky-sim's childclass "fr3" tree: it must keep MuJoCo's plain
    defaults (as in tactex's scene), not a Franka joint's rotor inertia and gear friction (a 0.2 kg pad
    with 1.1 N of dry friction hopped on the surface, 0–40 N tick to tick, once the arm stiffened)."""
    import xml.etree.ElementTree as ET

    import mujoco

    from tactex.twin.twin import Twin

    twin = Twin(TwinConfig(object_name="plane"))
    m = mujoco.MjModel.from_xml_string(ET.tostring(twin.sim.scene, encoding="unicode"))
    pad = m.joint("pad_slide").dofadr[0]
    assert m.dof_armature[pad] == 0.0 and m.dof_frictionloss[pad] == 0.0
    assert m.jnt_stiffness[m.joint("pad_slide").id] == pytest.approx(TwinConfig().tool_stiffness_n_per_m)
    # franky-sim's arm and finger stubs keep theirs
    assert m.dof_armature[m.joint("robot0_fr3_joint7").dofadr[0]] > 0.0
    assert m.dof_frictionloss[m.joint("robot0_finger_joint1").dofadr[0]] > 0.0


def test_client_connects_and_reads_state(twin, robot):
    assert twin.ready_line.startswith(f"twin ready: robot {twin.hostname}:1337, Net F/T udp")
    state = robot.read_once()
    assert np.asarray(state.q).shape == (7,)
    pose = _pose(state)
    # set_EE put O_T_EE at our TCP: tool z points down at the start pose, the plane 5 cm below
    assert pose[2, 2] < -0.99
    assert 0.03 < pose[2, 3] - PLANE_TOP_Z < 0.08
    assert state.m_load == pytest.approx(TOOL.calibrated_mass_properties()[0])
    # no contact: the estimate (the flange's reading less the declared load) is the arm's small sway only
    assert np.abs(state.K_F_ext_hat_K).max() < NO_CONTACT_N
    status = twin.wait_status(lambda s: s.get("connected"), 30.0)
    assert status["connected"] and status["ticks"] > 0


def test_a_load_declared_heavier_than_the_tool_reads_as_a_push_down_as_on_a_franka(twin, robot):
    """The twin's wrench estimate is the flange's reading less the load the client declared (set_load), as a
    Franka's is from its joint torques: declared 0.5 kg too heavy, the robot seems to push down by its weight."""
    mass, com = TOOL.calibrated_mass_properties()
    inertia = (np.eye(3) * 1e-3).reshape(9).tolist()
    com_flange = (flange_R_tool() @ com).tolist()
    robot.set_load(float(mass) + WRONG_LOAD_KG, com_flange, inertia)
    try:
        for _ in range(20):  # the first state read after a command can be one from before it
            state = robot.read_once()
        assert state.m_load == pytest.approx(mass + WRONG_LOAD_KG)
        # K's z points down at the start pose: the robot's force on the environment is +z
        assert state.K_F_ext_hat_K[2] == pytest.approx(WRONG_LOAD_KG * 9.81, abs=0.05)
        assert np.abs(state.K_F_ext_hat_K[:2]).max() < 0.05
    finally:
        robot.set_load(float(mass), com_flange, inertia)
        for _ in range(20):
            robot.read_once()


def test_netft_stream_reads_tool_weight_then_zero_after_tare(twin):
    raw = NetFTClient(twin.hostname, twin.ft_port, tare_samples=0)
    raw.start()
    try:
        # the tool reads its weight only at rest: the twin may still be settling the arm (slower than
        # real time on a loaded machine), so wait until two readings 0.1 s apart agree
        weight, deadline = raw.latest()[0], time.monotonic() + 5.0
        while time.monotonic() < deadline:
            time.sleep(0.1)
            later = raw.latest()[0]
            if abs(later[2] - weight[2]) < 0.01:
                break
            weight = later
        # the raw reading holds the tool's weight: the flange pulls the tool up, i.e. along −z of the
        # sensor (z points down at the start pose)
        assert weight[2] == pytest.approx(-TOOL.calibrated_mass_properties()[0] * 9.81, rel=0.02)
        # the stream goes on; its rate depends on how busy the machine is, so only its flow is checked
        t0, n0 = time.monotonic(), raw.records
        while raw.records - n0 < 100 and time.monotonic() - t0 < STREAM_HANG_GUARD_S:
            raw.poll()
            time.sleep(0.0005)
        assert raw.records - n0 >= 100, f"Net F/T sent {raw.records - n0} records in {STREAM_HANG_GUARD_S} s"
    finally:
        raw.close()
    tared = NetFTClient(twin.hostname, twin.ft_port)
    tared.start()
    try:
        assert np.abs(tared.latest()[0]).max() < 0.05
    finally:
        tared.close()


def test_press_netft_matches_franka_estimate_and_command(twin, robot):
    """Lower the TCP onto the plane and press with 15 N: the Net F/T force along tool z, the
    twin's K_F_ext_hat_K (the robot's force on the environment along K z) and the command agree."""
    model = robot.load_model()
    ft = NetFTClient(twin.hostname, twin.ft_port)
    ft.start()  # tared out of contact

    def target(t, p0):
        if t < 0.6:  # descend at 10 cm/s to 5 mm above the plane, in impedance
            return np.r_[p0[:2], max(PLANE_TOP_Z + 0.005, p0[2] - 0.1 * t)], None
        return np.r_[p0[:2], p0[2]], -PRESS_N  # then push down with the force

    try:
        rows = _impedance_loop(robot, model, 1.6, target, ft)
    finally:
        ft.close()
    settled = rows[rows[:, 0] > 1.2]
    k_f, ft_z = settled[:, 2].mean(), settled[:, 3].mean()
    assert settled[:, 1].max() < PLANE_TOP_Z + 0.002  # the pad is on the plane
    assert ft_z == pytest.approx(PRESS_N, rel=FORCE_TOLERANCE)
    assert k_f == pytest.approx(PRESS_N, rel=FORCE_TOLERANCE)
    assert ft_z == pytest.approx(k_f, rel=FORCE_TOLERANCE)


def test_rubbing_removes_marking(twin, robot):
    model = robot.load_model()
    before = twin.status().get("dirt_removed_fraction", 0.0)

    def target(t, p0):
        if t < 0.6:
            return np.r_[p0[:2], max(PLANE_TOP_Z + 0.005, p0[2] - 0.1 * t)], None
        # press with 15 N while sliding ±2 cm along x at up to ~6 cm/s
        return np.r_[p0[0] + 0.02 * np.sin(3.0 * (t - 0.6)), p0[1], p0[2]], -PRESS_N

    _impedance_loop(robot, model, 1.8, target)
    status = twin.wait_status(lambda s: s.get("dirt_removed_fraction", 0.0) > before, 30.0)
    assert status["dirt_removed_fraction"] > before
    assert status["max_contact_force_n"] > 0.5 * PRESS_N


def test_export_cloud_has_red_target_on_object(tmp_path):
    from tactex.pointcloud import load_cloud
    from tactex.sim.scene import SceneConfig

    out = tmp_path / "plate.ply"
    run = subprocess.run([sys.executable, "-m", "tactex.cli", "twin", "--object", "plate", "--export-cloud",
                          str(out)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    cloud = load_cloud(out)
    red = cloud.colors[:, 0] > 0.99
    assert cloud.n_target > 0 and np.array_equal(red & (cloud.colors[:, 1] < 0.01), cloud.target > 0)
    assert cloud.spacing == pytest.approx(0.003, rel=0.2)
    # on the object's surface, in the robot base frame
    scene = SceneConfig(object_name="plate")
    pos, rot = scene.object_pose()
    local = (cloud.points - pos) @ rot
    surf = scene.sim_object.surface
    assert np.abs(local[:, 2] - surf.height(local[:, 0], local[:, 1])).max() < 1e-6
    assert np.allclose(cloud.points[:, :2].mean(axis=0), pos[:2], atol=0.02)


def test_address_in_use_is_one_line_error(twin):
    run = subprocess.run([sys.executable, "-m", "tactex.cli", "twin", "--object", "plane", "--hostname",
                          twin.hostname], capture_output=True, text=True, timeout=120)
    assert run.returncode != 0
    assert f"{twin.hostname}:1337" in run.stderr and "--hostname" in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1


def test_sigterm_stops_the_twin_cleanly():
    with TwinProcess("plane") as proc:
        status = proc.wait_status(lambda s: s.get("ticks", 0) > 0, 30.0)
        assert status["ticks"] > 0
        code = proc.close()
    assert code == 0, proc.stderr()


def test_a_twin_ends_with_the_process_that_started_it(tmp_path):
    script = tmp_path / "killed.py"
    script.write_text("import os, signal\nfrom tactex.twin.process import TwinProcess\n"
                      "t = TwinProcess('plane').start()\nprint(t.process.pid, flush=True)\n"
                      "os.kill(os.getpid(), signal.SIGKILL)\n")
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    pid = int(run.stdout.split()[-1])
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.1)
    os.kill(pid, 9)
    pytest.fail(f"the twin (pid {pid}) outlived the process that started it by 10 s")


def test_command_success_rate_counts_late_answers(twin, robot):
    """A client that answers promptly, then every 10th state 3 ms late, then promptly again: the twin's
    control_command_success_rate (the share of the last 100 cycles whose answer came within its
    window) falls while answers are late and recovers once the late ones are over 100 cycles old, as
    a real Franka's would; franky-sim alone reports 1.0 whatever the client does."""
    ctrl = robot.start_torque_control()
    rates = []
    for k in range(600):
        state, _ = ctrl.readOnce()
        rates.append(state.control_command_success_rate)
        if 150 <= k < 400 and k % 10 == 5:
            time.sleep(0.003)
        cmd = plf.Torques([0.0] * 7)  # the arm holds under zero torque (the load is declared)
        cmd.motion_finished = k == 599
        ctrl.writeOnce(cmd)
    rates = np.array(rates)
    prompt, late, after = np.median(rates[100:150]), rates[300:400].min(), np.median(rates[550:600])
    # each late answer costs the twin at least 2 cycles: ≥ 20 of the last 100 in the late phase; a
    # loaded machine may cost the prompt phases a few too, hence the relative margins
    assert late < prompt - 0.1 and late < after - 0.1, (prompt, late, after)
    # the status file is rewritten every 0.5 s: one written during the late phase already shows a drop, so
    # wait for the motion's minimum itself, kept after the motion ended
    status = twin.wait_status(lambda s: s.get("command_success_rate_min", 1.0) <= late + 0.05, 30.0)
    assert status["command_success_rate_min"] <= late + 0.05, status
