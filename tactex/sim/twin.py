"""``tactex twin``: our scene inside franky-sim, a protocol-level stand-in for a real Franka.

franky-sim (the ``franka`` extra) speaks libfranka's network protocol on ``HOST:1337`` over its
own MuJoCo world. :func:`run_twin` adds our object (with its dirt), our table and our wrist
assembly (F/T sensor, tool body, sponge on a slide joint: :func:`tactex.sim.tool.tool_xml`) to that
world in place of the Franka hand, and publishes the simulated wrist sensor over ATI's Net F/T
protocol (:class:`tactex.robots.netft.NetFTServer`, UDP). A pylibfranka client, e.g.
:class:`tactex.robots.libfranka_backend.LibfrankaBackend`, then drives it as it would drive the
arm; the twin knows how much of the marking a cleaning run removed (:attr:`Twin.status`).

What the twin reports beyond stock franky-sim:

- ``K_F_ext_hat_K`` / ``O_F_ext_hat_K`` / ``tau_ext_hat_filtered`` (always zero in franky-sim)
  from the MuJoCo contact forces on the robot, with libfranka's documented sign: the wrench the
  robot exerts on the environment is positive (``robot_state.h``: "Forces applied by the robot to
  the environment are positive, while forces applied by the environment on the robot are
  negative"), about the K frame's origin (``O_T_EE · EE_T_K``). ``TwinConfig.ext_wrench_on_robot``
  flips it, for clients written the other way round.
- The Net F/T record is the raw reading of MuJoCo's force/torque sensors at the sensor site (the
  wrench the flange exerts on the tool, sensor frame, the tool's weight included): the input of
  :class:`tactex.sim.ft_sensor.FTSensorModel`; a client tares it out of contact.

Masses: the Franka hand is removed (its finger joints stay, as massless stubs, because franky-sim
drives them), and franky-sim's dynamics model gets no end effector (as a real arm configured with
"no end effector" in Desk: ``F_T_NE`` = identity, ``m_ee`` ≈ 0), so the arm holds still under zero
torque once the client declares the tool with ``set_load`` (the wrist assembly's mass, centre of
mass as :meth:`ToolGeometry.calibrated_mass_properties`); without it the tool's weight sags it.
"""

from __future__ import annotations

import errno
import json
import math
import os
import select
import signal
import socket
import threading
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tactex.config import param
from tactex.errors import ConfigError, MissingDependencyError, SimulationError, TactexError
from tactex.robots.netft import NETFT_PORT
from tactex.sim.scene import SceneConfig
from tactex.sim.tool import ToolGeometry, tool_xml
from tactex.sim.twin_clock import CommandRate, TwinClock, fine_timer_slack

__all__ = ["FRANKA_PORTS", "Twin", "TwinConfig", "export_marking_cloud", "run_twin"]

#: TCP ports franky-sim serves on: the robot (libfranka) and the gripper.
FRANKA_PORTS = (1337, 1338)
_PREFIX = "robot0_"  # franky-sim's name prefix of the first robot
_STUB_MASS_KG = 1e-5  # each finger stub (franky-sim drives the finger joints; they must exist)
_STUB_Z_M = 0.0584  # finger joint position below the flange [m]
_TOOL_CLASS = "tactex_tool"  # default class of the wrist assembly (not franky-sim's "fr3")


