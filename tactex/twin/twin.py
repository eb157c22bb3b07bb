"""``tactex twin``: our scene inside franky-sim, a protocol-level stand-in for a real Franka.

franky-sim (the ``franka`` extra) speaks libfranka's network protocol on ``HOST:1337`` over its
own MuJoCo world. :func:`run_twin` adds our object (with its dirt), our table and our wrist
assembly (F/T sensor, tool body, sponge on a slide joint: :func:`tactex.sim.tool.tool_xml`) to that
world in place of the Franka hand (:mod:`tactex.twin.scene`), and publishes the simulated wrist
sensor over ATI's Net F/T protocol (:class:`tactex.robots.netft.NetFTServer`, UDP). A pylibfranka
client, e.g. :class:`tactex.robots.libfranka_backend.LibfrankaBackend`, then drives it as it would
drive the arm; the twin knows how much of the marking a cleaning run removed (:attr:`Twin.status`).

Beyond stock franky-sim, the robot state carries the contact wrench (:mod:`tactex.twin.wrench`),
and the Net F/T record is the raw reading of MuJoCo's force/torque sensors at the sensor site (the
wrench the flange exerts on the tool, sensor frame, the tool's weight included): the input of
:class:`tactex.sim.ft_sensor.FTSensorModel`; a client tares it out of contact.
"""

from __future__ import annotations

import errno
import json
import math
import os
import signal
import socket
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from tactex.errors import MissingDependencyError, SimulationError, TactexError
from tactex.twin.clock import CommandRate, TwinClock, fine_timer_slack
from tactex.twin.command_channel import CommandChannel, check_franky_internals
from tactex.twin.config import TwinConfig
from tactex.twin.scene import ROBOT_PREFIX, STUB_MASS_KG, STUB_Z_M, add_scene
from tactex.twin.wrench import contact_aware_robot_class, tool_wrench_on_environment

__all__ = ["FRANKA_PORTS", "Twin", "run_twin"]

#: TCP ports franky-sim serves on: the robot (libfranka) and the gripper.
FRANKA_PORTS = (1337, 1338)


def _franky() -> tuple[Any, Any, Any, Any]:
    try:
        from franky_sim import SimulationServer
        from franky_sim.base_simulator import RobotParameters
        from franky_sim.mujoco_simulator import FrankaMujocoRobot, MujocoSimulator
    except ImportError as exc:
        raise MissingDependencyError("franky-sim", "franka", "tactex twin") from exc
    return SimulationServer, RobotParameters, FrankaMujocoRobot, MujocoSimulator


def _check_addresses(config: TwinConfig) -> None:
    """Bind every address the twin needs once, to fail early with a message that names it."""
    tried = [(socket.SOCK_STREAM, port, "tcp") for port in FRANKA_PORTS]
    if config.ft_port:
        tried.append((socket.SOCK_DGRAM, config.ft_port, "udp"))
    if config.camera_port:
        tried.append((socket.SOCK_STREAM, config.camera_port, "tcp"))
    for kind, port, proto in tried:
        sock = socket.socket(socket.AF_INET, kind)
        if kind == socket.SOCK_STREAM:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as franky-sim does
        try:
            sock.bind((config.hostname, port))
        except OSError as exc:
            what = ("--port-ft" if proto == "udp" else "--port-camera" if port == config.camera_port
                    else "--hostname (e.g. 127.0.0.2)")
            in_use = exc.errno == errno.EADDRINUSE
            reason = "is in use (another twin or franky-sim?)" if in_use else f"cannot be bound ({exc.strerror})"
            raise TactexError(f"{proto} {config.hostname}:{port} {reason}: stop what serves there, or pick another "
                              f"address with {what}") from None
        finally:
            sock.close()


