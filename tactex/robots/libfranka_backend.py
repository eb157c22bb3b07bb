"""The real Franka through libfranka's official Python bindings (``pylibfranka``, the ``franka`` extra).

One tick of the 1 kHz loop is ``readOnce`` → :class:`~tactex.control.state.RobotState` → our
controller and safety layer → ``writeOnce``, all in the calling thread. libfranka's budget for
that iteration is about 0.5 ms; our share (:attr:`LoopTiming.compute_us`: from ``readOnce``
returning to ``writeOnce``) must stay ≤ 0.3 ms, so nothing slow runs here: vision runs in its own
process (:mod:`tactex.robots.vision_process`) and the F/T stream is polled, not read by a thread
(pylibfranka holds the GIL while it waits for the robot, which starves every other thread of this
process).

What comes from the robot: joint state, the TCP pose ``O_T_EE`` (our TCP, set with ``set_EE``
from the tool), the Jacobian, mass matrix, Coriolis and gravity from libfranka's own ``Model``
(not ours), the measured torques ``tau_J``, ``control_command_success_rate``. The commanded
torque excludes gravity (the firmware adds it). The contact wrench comes from a
:class:`~tactex.robots.wrench.WrenchSource`: the arm's estimate ``K_F_ext_hat_K`` or a Net F/T.

Inverse kinematics (the tasks' transit moves) runs on tactex's MuJoCo model of the same arm and
tool (the Panda's and FR3's kinematics are the same); the torque loop never uses it.

Failure handling: a libfranka exception (a reflex, ``communication_constraints_violation``, a lost
link) becomes the :class:`~tactex.errors.RobotError` of its kind (:func:`libfranka_error_kind`)
naming libfranka's message, after torque control has ended; with ``auto_recovery`` the backend
calls ``automatic_error_recovery`` once and the error still ends the task. :meth:`close` ends
torque control with ``motion_finished`` (idempotent; also run by Ctrl-C through the tasks'
``finally``). ``dry_run`` never starts torque control: it
reads the state at 1 kHz with ``read_once`` and drops the torques, so the arm stays braked/idle.
"""

from __future__ import annotations

import gc
import importlib.util
import ipaddress
import math
import os
import time
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from tactex.config import param
from tactex.control.safety import FRANKA_TAU_MAX, LIMIT_MARGIN
from tactex.control.state import RobotState
from tactex.errors import (
    ConfigError,
    InputError,
    MissingDependencyError,
    RobotClosedError,
    RobotCommunicationError,
    RobotConnectionError,
    RobotError,
    RobotRealtimeError,
    RobotReflexError,
)
from tactex.perception.frame import CameraFrame
from tactex.robots.cpu_latency import CpuLatencyRequest, check_latency_us
from tactex.robots.netft import NetFTClient, parse_netft_address
from tactex.robots.scheduling import Scheduling
from tactex.robots.wrench import FrankaWrenchSource, NetFTWrenchSource, WrenchSource
from tactex.sim.tool import ToolGeometry, flange_R_tool

__all__ = [
    "CONNECT_TIMEOUT_S",
    "FrankaConfig",
    "LibfrankaBackend",
    "LoopTiming",
    "ModelTerms",
    "connecting_line",
    "flange_T_tcp",
    "franka_model_terms",
    "franka_state_to_robot_state",
    "libfranka_error_kind",
    "pin_control_thread",
]

_GRAVITY = [0.0, 0.0, -9.81]
#: A tick whose command comes this late ends the run [µs]: libfranka tolerates a few lost cycles,
#: not tens of them in a row. The default of :attr:`FrankaConfig.late_abort_ms`, and its ceiling on a robot.
LATE_COMMAND_ABORT_US = 20_000.0
#: The bare hold's joint stiffness [N·m/rad] and damping [N·m·s/rad]: the gains of libfranka's
#: ``joint_impedance_control`` example, which holds a real arm with them.
BARE_STIFFNESS_N_M_PER_RAD = (600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0)
BARE_DAMPING_N_M_S_PER_RAD = (50.0, 50.0, 50.0, 50.0, 30.0, 25.0, 15.0)