@dataclass(frozen=True)
class TwinConfig:
    """The twin: object, tool, dirt and network addresses (units in brackets)."""

    object_name: str = param("sine_panel", "object from the registry (tactex.sim.objects)")
    object_position: tuple[float, float, float] | None = param(
        None, "object position in the robot base frame [m]; default: the object's own placement (0.5 0 0; the cup "
        "0.42 0 0), as in tactex clean")
    object_rpy_deg: tuple[float, float, float] = param((0.0, 0.0, 0.0), "object orientation roll/pitch/yaw [deg]")
    marking: str = param("X", "dirt pattern (X, RLI, blobs, shapes, full; tactex clean's default X); empty = the "
                              "object's default")
    # the tool of tactex clean and wipe (tactex.tasks.world.SimWorldParams): the client declares it
    tool_stiffness_n_per_m: float = param(2500.0, "sponge stiffness along the tool axis [N/m]")
    tool_damping_ratio: float = param(0.7, "sponge damping, fraction of critical [-]")
    tool_friction: float = param(0.4, "pad–surface Coulomb friction coefficient [-]")
    tool_pad_radius_m: float = param(0.025, "sponge radius [m]")
    tool_pad_shape: str = param("sphere", "pad shape: sphere (domed sponge) or cylinder (flat)")
    payload_mass_kg: float = param(0.0, "extra mass hung at the TCP, unknown to the F/T calibration [kg]")
    dirt_resolution_m: float = param(0.002, "dirt grid cell size [m]")
    preston_coefficient: float = param(5e-3, "Preston wear coefficient [1/(Pa·m)]")
    dirt_force_threshold_n: float = param(2.0, "normal force below which no dirt is removed [N]")
    contact_sample_ticks: int = param(5, "ticks between dirt updates from the pad's contacts [-]")
    hostname: str = param("127.0.0.1", "address the robot (TCP 1337, gripper 1338) and the Net F/T serve on")
    ft_port: int = param(NETFT_PORT, "UDP port of the Net F/T stream")
    ft_rate_hz: float = param(1000.0, "Net F/T record rate [Hz]")
    status_file: str = param("", "JSON file rewritten every status_period_s with the twin's status ('' = none)")
    status_period_s: float = param(0.5, "period of the status file [s]")
    realtime_factor: float = param(1.0, "simulated seconds per wall-clock second the twin aims at (it paces "
                                        "itself with sleeps; 0 = as fast as it can)")
    command_window_ms: float = param(
        0.5, "how long after each state the twin waits for the client's command before it steps [ms] (scaled with "
             "--realtime-factor above 1): the budget tactex plans for one FCI iteration (receive, compute, send; "
             "docs/real_robot.md); a later command is used a cycle late and counts against "
             "control_command_success_rate")
    joint_friction_residual: float = param(
        0.0, "fraction of franky-sim's dry joint friction (MuJoCo frictionloss 0.25–1.14 N·m) left on the arm: a "
             "real Franka adds gravity and friction to the commanded torques (libfranka's Torques are 'without "
             "gravity and friction'), franky-sim only gravity; 1 = franky-sim as it is [-]")
    ext_wrench_on_robot: bool = param(False, "report K_F_ext_hat_K as the wrench ON the robot (the opposite of "
                                             "libfranka's documented sign), for clients written that way")

    def __post_init__(self) -> None:
        from tactex.sim.objects import resolve_object_name

        object.__setattr__(self, "object_name", resolve_object_name(self.object_name))  # 'Plate' is plate
        self.scene_config()  # object, marking, tool and dirt checks
        if not (isinstance(self.ft_port, int) and 0 <= self.ft_port < 65536):
            raise ConfigError(f"ft_port must be a UDP port in 0..65535 (0: any free one), got {self.ft_port!r}")
        if not self.hostname.strip():
            raise ConfigError("hostname must be an address, e.g. 127.0.0.1")
        for name, lo in (("ft_rate_hz", 1.0), ("status_period_s", 0.01)):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= lo):
                raise ConfigError(f"{name} must be ≥ {lo:g}, got {v!r}")
        if not (math.isfinite(self.joint_friction_residual) and 0.0 <= self.joint_friction_residual <= 1.0):
            raise ConfigError(f"joint_friction_residual must be in [0, 1], got {self.joint_friction_residual!r}")
        if not (math.isfinite(self.command_window_ms) and 0.0 < self.command_window_ms < 1.0):
            raise ConfigError(f"command_window_ms must be in (0, 1) ms (the client's share of the 1 ms state "
                              f"period at real time), got {self.command_window_ms!r}")
        if not (math.isfinite(self.realtime_factor) and 0.0 <= self.realtime_factor <= 100.0):
            raise ConfigError(f"realtime_factor must be in [0, 100] (0: unpaced), got {self.realtime_factor!r}")

    def scene_config(self) -> SceneConfig:
        """The :class:`SceneConfig` of the same object, tool and dirt (validates them)."""
        return SceneConfig(
            object_name=self.object_name, object_position=self.object_position, object_rpy_deg=self.object_rpy_deg,
            marking=self.marking, tool_stiffness_n_per_m=self.tool_stiffness_n_per_m,
            tool_damping_ratio=self.tool_damping_ratio, tool_friction=self.tool_friction,
            tool_pad_radius_m=self.tool_pad_radius_m, tool_pad_shape=self.tool_pad_shape,
            payload_mass_kg=self.payload_mass_kg, dirt_resolution_m=self.dirt_resolution_m,
            preston_coefficient=self.preston_coefficient, dirt_force_threshold_n=self.dirt_force_threshold_n,
            contact_sample_ticks=self.contact_sample_ticks,
        )

    @property
    def tool(self) -> ToolGeometry:
        return self.scene_config().tool