class Twin:
    """franky-sim with our scene, its Net F/T server and the status; :meth:`run` serves until
    :meth:`stop` (or a signal, from :func:`run_twin`)."""

    def __init__(self, config: TwinConfig) -> None:
        self.config = config
        self.scene = config.scene_config()
        self._simulation_server_cls, robot_parameters, franka_robot, simulator = _franky()
        import mujoco

        from tactex.sim.dirt import DirtField, PrestonParams

        self._mujoco = mujoco
        obj = self.scene.sim_object
        self.dirt = DirtField(obj.surface, self.scene.marking or obj.marking, self.scene.dirt_resolution_m,
                              PrestonParams(self.scene.preston_coefficient, self.scene.dirt_force_threshold_n,
                                            self.scene.tool_pad_radius_m))
        self.tool = self.scene.tool
        self._object_pos, self._object_rot = self.scene.object_pose()
        self.sim = simulator(enable_visualization=False)
        # no end effector in the dynamics model (the client declares the tool with set_load), except the
        # finger stubs' mass; the nominal EE is the flange
        params = robot_parameters(ee_mass=2 * STUB_MASS_KG, ee_com=(0.0, 0.0, STUB_Z_M), ee_tcp_xyz=(0.0, 0.0, 0.0),
                                  ee_tcp_rpy=(0.0, 0.0, 0.0), ee_inertia=(1e-9, 0, 0, 0, 1e-9, 0, 0, 0, 1e-9))
        self.robot = self.sim.add_robot(robot_parameters=params)
        self.robot.__class__ = contact_aware_robot_class(franka_robot)  # add_robot hard-codes its class
        self.robot._twin_ext = None
        self.robot._twin_on_robot = bool(config.ext_wrench_on_robot)
        add_scene(self.sim, self.scene)
        self._lock = threading.Lock()
        self._ft = np.zeros(6)  # latest raw F/T reading, handed to the Net F/T thread under the lock
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self.ticks = 0
        self.max_contact_force_n = 0.0
        self.pad_force_n = 0.0
        self.server: Any = None
        self.netft: Any = None
        self._last_status = (0.0, time.monotonic())
        self._rtf = float("nan")
        self.command_rate = CommandRate()
        self._wipe_due = False  # a wear update from the last step's contacts is pending
        self.camera: Any = None  # the camera server (tactex.twin.camera_server), once serving
        # a camera snapshot asked of the simulation thread, and the event it sets when taken
        self._snap_wanted = False
        self._snap_done = threading.Event()
        self._snap: tuple | None = None
        self._mount_error = config.camera_mount_error()

    # -- per-tick work (the simulation thread) -----------------------------------------------------
    def _setup_ids(self) -> None:
        mujoco = self._mujoco
        m, d = self.sim.model, self.sim.data
        self.model, self.data = m, d
        a, b = int(m.sensor("ft_force").adr[0]), int(m.sensor("ft_torque").adr[0])
        self._ft_force, self._ft_torque = d.sensordata[a:a + 3], d.sensordata[b:b + 3]
        robot_bodies = np.array([m.body(i).name.startswith(ROBOT_PREFIX) or i in self._tool_bodies(m)
                                 for i in range(m.nbody)])
        tool = self._tool_bodies(m)
        # the arm's links: their contacts count directly (the tool's reach the arm through the flange)
        self._geom_arm = (robot_bodies[m.geom_bodyid] & ~np.isin(m.geom_bodyid, sorted(tool))).tolist()
        self._geom_robot = robot_bodies[m.geom_bodyid].tolist()
        self._flange_body = m.body("flange").id
        self._ft_site = m.site("ft_site").id
        self._jacr = np.zeros((3, m.nv))
        self._flange_acc = np.zeros(6)
        self._flange_vel = np.zeros(6)
        self._w6 = np.zeros(6)  # the flange's wrench on the robot: force, moment about its origin
        self._tau_nv = np.zeros(m.nv)
        self._geom_body = m.geom_bodyid.tolist()
        self._dofs = list(self.robot._dof_addrs)
        # the firmware's friction compensation (see TwinConfig.joint_friction_residual)
        m.dof_frictionloss[self._dofs] *= float(self.config.joint_friction_residual)
        # franky-sim holds an idle arm (no client, between motions) with an explicit joint PD whose damping
        # on the wrist joints exceeds 2·I/dt of their inertia I (armature included): an explicit damper that
        # stiff is unstable, and without the joints' dry friction the wrist chatters at the torque limit.
        # Cap the damping at I/(2·dt) so the hold is stable without friction.
        full = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, full)
        inertia = np.diag(full)[self._dofs]
        self.robot.kv = np.minimum(np.asarray(self.robot.kv, dtype=float), 0.5 * inertia / float(m.opt.timestep))
        self._jacp = np.zeros((3, m.nv))
        self._c6 = np.zeros(6)
        self._pad_geom = m.geom("pad").id
        self._object_geom = m.geom("object_geom").id
        self._pad_body = m.body("pad").id
        self._pad_vel = np.zeros(6)
        self._pad_bottom = self.tool.pad_thickness_m / 2 if self.tool.pad_shape == "cylinder" else None
        self._sample = int(self.config.contact_sample_ticks)
        self._dt = float(m.opt.timestep)
        self._mj_contact_force = mujoco.mj_contactForce
        self._mj_jac = mujoco.mj_jac
        self._camera_id = m.camera("wrist_camera").id

    @staticmethod
    def _tool_bodies(m: Any) -> set[int]:
        flange = m.body("flange").id
        out = set()
        for i in range(m.nbody):
            j = i
            while j > 0:
                if j == flange:
                    out.add(i)
                    break
                j = int(m.body_parentid[j])
        return out

    def _post_step(self, _sim: Any) -> None:
        try:
            self._tick()
        except BaseException as exc:
            self._error = exc
            self._stop.set()
            raise

    def _tick(self) -> None:
        d = self.data
        with self._lock:
            self._ft[:3] = self._ft_force
            self._ft[3:] = self._ft_torque
        self.ticks += 1
        if self.netft is not None and self.ticks % self._ft_every == 0:
            self.netft.pump(self._ft)  # sampled at the physics step, sent at once: no thread, no lag
        self.robot._twin_ext = self._external_wrench()
        if d.ncon == 0:
            self.pad_force_n = 0.0
            return
        pad_fx = pad_fy = pad_fz = 0.0
        m, c6, pad = self.model, self._c6, self._pad_geom
        for i in range(d.ncon):
            con = d.contact[i]
            if con.geom1 != pad and con.geom2 != pad:
                continue
            self._mj_contact_force(m, d, i, c6)
            ux, uy, uz = (con.frame.reshape(3, 3).T @ c6[:3]).tolist()
            pad_fx, pad_fy, pad_fz = pad_fx + ux, pad_fy + uy, pad_fz + uz
        self.pad_force_n = math.sqrt(pad_fx * pad_fx + pad_fy * pad_fy + pad_fz * pad_fz)
        self.max_contact_force_n = max(self.max_contact_force_n, self.pad_force_n)
        if self.ticks % self._sample == 0:
            self._wipe_due = True  # done after the state has left (Twin._serve), off the step's time

    def _external_wrench(self) -> tuple:
        """What the robot's joint torques would say of the outside world this step (see
        :mod:`tactex.twin.wrench`): (force on the robot [N] and its moment about the world origin [N·m],
        world frame, and the joint torques [N·m]), from the flange's interaction with the tool less
        the declared load (a point mass: its weight and translational inertia), plus the contacts on the
        arm's links. Plain floats: it runs every step, where
        numpy's per-call overhead on 3-vectors would cost several times the physics step."""
        m, d, mujoco = self.model, self.data, self._mujoco
        body = self._flange_body
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = d.site_xmat[self._ft_site].tolist()
        fx, fy, fz = self._ft_force.tolist()
        tx, ty, tz = self._ft_torque.tolist()
        f_world = (r00 * fx + r01 * fy + r02 * fz, r10 * fx + r11 * fy + r12 * fz, r20 * fx + r21 * fy + r22 * fz)
        t_world = (r00 * tx + r01 * ty + r02 * tz, r10 * tx + r11 * ty + r12 * tz, r20 * tx + r21 * ty + r22 * tz)
        robot = self.robot
        cx, cy, cz = robot.F_x_Cload
        q00, q01, q02, q10, q11, q12, q20, q21, q22 = d.xmat[body].tolist()
        rx, ry, rz = q00 * cx + q01 * cy + q02 * cz, q10 * cx + q11 * cy + q12 * cz, q20 * cx + q21 * cy + q22 * cz
        ox, oy, oz = d.xpos[body].tolist()  # the flange's origin, where F_x_Cload is measured from
        px, py, pz = d.site_xpos[self._ft_site].tolist()  # the sensor's site: its moment is about it
        # the acceleration (less gravity) of the load's centre of mass, a point r of the flange: the origin's,
        # plus the angular acceleration's and the rotation's terms
        mujoco.mj_objectAcceleration(m, d, mujoco.mjtObj.mjOBJ_BODY, body, self._flange_acc, 0)
        mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, body, self._flange_vel, 0)
        bx, by, bz, ax, ay, az = self._flange_acc.tolist()
        wx, wy, wz = self._flange_vel[:3].tolist()
        vx, vy, vz = wy * rz - wz * ry, wz * rx - wx * rz, wx * ry - wy * rx  # ω × r
        acc = (ax + by * rz - bz * ry + wy * vz - wz * vy, ay + bz * rx - bx * rz + wz * vx - wx * vz,
               az + bx * ry - by * rx + wx * vy - wy * vx)
        force, moment = tool_wrench_on_environment(f_world, t_world, (px, py, pz), robot.m_load,
                                                   (ox + rx, oy + ry, oz + rz), acc)
        fx, fy, fz = -force[0], -force[1], -force[2]  # on the robot
        mx, my, mz = -moment[0], -moment[1], -moment[2]
        jacp, jacr = self._jacp, self._jacr
        self._mj_jac(m, d, jacp, jacr, d.site_xpos[self._ft_site], body)
        self._w6[:] = (fx, fy, fz, mx - (py * fz - pz * fy), my - (pz * fx - px * fz), mz - (px * fy - py * fx))
        np.dot(self._w6[:3], jacp, out=self._tau_nv)
        self._tau_nv += np.dot(self._w6[3:], jacr)
        tau = self._tau_nv[self._dofs]
        arm, robot_geom, body_of, c6 = self._geom_arm, self._geom_robot, self._geom_body, self._c6
        for i in range(d.ncon):
            con = d.contact[i]
            g1, g2 = int(con.geom1), int(con.geom2)
            if arm[g1] == arm[g2] or robot_geom[g1] == robot_geom[g2]:  # not an arm link's, or the robot's own
                continue
            self._mj_contact_force(m, d, i, c6)
            f = con.frame.reshape(3, 3).T @ c6[:3]  # on geom2, world frame
            if not arm[g2]:
                f = -f
            cx, cy, cz = con.pos.tolist()
            ux, uy, uz = f.tolist()
            fx, fy, fz = fx + ux, fy + uy, fz + uz
            mx, my, mz = mx + cy * uz - cz * uy, my + cz * ux - cx * uz, mz + cx * uy - cy * ux
            self._mj_jac(m, d, jacp, None, con.pos, body_of[g2 if arm[g2] else g1])
            tau = tau + jacp[:, self._dofs].T @ f
        return (fx, fy, fz), (mx, my, mz), tau

    def _wipe(self) -> None:
        """Preston wear under the pad from its contacts with the object (as MujocoBackend._wipe)."""
        d, m = self.data, self.model
        pad, obj = self._pad_geom, self._object_geom
        force = 0.0
        point = np.zeros(3)
        normal = np.zeros(3)
        for i in range(d.ncon):
            con = d.contact[i]
            g1, g2 = int(con.geom1), int(con.geom2)
            if not ((g1 == pad and g2 == obj) or (g1 == obj and g2 == pad)):
                continue
            self._mj_contact_force(m, d, i, self._c6)
            fn = float(self._c6[0])
            if fn <= 0.0:
                continue
            force += fn
            point += fn * con.pos
            normal += (fn if g2 == pad else -fn) * con.frame[:3]  # from the surface to the pad
        if force <= self.dirt.params.force_threshold_n:
            return
        point /= force
        normal /= np.linalg.norm(normal)
        if self._pad_bottom is not None:  # flat sponge: the footprint is the pad disc under the pad
            centre = d.xpos[self._pad_body] + d.xmat[self._pad_body].reshape(3, 3)[:, 2] * self._pad_bottom
            point = centre + float((point - centre) @ normal) * normal
        self._mujoco.mj_objectVelocity(m, d, self._mujoco.mjtObj.mjOBJ_BODY, self._pad_body, self._pad_vel, 0)
        v = self._pad_vel[3:]
        slip = math.sqrt(max(float(v @ v) - float(v @ normal) ** 2, 0.0))
        if slip > 0.0:
            point_obj = (point - self._object_pos) @ self._object_rot
            self.dirt.apply_wear(point_obj, force * slip * self._dt * self._sample)

    def _serve(self, server: Any, clock: TwinClock) -> None:
        """franky-sim's loop (commands, step, state) on ``clock``: the commands are taken as soon as
        the client's answer to the last state is in, or when its window closes; a cycle counts for
        libfranka's ``control_command_success_rate`` when that answer came within the window."""
        fine_timer_slack()
        servers = list(server.robot_servers)
        robot_server = servers[0]
        commands = CommandChannel(robot_server)
        rate, paced = self.command_rate, clock.period_s > 0.0  # unpaced, no command can be late
        monotonic, step = time.monotonic, self.sim.step
        try:
            while server.running:
                moving = paced and robot_server.current_motion_id != 0
                last = commands.last_sent()
                # out of a motion no answer is awaited: step at once, and the state waits for its time
                commands.take(servers, last, clock.process_at() if moving else None)
                rate.cycle(moving, commands.answered >= last)
                self.robot._twin_success = rate.rate
                step()
                clock.wait_until(clock.send_at())
                t2 = monotonic()
                for rs in servers:
                    rs.send_state()
                t3 = monotonic()
                clock.sent(t3 - t2, t3)
                if self._wipe_due:  # the contacts of this step are still in MuJoCo's data
                    self._wipe_due = False
                    self._wipe()
                if self._snap_wanted:
                    self._take_snapshot()
        except BaseException as exc:
            if self._error is None:
                self._error = exc
            self._stop.set()

    def _take_snapshot(self) -> None:
        """In the simulation thread, between two steps: what a camera frame depends on (the wrist camera's
        optical pose in the base frame, the object's pose, the simulated time, a copy of the dirt)."""
        from tactex.sim.camera import optical_R_mujoco_camera

        d, i = self.data, self._camera_id
        pose = np.eye(4)
        pose[:3, :3] = d.cam_xmat[i].reshape(3, 3) @ optical_R_mujoco_camera
        pose[:3, 3] = d.cam_xpos[i]
        pose = pose @ self._mount_error  # the camera as mounted, which a client calibrates
        self._snap = (pose, self._object_pos.copy(), self._object_rot.copy(), float(d.time), self.dirt.level.copy())
        self._snap_wanted = False
        self._snap_done.set()

    def camera_snapshot(self, timeout_s: float) -> tuple | None:
        """(base_T_camera, object position, object rotation, t [s], dirt levels) taken by the simulation
        thread at its next step; None when it takes no step within ``timeout_s`` [s]."""
        self._snap_done.clear()
        self._snap_wanted = True
        if not self._snap_done.wait(timeout_s):
            return None
        return self._snap

    def toggle_camera_stream(self) -> None:
        """Stop the camera's frames (the connection stays open), or start them again."""
        if self.camera is not None:
            if self.camera.paused.is_set():
                self.camera.paused.clear()
            else:
                self.camera.paused.set()

    def ft_reading(self) -> np.ndarray:
        """The latest raw wrist reading [N, N·m] (6,): sensor frame, the tool's weight included."""
        with self._lock:
            return self._ft.copy()

    # -- status ---------------------------------------------------------------------------------------
    def _connected(self) -> bool:
        rs = self.server.robot_servers[0] if self.server is not None and self.server.robot_servers else None
        return rs is not None and getattr(rs, "_FrankaServer__tcp_socket", None) is not None

    def status(self) -> dict:
        """Simulated time, ticks, dirt removed, contact force, client connections, real-time factor."""
        d = self.data
        sim_t = float(d.time) if d is not None else 0.0
        now = time.monotonic()
        t0, w0 = self._last_status
        if now - w0 > 0.05:
            self._rtf = (sim_t - t0) / (now - w0)
            self._last_status = (sim_t, now)
        remaining = self.dirt.remaining_fraction()
        return {
            "sim_time_s": sim_t,
            "ticks": self.ticks,
            "dirt_remaining_fraction": remaining,
            "dirt_removed_fraction": 1.0 - remaining,
            "max_contact_force_n": self.max_contact_force_n,
            "contact_force_n": self.pad_force_n,
            "connected": self._connected(),
            "ft_streaming": bool(self.netft is not None and self.netft._client is not None),
            "ft_records_sent": 0 if self.netft is None else self.netft.sent,
            "realtime_factor": self._rtf,
            "command_success_rate": self.command_rate.rate,
            "command_success_rate_min": self.command_rate.lowest,
            "object": self.config.object_name,
            "hostname": self.config.hostname,
            "ft_port": 0 if self.netft is None else int(self.netft.address[1]),
            "camera_port": 0 if self.camera is None else int(self.camera.address[1]),
            "camera_frames_sent": 0 if self.camera is None else self.camera.frames_sent,
        }

    def write_status(self) -> None:
        path = self.config.status_file
        if not path:
            return
        out = Path(path)
        tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
        status = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in self.status().items()}
        tmp.write_text(json.dumps(status) + "\n")
        os.replace(tmp, out)

    # -- lifecycle ------------------------------------------------------------------------------------
    def stop(self) -> None:
        self._stop.set()

    def toggle_ft_stream(self) -> None:
        """Stop the Net F/T stream, or start it again (the client sees a dead, then a live sensor)."""
        server = getattr(self, "netft", None)
        if server is not None:
            if server.paused.is_set():
                server.paused.clear()
            else:
                server.paused.set()

    def run(self, ready=None) -> None:
        """Serve until :meth:`stop`; ``ready(twin)`` is called once both servers listen.

        Raises:
            TactexError: an address is taken; SimulationError: the scene does not compile or the
            simulation loop failed.
        """
        from tactex.robots.netft import NetFTServer

        cfg = self.config
        _check_addresses(cfg)
        if cfg.status_file:
            Path(cfg.status_file).parent.mkdir(parents=True, exist_ok=True)
        with self.sim:
            server = self._simulation_server_cls(self.sim, hostname_candidates=[cfg.hostname])
            try:
                server.init()
            except OSError as exc:
                server.cleanup()
                raise TactexError(f"tcp {cfg.hostname}:{FRANKA_PORTS[0]}: {exc}; stop what serves there or pick "
                                  "another address with --hostname") from None
            except ValueError as exc:
                server.cleanup()
                raise SimulationError(f"the twin's scene for object '{cfg.object_name}' does not compile: {exc}") \
                    from exc
            self.server = server
            try:
                self._setup_ids()
                check_franky_internals(server.robot_servers[0])
                try:
                    self.netft = NetFTServer(self.ft_reading, cfg.hostname, cfg.ft_port, rate_hz=cfg.ft_rate_hz)
                except OSError as exc:
                    raise TactexError(f"udp {cfg.hostname}:{cfg.ft_port}: {exc.strerror}; stop what serves there "
                                      "or pick another port with --port-ft") from None
                self._ft_every = max(1, round(1.0 / (cfg.ft_rate_hz * self._dt)))
                if cfg.camera_port:
                    from tactex.twin.camera_server import TwinCameraServer

                    self.camera = TwinCameraServer(self, cfg.hostname, cfg.camera_port, cfg.camera_width,
                                                   cfg.camera_height, cfg.camera_rate_hz)
                self.sim.register_post_step_callback(self._post_step)
                period_s = 1e-3 / cfg.realtime_factor if cfg.realtime_factor > 0 else 0.0
                # franky-sim's run_async loop, with the robot's cadence (tactex.twin.clock)
                server.running = True
                clock = TwinClock(period_s, cfg.command_window_ms * 1e-3 * min(1.0, period_s / 1e-3))
                server.async_thread = threading.Thread(target=self._serve, args=(server, clock), name="twin-1khz",
                                                       daemon=True)
                server.async_thread.start()
                if ready is not None:
                    ready(self)
                while not self._stop.wait(cfg.status_period_s):
                    if server.async_thread is None or not server.async_thread.is_alive():
                        break
                    self.write_status()
                self.write_status()
            finally:
                server.cleanup()
                if self.netft is not None:
                    self.netft.close()
                if self.camera is not None:
                    self.camera.close()
        if self._error is not None:
            raise SimulationError(f"the twin's simulation loop failed: {self._error!r}") from self._error
        if server.async_thread is not None and not self._stop.is_set():
            raise SimulationError("the twin's simulation loop stopped unexpectedly (see the log above)")


def run_twin(config: TwinConfig, *, ready=None, handle_signals: bool = True) -> Twin:
    """Build the twin and serve until SIGTERM/SIGINT (when ``handle_signals``) or ``twin.stop()``;
    SIGUSR1 stops and restarts the Net F/T stream (a sensor drill). ``ready(twin)`` is called once
    it listens. Returns the stopped twin."""
    twin = Twin(config)
    previous = {}
    if handle_signals and threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGINT):
            previous[sig] = signal.signal(sig, lambda *_: twin.stop())
        # a dead-sensor drill: SIGUSR1 stops the Net F/T stream, the next SIGUSR1 starts it again
        previous[signal.SIGUSR1] = signal.signal(signal.SIGUSR1, lambda *_: twin.toggle_ft_stream())
        # and SIGUSR2 the camera's frames
        previous[signal.SIGUSR2] = signal.signal(signal.SIGUSR2, lambda *_: twin.toggle_camera_stream())
    try:
        twin.run(ready)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return twin