@dataclass(frozen=True)
class FrankaConfig:
    """How to reach and set up a real Franka (units in brackets)."""

    robot_ip: str = param("", "the robot's FCI address (Desk → Settings → Network), e.g. 172.16.0.2")
    ft: str = param("franka", "wrench source: 'franka' (the arm's estimated external wrench K_F_ext_hat_K) or "
                              "'netft:HOST[:PORT]' (an ATI Net F/T at the wrist, RDT over UDP)")
    ft_counts_per_force: float = param(1e6, "Net F/T calibration: counts per newton (cfgcpf) [1/N]")
    ft_counts_per_torque: float = param(1e6, "Net F/T calibration: counts per newton-metre (cfgcpt) [1/(N·m)]")
    ft_timeout_s: float = param(0.05, "a Net F/T stream silent this long counts as lost [s]")
    dry_run: bool = param(False, "read the robot's state and run the whole pipeline, but never start torque "
                                 "control: the arm stays braked (first tries)")
    auto_recovery: bool = param(False, "after a libfranka reflex, call automatic_error_recovery before ending "
                                       "(the run still stops)")
    realtime: str = param("auto", "libfranka's real-time check: enforce (a PREEMPT_RT kernel is required), ignore, "
                                  "or auto (ignore on a loopback address, i.e. tactex twin; enforce otherwise)")
    collision_torque_n_m: float = param(
        60.0, "libfranka's collision reflex: upper joint-torque threshold for joints 1–4 (5–7 get 2/5 of it) [N·m]")
    collision_force_n: float = param(60.0, "libfranka's collision reflex: upper Cartesian force threshold [N]")
    control_cpu: int = param(-1, "pin the control loop to this CPU core, run it with real-time priority when "
                                 "allowed, and keep the vision process off it (-1: no pinning)")
    cpu_latency_us: int = param(-1, "while connected, hold the CPUs' idle wake-up latency at or below this "
                                    "through /dev/cpu_dma_latency (0: idle CPUs poll; -1: no request) [µs]")
    late_abort_ms: float = param(
        LATE_COMMAND_ABORT_US / 1e3,
        "a command this late after its state ends torque control with an error, as a real Franka stops after "
        "~20 lost cycles; more is allowed only on a loopback address (tactex twin on a busy machine, whose "
        "stalls are the machine's, not a robot's) [ms]")

    def __post_init__(self) -> None:
        if not isinstance(self.robot_ip, str) or not self.robot_ip.strip():
            raise ConfigError("robot_ip: give the robot's FCI address, e.g. --robot-ip 172.16.0.2 "
                              "(or 127.0.0.1 for tactex twin)")
        if self.realtime not in ("auto", "enforce", "ignore"):
            raise ConfigError(f"realtime must be auto, enforce or ignore, got {self.realtime!r}")
        if not (self.ft == "franka" or self.ft.startswith("netft:")):
            raise ConfigError(f"ft must be 'franka' or 'netft:HOST[:PORT]', got {self.ft!r}")
        if self.ft.startswith("netft:"):
            parse_netft_address(self.ft[len("netft:"):])
        cpus = os.cpu_count() or 1
        if isinstance(self.control_cpu, bool) or not isinstance(self.control_cpu, int) \
                or not -1 <= self.control_cpu < cpus:
            raise ConfigError(f"control_cpu must be a core number in 0..{cpus - 1} or -1 (no pinning), "
                              f"got {self.control_cpu!r}")
        check_latency_us(self.cpu_latency_us)
        late = self.late_abort_ms
        if isinstance(late, bool) or not isinstance(late, (int, float)) or not (math.isfinite(late) and late > 0):
            raise ConfigError(f"late_abort_ms must be a positive number of milliseconds, got {late!r}")
        if late * 1e3 > LATE_COMMAND_ABORT_US and not self.is_loopback:
            raise ConfigError(f"late_abort_ms above {LATE_COMMAND_ABORT_US / 1e3:.0f} ms is for tactex twin on a "
                              f"loopback address only (a real Franka stops at about 20 lost cycles anyway); "
                              f"got {late!r} with robot_ip {self.robot_ip!r}")
        for name in ("ft_counts_per_force", "ft_counts_per_torque", "ft_timeout_s", "collision_torque_n_m",
                     "collision_force_n"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be a positive number, got {getattr(self, name)!r}")

    @property
    def is_loopback(self) -> bool:
        """Whether ``robot_ip`` is this machine (tactex twin), not a robot on the network."""
        try:
            return ipaddress.ip_address(self.robot_ip).is_loopback
        except ValueError:
            return self.robot_ip == "localhost"

    @property
    def ignore_realtime(self) -> bool:
        if self.realtime != "auto":
            return self.realtime == "ignore"
        return self.is_loopback

    def wrench_source(self, tool: ToolGeometry) -> WrenchSource:
        if self.ft == "franka":
            return FrankaWrenchSource()
        host, port = parse_netft_address(self.ft[len("netft:"):])
        client = NetFTClient(host, port, counts_per_force=self.ft_counts_per_force,
                             counts_per_torque=self.ft_counts_per_torque, timeout_s=self.ft_timeout_s)
        mass, com = tool.calibrated_mass_properties()
        return NetFTWrenchSource(client, mass, com, tool.tcp_offset_m)


def flange_T_tcp(tool: ToolGeometry) -> np.ndarray:
    """Pose (4, 4) of our TCP in the flange frame: the tool frame (flange turned −45° about z) moved
    ``tcp_offset_m`` along its z axis (the uncompressed pad tip)."""
    pose = np.eye(4)
    pose[:3, :3] = flange_R_tool()
    pose[2, 3] = tool.tcp_offset_m
    return pose


def _col_major(a: Any, rows: int, cols: int) -> np.ndarray:
    """A column-major libfranka array as a C-contiguous (rows, cols) matrix (controllers write into
    products of it with ``out=``, which needs C order)."""
    return np.ascontiguousarray(np.asarray(a, dtype=float).reshape(cols, rows).T)


class ModelTerms(NamedTuple):
    """libfranka's model at one state (:func:`franka_model_terms`)."""

    jacobian: np.ndarray  #: (6, 7) the TCP's zero Jacobian, base frame
    mass_matrix: np.ndarray  #: (7, 7) [kg·m²]
    coriolis: np.ndarray  #: (7,) C(q, dq)·dq [N·m]
    gravity: np.ndarray  #: (7,) [N·m]


def franka_model_terms(state: Any, model: Any) -> ModelTerms:
    """libfranka's model at ``state``: the TCP's zero Jacobian (6, 7), the mass matrix (7, 7)
    [kg·m²], the Coriolis torque C(q, dq)·dq (7,) [N·m] and the gravity torque (7,) [N·m].

    libfranka's arrays are column-major. The gravity vector uses ``O_ddP_O`` (filled by the
    firmware; a state without it, as franky-sim sends, gets −9.81 z).
    """
    jac = _col_major(model.zero_jacobian(state), 6, 7)
    mass = _col_major(model.mass(state), 7, 7)
    coriolis = np.asarray(model.coriolis(state), dtype=float)
    if not any(state.O_ddP_O):
        state.O_ddP_O = _GRAVITY
    gravity = np.asarray(model.gravity(state), dtype=float)
    return ModelTerms(jac, mass, coriolis, gravity)


def franka_state_to_robot_state(state: Any, model: Any, t: float, wrench: WrenchSource,
                                terms: ModelTerms | None = None) -> RobotState:
    """libfranka's state and model → our :class:`RobotState` (world = the robot's base frame O), the
    contact wrench read from ``wrench`` at the pose of this state.

    ``terms``: the model terms (:func:`franka_model_terms`) to use instead of evaluating ``model``
    at ``state``, e.g. those of the previous state, computed while the robot executed the last
    command (the pose, velocities and wrench are always this state's; the TCP twist is J·dq with
    the given J).
    """
    # O_T_EE is 16 floats, column-major: the rotation's rows and the translation picked out as Python
    # floats make two arrays (each numpy call costs microseconds between a state and its command)
    o = state.O_T_EE
    rot = np.array(((o[0], o[4], o[8]), (o[1], o[5], o[9]), (o[2], o[6], o[10])))
    jac, mass, coriolis, gravity = terms if terms is not None else franka_model_terms(state, model)
    dq = np.array(state.dq, dtype=float)
    return RobotState(
        t=t, q=np.array(state.q, dtype=float), dq=dq, tau_measured=np.array(state.tau_J, dtype=float),
        ee_position=np.array(o[12:15], dtype=float), ee_rotation=rot, ee_twist=jac @ dq, jacobian=jac,
        mass_matrix=mass, coriolis=coriolis, gravity=gravity,
        wrench_tool=np.asarray(wrench.wrench_tool(state, rot), dtype=float),
    )


def _lost_cycles(period_ms: float) -> int:
    """The cycles the robot reports missing before a state: its ``Duration`` since the last state [ms], minus one."""
    return max(0, round(period_ms) - 1)


def pin_control_thread(cpu: int, priority: int = 80) -> str:
    """Pin the calling process to ``cpu`` and give it SCHED_FIFO ``priority`` when the system allows
    (root, or an rtprio limit; libfranka does the same with RealtimeConfig.kEnforce). Returns what
    was done, for the run's metrics. A core of its own keeps the loop's caches warm between ticks
    (docs/real_robot.md: the cost of a tick after each wait for the robot)."""
    if cpu < 0:
        return "not pinned"
    os.sched_setaffinity(0, {cpu})
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        return f"cpu {cpu}, SCHED_FIFO {priority}"
    except PermissionError:
        return f"cpu {cpu}, normal priority (no permission for SCHED_FIFO)"


#: A loop period over this is a stall of the control PC [µs]: three cycles a Franka would count as lost.
STALL_US = 3000.0
#: Most stalled ticks whose time a run keeps (metrics ``loop_stalls_t_s``) [-].
STALLS_KEPT = 200


class LoopTiming:
    """Per-tick timing of the 1 kHz loop, kept in preallocated arrays (grown in blocks).

    ``compute_us``: readOnce returned → writeOnce called (our controller, safety layer and task);
    ``period_us``: between successive readOnce returns (wall clock); ``lost``: cycles libfranka
    reports missing (its Duration since the last read, in ms, minus one); ``success``: libfranka's
    ``control_command_success_rate``.
    """

    def __init__(self, block: int = 65536) -> None:
        self._block = block
        self.n = 0
        self.compute_us = np.zeros(block)
        self.period_us = np.zeros(block)
        self.lost = np.zeros(block, dtype=np.int64)
        self.success = np.ones(block)
        self.stalls_t_s: list[float] = []  # the robot time [s] of the first STALLS_KEPT stalled ticks

    def stall(self, t_s: float, period_us: float) -> None:
        """Note the tick read at robot time ``t_s`` [s] when its wall-clock period ``period_us`` [µs] was a
        stall (over :data:`STALL_US`): what the robot does next answers a state that jumped."""
        if period_us > STALL_US and len(self.stalls_t_s) < STALLS_KEPT:
            self.stalls_t_s.append(float(t_s))

    def add(self, compute_us: float, period_us: float, lost: int, success: float) -> None:
        if self.n == self.compute_us.size:
            for name in ("compute_us", "period_us", "lost", "success"):
                a = getattr(self, name)
                setattr(self, name, np.concatenate([a, np.zeros(self._block, dtype=a.dtype)]))
        i = self.n
        self.compute_us[i] = compute_us
        self.period_us[i] = period_us
        self.lost[i] = lost
        self.success[i] = success
        self.n = i + 1

    def metrics(self) -> dict[str, Any]:
        """``loop_compute_us`` and ``loop_period_us`` (p50/p99/p99.9/max), ``lost_cycles``,
        ``min_command_success_rate``, ``loop_ticks`` for metrics.json."""
        n = self.n

        def pct(a: np.ndarray) -> dict[str, float]:
            if a.size == 0:
                return {k: float("nan") for k in ("p50", "p99", "p99.9", "max")}
            p = np.percentile(a, [50, 99, 99.9])
            return {"p50": float(p[0]), "p99": float(p[1]), "p99.9": float(p[2]), "max": float(a.max())}

        return {
            "loop_ticks": n,
            "loop_compute_us": pct(self.compute_us[:n]),
            "loop_period_us": pct(self.period_us[1:n]),
            "lost_cycles": int(self.lost[:n].sum()),
            "min_command_success_rate": float(self.success[:n].min()) if n else float("nan"),
            # ticks whose period was a stall of the PC (or of the twin beside it), and when the first were read
            "loop_stalls": int(np.count_nonzero(self.period_us[1:n] > STALL_US)),
            "loop_stalls_t_s": list(self.stalls_t_s),
        }


#: What to check, per kind of libfranka error that ends torque control.
_HINTS: dict[type[RobotError], str] = {
    RobotConnectionError: "the link to the robot was lost: check the cable, the FCI address and that nothing else "
                          "loads the PC",
    RobotCommunicationError: "commands arrived late: use a PREEMPT_RT kernel, the performance CPU governor and a "
                             "direct cable (docs/real_robot.md)",
    RobotReflexError: "a libfranka reflex or refusal: see Desk for the error; clear it with the pilot buttons or "
                      "--auto-recovery",
}


def libfranka_error_kind(exc: BaseException, plf: Any) -> type[RobotError]:
    """The :class:`RobotError` kind of an exception raised by pylibfranka (module ``plf``) during
    torque control. pylibfranka's exceptions carry no reflex field: a communication violation is
    named only in the message, so this is the one place that reads it; callers match the type."""
    if isinstance(exc, plf.NetworkException):
        return RobotConnectionError
    if "communication_constraints_violation" in str(exc):
        return RobotCommunicationError
    return RobotReflexError


#: libfranka's wait for the robot's answer before it gives up [s] (its Network's default TCP timeout).
CONNECT_TIMEOUT_S = 60


def connecting_line(robot_ip: str) -> str:
    """What to say before connecting: an address where nothing answers holds libfranka silent this long."""
    return f"connecting to the Franka at {robot_ip} (libfranka waits up to {CONNECT_TIMEOUT_S} s for it to answer)"


class LibfrankaBackend:
    """:class:`~tactex.robots.backend.RobotBackend` on a real Franka (or ``tactex twin``).

    Args:
        config: address, wrench source, dry run, recovery, reflex thresholds.
        tool: the tool on the flange (TCP, mass for ``set_load``, F/T calibration).
        ik_scene: a :class:`~tactex.sim.scene.SceneConfig` whose arm and tool serve :meth:`solve_ik`
            (default: the default scene with ``tool``'s geometry).

    Raises:
        MissingDependencyError: pylibfranka is not installed.
        RobotError: the robot cannot be reached or refuses the set-up.
    """

    n_joints = 7
    dt = 0.001
    #: The next state's model terms are evaluated ahead, at the state answered last, only while that state is
    #: younger than this [s] (one cycle: the joints have moved by at most dq·1 ms).
    model_ahead_max_age_s = 0.001

    def __init__(self, config: FrankaConfig, tool: ToolGeometry | None = None, ik_scene=None) -> None:
        if not isinstance(config, FrankaConfig):
            raise InputError(f"LibfrankaBackend takes a FrankaConfig (e.g. FrankaConfig(robot_ip='172.16.0.2')), "
                             f"got {type(config).__name__}")
        if importlib.util.find_spec("pylibfranka") is None:
            raise MissingDependencyError("pylibfranka", "franka", "The real-robot backend (--robot franka)")
        import pylibfranka

        self._plf = pylibfranka
        self.config = config
        self.tool = tool or ToolGeometry()
        self._ik_scene_config = ik_scene
        self._ik = None
        self.timing = LoopTiming()
        self.events: list[str] = []
        # what the thread had before libfranka and the pinning raise it to real time, given back on close
        self._scheduling_before = Scheduling.current()
        self._control = None
        self._pending_write = False
        self._tau = np.zeros(7)
        self._closed = False
        self._t = 0.0
        self._t_read = 0.0
        self._compute_us = float("nan")
        self._gc_was_on = False  # set while torque control runs with the collector switched off by us
        #: tau_J_d [N·m] of the first state of a torque control just (re)started, until the control loop
        #: takes it (ControlLoop.tick: the safety layer's rate limit continues from it); None otherwise
        self.torque_restart: np.ndarray | None = None
        self._last_read_wall: float | None = None
        self.wrench = config.wrench_source(self.tool)
        self.scheduling = pin_control_thread(config.control_cpu)
        self.cpu_latency = CpuLatencyRequest(-1)  # made once the robot is set up
        rt = pylibfranka.RealtimeConfig.kIgnore if config.ignore_realtime else pylibfranka.RealtimeConfig.kEnforce
        try:
            self.robot = pylibfranka.Robot(config.robot_ip, rt)
        except pylibfranka.RealtimeException as exc:
            self._restore_scheduling()
            raise RobotRealtimeError(
                f"libfranka refuses to run without a real-time kernel ({exc}): install a PREEMPT_RT kernel "
                "(docs/real_robot.md), or pass --realtime ignore for a test on a normal kernel") from exc
        except Exception as exc:
            self._restore_scheduling()
            what = ("is `tactex twin` running (and ready) on this machine?" if config.is_loopback else
                    "check the FCI address, that FCI is activated in Desk, the brakes are open and no other program "
                    "holds the robot")
            raise RobotConnectionError(f"cannot connect to the Franka at {config.robot_ip} ({exc}): {what}") from exc
        try:
            self._configure()
            self.model = self.robot.load_model()
            self.robot.read_once()  # the first read after idling can be stale
            self._franka_state = self.robot.read_once()
            self.wrench.start(world_R_tool=_col_major(self._franka_state.O_T_EE, 4, 4)[:3, :3])
            self._state = self._convert(self._franka_state)
            self.cpu_latency = CpuLatencyRequest(config.cpu_latency_us)
        except Exception as exc:
            self.cpu_latency.release()
            self.wrench.close()
            self._restore_scheduling()
            if isinstance(exc, RobotError):
                raise
            raise RobotError(f"setting up the Franka at {config.robot_ip} failed: {exc}") from exc

    # -- set-up ---------------------------------------------------------------------------------
    def _configure(self) -> None:
        cfg, tool = self.config, self.tool
        tq = cfg.collision_torque_n_m
        torque = [tq] * 4 + [0.4 * tq] * 3
        force = [cfg.collision_force_n] * 3 + [0.4 * cfg.collision_force_n] * 3
        self.robot.set_collision_behavior(torque, torque, force, force)
        state = self.robot.read_once()
        f_T_ne = _col_major(state.F_T_NE, 4, 4)
        ne_T_ee = np.linalg.inv(f_T_ne) @ flange_T_tcp(tool)
        self.robot.set_EE(ne_T_ee.T.reshape(16).tolist())
        mass, com_sensor = tool.calibrated_mass_properties()
        com_flange = flange_R_tool() @ com_sensor
        inertia = (np.eye(3) * 1e-3).T.reshape(9).tolist()  # a small tool: a point mass is what matters
        self.robot.set_load(float(mass), com_flange.tolist(), inertia)

    def _kinematics(self):
        if self._ik is None:
            from tactex.robots.mujoco_backend import MujocoBackend
            from tactex.sim.scene import SceneConfig

            cfg = self._ik_scene_config or SceneConfig(
                tool_stiffness_n_per_m=self.tool.stiffness_n_per_m, tool_pad_shape=self.tool.pad_shape,
                tool_pad_radius_m=self.tool.pad_radius_m)
            self._ik = MujocoBackend(cfg)
        return self._ik

    # -- RobotBackend ---------------------------------------------------------------------------
    def _convert(self, franka_state, terms: ModelTerms | None = None) -> RobotState:
        return franka_state_to_robot_state(franka_state, self.model, self._t, self.wrench, terms)

    def reset(self, seed: int | None = None) -> RobotState:
        """The current state (a real robot cannot be reset; ``seed`` is ignored)."""
        return self.state()

    def state(self) -> RobotState:
        return self._state

    def apply_torque(self, tau: np.ndarray) -> None:
        """Answer the current state with ``tau`` [N·m] (gravity excluded): sent at once while torque
        control runs, so whatever the task does before :meth:`step` runs while the robot executes
        it, not between a state and its command."""
        tau = np.asarray(tau, dtype=float)
        if tau.shape != (7,):
            raise InputError(f"apply_torque takes 7 joint torques [N·m], got shape {tau.shape}")
        if not np.isfinite(tau).all():  # the safety layer never lets one through; a last guard
            tau = np.zeros(7)
        self._tau = tau
        if self._pending_write:
            self._send()
        elif self.config.dry_run and math.isnan(self._compute_us):  # what the send would have cost
            self._compute_us = (time.perf_counter() - self._t_read) * 1e6

    def _send(self) -> None:
        """writeOnce the torque set last, timing our share of the cycle (state read → command sent)."""
        t_send = time.perf_counter()
        self._compute_us = (t_send - self._t_read) * 1e6
        self._abort_if_late(self._compute_us)
        try:
            self._control.writeOnce(self._plf.Torques(self._tau.tolist()))
        except Exception as exc:
            raise self._fault(exc) from exc
        self._pending_write = False

    def _abort_if_late(self, late_us: float) -> None:
        """End torque control and raise when the pending state's answer comes ``late_us`` [µs] after it,
        more than ``config.late_abort_ms``: a real Franka stops there (communication_constraints_violation);
        a twin would keep the last torque on an arm nobody controls."""
        if late_us > self.config.late_abort_ms * 1e3:
            self.close()
            raise RobotCommunicationError(
                f"the control loop answered {late_us / 1e3:.0f} ms late (--late-abort-ms "
                f"{self.config.late_abort_ms:g}; a cycle is 1 ms): the PC stalled, or something slow ran between "
                "two ticks while torque control was on; a real Franka stops there "
                "(communication_constraints_violation). Torque control ended"
                + ("; on the twin, a machine this busy needs --late-abort-ms 5000 (loopback only)"
                   if self.config.is_loopback else
                   "; see docs/real_robot.md for the PC's set-up (real-time kernel, performance governor)"))

    def step(self) -> RobotState:
        """Send the torque set by :meth:`apply_torque` (unless it went already) and wait for the next
        state (1 ms)."""
        if self._closed:
            raise RobotClosedError("the Franka backend is closed")
        try:
            if self.config.dry_run:
                if math.isnan(self._compute_us):  # the task stepped without a torque
                    self._compute_us = (time.perf_counter() - self._t_read) * 1e6
                terms = self._model_ahead()
                self.wrench.prefetch(self._state.ee_rotation)
                franka_state, period_ms = self._read_dry()
            else:
                restarted = self._control is None
                if restarted:
                    self._control = self.robot.start_torque_control()
                    self._pending_write = False
                    self._gc_off()
                    self._compute_us = float("nan")  # the first state of a control: nothing to answer yet
                    terms = None  # the last state read is from before the pause
                else:
                    if self._pending_write:  # the task stepped without a new torque: the last one again
                        self._send()
                    terms = self._model_ahead()
                self.wrench.prefetch(self._state.ee_rotation)
                franka_state, duration = self._control.readOnce()
                self._pending_write = True
                period_ms = duration.to_sec() * 1e3
                if restarted:  # the robot's torque-rate check starts from its own last command, not ours
                    self.torque_restart = np.array(franka_state.tau_J_d, dtype=float)
        except RobotError:
            raise
        except Exception as exc:
            raise self._fault(exc) from exc
        now = time.perf_counter()
        period_us = (now - self._last_read_wall) * 1e6 if self._last_read_wall is not None else float("nan")
        compute_us = self._compute_us if self._last_read_wall is not None else float("nan")
        self._last_read_wall = now
        lost = _lost_cycles(period_ms)
        if not math.isnan(compute_us):
            self.timing.add(compute_us, period_us, lost, float(franka_state.control_command_success_rate))
        self._t += max(period_ms, 1.0) * 1e-3
        self.timing.stall(self._t, period_us)
        self._t_read = now
        self._franka_state = franka_state
        self._state = self._convert(franka_state, terms)
        if self.config.dry_run:
            self._compute_us = float("nan")  # set by the next apply_torque
        return self._state

    def _model_ahead(self) -> ModelTerms | None:
        """The model terms for the next state, evaluated at the last one while the robot executes
        its command, so that libfranka's four model calls are not between a state and its command
        (docs/real_robot.md); None when the last state is older than a cycle (after a pause, or a late
        tick), and the next state's own terms are evaluated with it. Within a cycle the joints move by
        at most dq·1 ms (under 2.6 mrad at the Franka's joint speed limits, far less in contact),
        which changes J, M, C and g by a fraction of a percent."""
        if time.perf_counter() - self._t_read >= self.model_ahead_max_age_s:
            return None
        return franka_model_terms(self._franka_state, self.model)

    def _read_dry(self) -> tuple[Any, float]:
        """One state at the robot's rate without torque control (read_once waits for the next packet)."""
        before = time.perf_counter()
        state = self.robot.read_once()
        return state, max(1.0, (time.perf_counter() - before) * 1e3)

    def _finish_motion(self, tau: np.ndarray) -> None:
        """Answer the pending state with ``tau`` and ``motion_finished``: libfranka ends torque control."""
        cmd = self._plf.Torques(tau.tolist())
        cmd.motion_finished = True
        if not self._pending_write:
            self._control.readOnce()
        self._control.writeOnce(cmd)

    def _gc_off(self) -> None:
        """No cyclic garbage collection while torque control runs: a full collection takes
        milliseconds, a lost cycle or more; the loop's objects are freed by reference counting, and
        the objects that exist now are frozen out of later collections (:func:`gc.freeze`)."""
        if gc.isenabled():
            gc.freeze()
            gc.disable()
            self._gc_was_on = True

    def _gc_on(self) -> None:
        if self._gc_was_on:
            gc.unfreeze()
            gc.enable()
            self._gc_was_on = False

    def _fault(self, exc: Exception) -> RobotError:
        """End torque control after a libfranka exception and name it."""
        self._gc_on()
        plf = self._plf
        kind = type(exc).__name__
        detail = str(exc)
        self.events.append(f"{kind}: {detail}")
        self._control = None  # libfranka has ended the motion; the object must not be used again
        self._pending_write = False
        recovered = ""
        if self.config.auto_recovery and isinstance(exc, plf.ControlException):
            try:
                self.robot.automatic_error_recovery()
                recovered = " (automatic_error_recovery done: the robot is ready again)"
            except Exception as rec_exc:  # reported; the original error stands
                recovered = f" (automatic_error_recovery failed: {rec_exc})"
        error = libfranka_error_kind(exc, plf)
        return error(f"libfranka {kind}: {detail}{recovered}; {_HINTS[error]}")

    def camera_frame(self) -> CameraFrame | None:
        """None: on the real robot the wrist camera runs in the vision process."""
        return None

    def solve_ik(self, position_world: np.ndarray, rotation_world: np.ndarray | None = None,
                 q_init: np.ndarray | None = None, q_posture: np.ndarray | None = None, *,
                 settled_step_rad: float | None = None, max_iter: int = 500) -> np.ndarray:
        """Joint positions (7,) [rad] for a TCP pose, on tactex's kinematic model of the arm and tool
        (the robot does not move); ``q_init`` defaults to the robot's current q. ``settled_step_rad``
        [rad], ``max_iter``: see :func:`~tactex.sim.ik.solve_site_ik` (the defaults: the full search)."""
        q0 = self._state.q if q_init is None else q_init
        self.pause()  # an IK solve takes milliseconds: more than a control cycle
        return self._kinematics().solve_ik(position_world, rotation_world, q0, q_posture,
                                           settled_step_rad=settled_step_rad, max_iter=max_iter)

    def tcp_pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The TCP's position (3,) [m] and orientation (3, 3) in the base frame at joint positions ``q`` (7,) [rad],
        on tactex's kinematic model of the arm and tool (the robot does not move; microseconds, no pause)."""
        return self._kinematics().tcp_pose(q)

    def link_capsules(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The arm's links at joint positions ``q`` (7,) [rad] as capsules of tactex's kinematic model (an
        approximation of the Panda's shape): axes' ends (K, 2, 3) [m] in the base frame, radii (K,) [m]."""
        return self._kinematics().link_capsules(q)

    @property
    def torque_paused(self) -> bool:
        """Torque control is not running (paused, or not started yet): the robot holds its posture itself."""
        return self._control is None and not self.config.dry_run

    def pause(self) -> None:
        """End torque control until the next :meth:`step` (which starts it again), so that work
        longer than a cycle can run between two ticks: the last torque is sent with
        ``motion_finished`` and the robot holds its posture itself meanwhile. A no-op when torque
        control is not running."""
        if self._control is None or self.config.dry_run:
            return
        if self._pending_write:  # the state read last still waits for its answer: it must not come late either
            self._abort_if_late((time.perf_counter() - self._t_read) * 1e6)
        try:
            self._finish_motion(self._tau)
        except Exception as exc:
            raise self._fault(exc) from exc
        self._control = None
        self._pending_write = False
        self._last_read_wall = None  # the pause is not a late tick
        self._gc_on()

    def bare_hold(self, duration_s: float) -> RobotState:
        """Hold the current posture for ``duration_s`` [s] with the gains of Franka's joint impedance
        example (:data:`BARE_STIFFNESS_N_M_PER_RAD`, :data:`BARE_DAMPING_N_M_S_PER_RAD`) in 7 Python floats
        per tick: no model, no state conversion, no safety layer, none of tactex's controllers. The link's
        floor: what this PC, its network and the robot allow a loop that does (almost) nothing;
        :attr:`timing` records it as :meth:`step` does. Unlike Franka's example it adds no Coriolis term
        and no rate limiter (the arm holds still); each torque is clipped a margin below the Franka's limits
        (:data:`~tactex.control.safety.LIMIT_MARGIN`) and a
        non-finite state is answered with zero torque. Torque control ends (``motion_finished``) when it
        returns; the returned state is the last one answered. The wrench source is not read meanwhile."""
        if self._closed:
            raise RobotClosedError("the Franka backend is closed")
        if self.config.dry_run:
            raise ConfigError("the bare hold commands torques: it cannot run in a dry run (drop --dry-run)")
        if isinstance(duration_s, bool) or not isinstance(duration_s, (int, float)) \
                or not (math.isfinite(duration_s) and duration_s > 0):
            raise InputError(f"the bare hold's duration must be a positive number of seconds, got {duration_s!r}")
        self.pause()
        plf, timing, perf = self._plf, self.timing, time.perf_counter
        k, d = BARE_STIFFNESS_N_M_PER_RAD, BARE_DAMPING_N_M_S_PER_RAD
        lim = [m * (1.0 - LIMIT_MARGIN) for m in FRANKA_TAU_MAX]  # a margin below the robot's limits
        zero = [0.0] * 7
        try:
            control = self._control = self.robot.start_torque_control()
            self._gc_off()
            state, duration = control.readOnce()
            self._pending_write = True
            self._t += max(duration.to_sec(), 1e-3)
            q0 = list(state.q)
            t_read = perf()
            t_end = t_read + duration_s
            while True:
                q, dq = state.q, state.dq
                tau = [k[j] * (q0[j] - q[j]) - d[j] * dq[j] for j in range(7)]
                # checked before the clip: Python's min/max turn a NaN into either bound
                tau = [min(lim[j], max(-lim[j], tau[j])) for j in range(7)] if all(map(math.isfinite, tau)) else zero
                t_send = perf()
                control.writeOnce(plf.Torques(tau))
                self._pending_write = False
                self._franka_state = state
                if t_send >= t_end:
                    break
                state, duration = control.readOnce()
                self._pending_write = True
                now = perf()
                period_ms = duration.to_sec() * 1e3
                timing.add((t_send - t_read) * 1e6, (now - t_read) * 1e6, _lost_cycles(period_ms),
                           float(state.control_command_success_rate))
                t_read = now
                self._t += max(period_ms, 1.0) * 1e-3
            self._tau = np.zeros(7)
            self._finish_motion(self._tau)  # reads the next state, answers it with motion_finished
            self._control = None
        except Exception as exc:
            raise self._fault(exc) from exc  # ends the control
        finally:
            self._last_read_wall = None
            if self._control is None:
                self._gc_on()
        self._state = self._convert(self._franka_state)
        return self._state

    def loop_metrics(self) -> dict[str, Any]:
        """The loop's timing figures and the wrench source's counters (metrics.json)."""
        return {**self.timing.metrics(), **self.wrench.stats(), "robot_errors": list(self.events),
                "dry_run": self.config.dry_run, "wrench_source": self.wrench.name,
                "control_scheduling": f"{self.scheduling}; {self.cpu_latency.description}"}

    def _restore_scheduling(self) -> None:
        """The thread's scheduling as it was before this backend (libfranka raises it to SCHED_FIFO 99 when
        control starts, :func:`pin_control_thread` pins it): a program that goes on after the robot must not
        run, nor start processes, at real-time priority."""
        if self._scheduling_before is not None:
            self.events.extend(f"close: {p}" for p in self._scheduling_before.restore())

    def close(self) -> None:
        """End torque control (``motion_finished`` with zero torque) and close the streams; idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            if self._control is not None and not self.config.dry_run:
                self._finish_motion(np.zeros(7))
        except Exception as exc:  # the link is gone: libfranka stopped the motion itself
            self.events.append(f"close: {type(exc).__name__}: {exc}")
        finally:
            self._control = None
            self._gc_on()
            try:
                self.cpu_latency.release()
            except OSError as exc:  # the request ends with the process anyway; the rest must still close
                self.events.append(f"close: cpu latency request: {exc}")
            self.wrench.close()
            if self._ik is not None:
                self._ik.close()
            self._restore_scheduling()
            # dropping libfranka's Robot closes its connection: the robot (or twin) serves one client at
            # a time and a second one would wait forever
            self.robot = None
            self.model = None