def export_marking_cloud(config: TwinConfig, path: str | Path, spacing_m: float = 0.003) -> Path:
    """Write the object's surface with its marking as a PLY in the robot base frame [m]: points at
    ``spacing_m``, normals, red (255, 0, 0) and ``target`` = 1 on the marking, as the TEC clouds.
    This is the cloud ``tactex clean --cloud FILE`` would get from a perfect scan of the twin."""
    from tactex.pointcloud.io import save_ply
    from tactex.pointcloud.markings import marked_cloud

    scene = config.scene_config()
    obj = scene.sim_object
    pos, rot = scene.object_pose()
    cloud = marked_cloud(obj.surface, scene.marking or obj.marking, spacing_m).transformed(rot, pos)
    return save_ply(cloud, path)


# -- scene assembly -------------------------------------------------------------------------------
def _find_body(root: ET.Element, name: str) -> ET.Element:
    for body in root.iter("body"):
        if body.get("name") == name:
            return body
    raise SimulationError(f"franky-sim's scene has no body '{name}': this franky-sim version is not supported")


def _replace_hand(root: ET.Element, scene: SceneConfig) -> None:
    """Swap franky-sim's Franka hand for our wrist assembly on the flange (link7 + 0.107 m)."""
    link7 = _find_body(root, f"{_PREFIX}fr3_link7")
    hand = _find_body(root, f"{_PREFIX}hand")
    link7.remove(hand)
    # childclass: franky-sim's arm bodies carry childclass "fr3", whose joint defaults (armature 0.195 kg·m²,
    # frictionloss 1.137, the reflected rotor and gear friction of a Franka joint) the sponge's slide joint
    # would otherwise inherit: a 0.2 kg pad with 1.1 N of dry friction instead of 20 g, which hopped on the
    # surface (0–40 N tick to tick) once the arm stiffened. The tool takes MuJoCo's plain defaults, as in
    # tactex's own scene; the finger stubs keep their explicit class "finger".
    flange = ET.SubElement(link7, "body", name="flange", pos=hand.get("pos", "0 0 0.107"), childclass=_TOOL_CLASS)
    ET.SubElement(flange, "site", name="flange", size="0.004")
    flange.append(ET.fromstring(tool_xml(scene.tool, scene.intrinsics.fovy_deg, gravcomp=False)))
    # franky-sim drives the two finger joints (and its gripper server reads them): keep them as
    # massless stubs without geometry, turned like the hand
    stub = ET.SubElement(flange, "body", name=f"{_PREFIX}hand", quat=hand.get("quat", "1 0 0 0"))
    for finger in hand.findall("body"):
        for child in list(finger):
            if child.tag in ("geom", "inertial"):
                finger.remove(child)
        ET.SubElement(finger, "inertial", pos="0 0 0", mass=f"{_STUB_MASS_KG:g}", diaginertia="1e-9 1e-9 1e-9")
        stub.append(finger)


def _add_scene(sim: Any, scene: SceneConfig) -> None:
    root = sim.scene
    default = root.find("default")
    if default is None:
        default = ET.SubElement(root, "default")
    tool_visual = ET.SubElement(default, "default", {"class": "tool_visual"})
    ET.SubElement(tool_visual, "geom", contype="0", conaffinity="0", group="2", density="0")
    tool_class = ET.SubElement(default, "default", {"class": _TOOL_CLASS})  # MuJoCo's defaults, see _replace_hand
    ET.SubElement(tool_class, "joint", armature="0", frictionloss="0", damping="0")
    option = root.find("option")
    if option is None:
        option = ET.SubElement(root, "option")
    option.set("cone", "elliptic")  # as our own scene: the pad's friction cone
    _replace_hand(root, scene)
    pos, rot = scene.object_pose()
    asset_xml, body_xml = scene.sim_object.mjcf("object", pos, rot)
    if asset_xml:
        asset = root.find("asset")
        if asset is None:
            asset = ET.SubElement(root, "asset")
        asset.append(ET.fromstring(asset_xml))
    world = sim.worldbody
    ET.SubElement(world, "geom", name="table", type="box", pos="0.4 0 -0.02", size="0.8 0.8 0.02",
                  rgba="0.4 0.35 0.3 1", contype="0", conaffinity="2", group="0")
    world.append(ET.fromstring(body_xml))
    sensor = ET.SubElement(root, "sensor")
    ET.SubElement(sensor, "force", name="ft_force", site="ft_site")
    ET.SubElement(sensor, "torque", name="ft_torque", site="ft_site")


# -- the twin -------------------------------------------------------------------------------------
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
    for kind, port, proto in tried:
        sock = socket.socket(socket.AF_INET, kind)
        if kind == socket.SOCK_STREAM:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as franky-sim does
        try:
            sock.bind((config.hostname, port))
        except OSError as exc:
            what = "--port-ft" if proto == "udp" else "--hostname (e.g. 127.0.0.2)"
            in_use = exc.errno == errno.EADDRINUSE
            reason = "is in use (another twin or franky-sim?)" if in_use else f"cannot be bound ({exc.strerror})"
            raise TactexError(f"{proto} {config.hostname}:{port} {reason}: stop what serves there, or pick another "
                              f"address with {what}") from None
        finally:
            sock.close()


class _CommandChannel:
    """The client's commands as the twin's loop sees them, through franky-sim's server: which state
    the newest command answered (libfranka sends the state's message id back in the first 8 bytes
    of its UDP command), and a wait for that answer on franky-sim's UDP socket.

    Uses franky-sim's private members (checked by :func:`check_franky_internals`): the UDP socket
    (made when a client connects, closed when it leaves) and the next state's message id.
    """

    def __init__(self, robot_server: Any) -> None:
        self.server = robot_server
        self.answered = -1  # message id of the newest state a command answered
        handle = robot_server._handle_udp_command

        def handle_command(data: bytes) -> None:
            self.answered = max(self.answered, int.from_bytes(data[:8], "little"))
            handle(data)

        robot_server._handle_udp_command = handle_command  # the hook franky-sim calls per UDP command

    def last_sent(self) -> int:
        """Message id of the last state sent (−1: none yet); a new client restarts the count."""
        last = int(self.server._FrankaServer__message_id) - 1
        if last < self.answered:  # franky-sim numbers a new client's states from 0 again
            self.answered = -1
        return last

    def _socket(self) -> Any:
        sock = getattr(self.server, "_FrankaServer__udp_socket", None)
        return sock if sock is not None and sock.fileno() >= 0 else None

    def take(self, servers: list, last: int, deadline: float | None) -> None:
        """Process the commands once the answer to state ``last`` is in, or at ``deadline``
        (monotonic s); at once when ``deadline`` is None. Commands are processed once a cycle,
        more often only when a stale answer came first (each pass then has a new command)."""
        if deadline is not None:
            processed = False
            while self.answered < last:
                left = deadline - time.monotonic()
                sock = self._socket()  # closed when the client leaves, possibly by the last pass
                if left <= 0.0:
                    break
                if sock is None:
                    TwinClock.wait_until(deadline)
                    break
                try:
                    if not select.select([sock], [], [], left)[0]:
                        break
                except (OSError, ValueError):  # closed meanwhile: the client is gone
                    break
                for rs in servers:
                    rs.process_commands()
                processed = True
            if processed:
                return
        for rs in servers:
            rs.process_commands()


def check_franky_internals(robot_server: Any) -> None:
    """Fail early when franky-sim lacks the members the twin's loop reads (tested with 1.0.x)."""
    needed = ("_FrankaServer__message_id", "_FrankaServer__udp_socket", "_handle_udp_command", "current_motion_id")
    missing = [name for name in needed if not hasattr(robot_server, name)]
    if missing:
        import importlib.metadata

        version = importlib.metadata.version("franky-sim")
        raise MissingDependencyError("franky-sim", "franka", "tactex twin", fix=(
            f"franky-sim {version} lacks {', '.join(missing)}, which the twin's loop reads; install the "
            "version tactex is tested with: pip install 'franky-sim>=1.0,<1.1'"))


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
        params = robot_parameters(ee_mass=2 * _STUB_MASS_KG, ee_com=(0.0, 0.0, _STUB_Z_M), ee_tcp_xyz=(0.0, 0.0, 0.0),
                                  ee_tcp_rpy=(0.0, 0.0, 0.0), ee_inertia=(1e-9, 0, 0, 0, 1e-9, 0, 0, 0, 1e-9))
        self.robot = self.sim.add_robot(robot_parameters=params)
        self.robot.__class__ = _contact_aware_class(franka_robot)  # add_robot hard-codes its class
        self.robot._twin_ext = None
        self.robot._twin_on_robot = bool(config.ext_wrench_on_robot)
        _add_scene(self.sim, self.scene)
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

    # -- per-tick work (the simulation thread) -----------------------------------------------------
    def _setup_ids(self) -> None:
        mujoco = self._mujoco
        m, d = self.sim.model, self.sim.data
        self.model, self.data = m, d
        a, b = int(m.sensor("ft_force").adr[0]), int(m.sensor("ft_torque").adr[0])
        self._ft_force, self._ft_torque = d.sensordata[a:a + 3], d.sensordata[b:b + 3]
        robot_bodies = np.array([m.body(i).name.startswith(_PREFIX) or i in self._tool_bodies(m)
                                 for i in range(m.nbody)])
        self._geom_robot = robot_bodies[m.geom_bodyid].tolist()
        self._geom_body = m.geom_bodyid.tolist()
        self._dofs = list(self.robot._dof_addrs)
        # the firmware's friction compensation (see TwinConfig.joint_friction_residual)
        m.dof_frictionloss[self._dofs] *= float(self.config.joint_friction_residual)
        # franky-sim holds an idle arm (no client, between motions) with an explicit joint PD whose damping
        # (200 N·m·s/rad on joints 5–7) exceeds 2·I/dt of the wrist (I ≈ 0.08 kg·m² on joint 7, its
        # armature included): only the joints' dry friction kept it from chattering at the torque limit
        # (±12 N·m every tick). Cap the damping at I/(2·dt) so the hold is stable without friction.
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
        if d.ncon == 0:
            self.robot._twin_ext = None
            self.pad_force_n = 0.0
            return
        # contact wrench on the robot: force (world), moment about the world origin, joint torques
        fx = fy = fz = mx = my = mz = 0.0
        tau = None
        pad_fx = pad_fy = pad_fz = 0.0
        is_robot, body_of, c6, jacp = self._geom_robot, self._geom_body, self._c6, self._jacp
        m = self.model
        for i in range(d.ncon):
            con = d.contact[i]
            g1, g2 = int(con.geom1), int(con.geom2)
            r1, r2 = is_robot[g1], is_robot[g2]
            if r1 == r2:
                continue
            self._mj_contact_force(m, d, i, c6)
            f = con.frame.reshape(3, 3).T @ c6[:3]  # on geom2, world frame
            if not r2:
                f = -f
            px, py, pz = con.pos.tolist()
            ux, uy, uz = f.tolist()
            fx, fy, fz = fx + ux, fy + uy, fz + uz
            mx, my, mz = mx + py * uz - pz * uy, my + pz * ux - px * uz, mz + px * uy - py * ux
            self._mj_jac(m, d, jacp, None, con.pos, body_of[g2 if r2 else g1])
            t = jacp[:, self._dofs].T @ f
            tau = t if tau is None else tau + t
            if g1 == self._pad_geom or g2 == self._pad_geom:
                pad_fx, pad_fy, pad_fz = pad_fx + ux, pad_fy + uy, pad_fz + uz
        self.robot._twin_ext = None if tau is None else ((fx, fy, fz), (mx, my, mz), tau)
        self.pad_force_n = math.sqrt(pad_fx * pad_fx + pad_fy * pad_fy + pad_fz * pad_fz)
        self.max_contact_force_n = max(self.max_contact_force_n, self.pad_force_n)
        if self.ticks % self._sample == 0:
            self._wipe_due = True  # done after the state has left (Twin._serve), off the step's time

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
        commands = _CommandChannel(robot_server)
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
        except BaseException as exc:
            if self._error is None:
                self._error = exc
            self._stop.set()

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
                self.sim.register_post_step_callback(self._post_step)
                period_s = 1e-3 / cfg.realtime_factor if cfg.realtime_factor > 0 else 0.0
                # franky-sim's run_async loop, with the robot's cadence (tactex.sim.twin_clock)
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
        if self._error is not None:
            raise SimulationError(f"the twin's simulation loop failed: {self._error!r}") from self._error
        if server.async_thread is not None and not self._stop.is_set():
            raise SimulationError("the twin's simulation loop stopped unexpectedly (see the log above)")


_IDENTITY16 = (1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0)


def wrench_about_k(o_t_ee, ee_t_k, force_on_robot, moment_on_robot, sign: float):
    """The contact wrench as libfranka reports it: (``O_F_ext_hat_K``, ``K_F_ext_hat_K``), each
    (force [N], moment [N·m]) as 6 floats, from the force on the robot (world frame) and its moment
    about the world origin. The moment is taken about the K frame's origin (``O_T_EE · EE_T_K``, both
    16 floats, column-major); ``sign`` −1 gives the robot's wrench on the environment. Python floats,
    not numpy: the twin calls it every contact tick, where a dozen small numpy calls cost ~30 µs."""
    a = o_t_ee if tuple(ee_t_k) == _IDENTITY16 else tuple(
        (np.asarray(o_t_ee, dtype=float).reshape(4, 4, order="F")
         @ np.asarray(ee_t_k, dtype=float).reshape(4, 4, order="F")).flatten(order="F").tolist())
    px, py, pz = a[12], a[13], a[14]
    fx, fy, fz = force_on_robot
    mx = moment_on_robot[0] - (py * fz - pz * fy)
    my = moment_on_robot[1] - (pz * fx - px * fz)
    mz = moment_on_robot[2] - (px * fy - py * fx)
    fx, fy, fz, mx, my, mz = sign * fx, sign * fy, sign * fz, sign * mx, sign * my, sign * mz
    world = (fx, fy, fz, mx, my, mz)
    k = (a[0] * fx + a[1] * fy + a[2] * fz, a[4] * fx + a[5] * fy + a[6] * fz, a[8] * fx + a[9] * fy + a[10] * fz,
         a[0] * mx + a[1] * my + a[2] * mz, a[4] * mx + a[5] * my + a[6] * mz, a[8] * mx + a[9] * my + a[10] * mz)
    return world, k


_ZERO6, _ZERO7 = (0.0,) * 6, (0.0,) * 7


def _contact_aware_class(base: type) -> type:
    """franky-sim's MuJoCo robot whose state carries the contact wrench and the command success rate
    (see the module docstring)."""

    class TwinRobot(base):  # type: ignore[misc, valid-type]
        _twin_ext: Any = None
        _twin_on_robot = False
        _twin_success = 1.0

        @property
        def state(self):
            st = super().state
            # franky-sim builds a new frozen snapshot per call, so it is filled in place:
            # dataclasses.replace would build all of its ~40 fields a second time every tick
            put = object.__setattr__
            put(st, "control_command_success_rate", self._twin_success)
            ext = self._twin_ext
            if ext is None:
                put(st, "O_F_ext_hat_K", _ZERO6)
                put(st, "K_F_ext_hat_K", _ZERO6)
                put(st, "tau_ext_hat_filtered", _ZERO7)
                return st
            f_on, m0_on, tau_on = ext
            sign = 1.0 if self._twin_on_robot else -1.0  # libfranka: the robot's wrench on the environment
            world, k = wrench_about_k(st.O_T_EE, st.EE_T_K, f_on, m0_on, sign)
            put(st, "O_F_ext_hat_K", world)
            put(st, "K_F_ext_hat_K", k)
            put(st, "tau_ext_hat_filtered", tuple((sign * np.asarray(tau_on)).tolist()))
            return st

    return TwinRobot


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
    try:
        twin.run(ready)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return twin
