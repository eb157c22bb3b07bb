"""Scene assembly: table, Franka with F/T sensor, wiping pad and wrist camera, one object with dirt.

:class:`SceneConfig` holds every knob with its unit; :func:`build_scene` turns it into a compiled
MuJoCo model plus the ids and helpers the backend needs (:class:`Scene`).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from tactex.config import param
from tactex.errors import ConfigError, SimulationError
from tactex.perception.frame import CameraIntrinsics, D415_DEPTH_640x480, D435I_DEPTH_640x480
from tactex.pointcloud.markings import MARKINGS
from tactex.pointcloud.units import check_units
from tactex.sim.dirt import DirtField, PrestonParams
from tactex.sim.franka import FRANKA_TORQUE_LIMITS, franka_arm_xml
from tactex.sim.objects import SimObject, rotation_from_rpy_deg
from tactex.sim.part import check_reach, object_or_part
from tactex.sim.tool import TOOL_SITE_NAMES, ToolGeometry, tool_xml

__all__ = ["CAMERA_PRESETS", "Scene", "SceneConfig", "build_scene"]

#: Camera models selectable by name.
CAMERA_PRESETS: dict[str, CameraIntrinsics] = {"d435i": D435I_DEPTH_640x480, "d415": D415_DEPTH_640x480}


@dataclass(frozen=True)
class SceneConfig:
    """Everything that defines a simulated scene (units in brackets)."""

    object_name: str = param("sine_panel", "object from the registry (tactex.sim.objects), or a part's mesh or scan "
                                           "file (tactex.sim.part)")
    object_units: str = param("m", "length unit of a part's file (object_name a path): m, mm or in")
    object_position: tuple[float, float, float] | None = param(
        None, "object frame origin in the world [m]; default: the object's own placement (0.5 0 0; the cup 0.42 0 0)")
    object_rpy_deg: tuple[float, float, float] = param((0.0, 0.0, 0.0), "object orientation roll/pitch/yaw [deg]")
    marking: str = param("", "dirt pattern (X, RLI, blobs, shapes, full); empty = the object's default")
    tool_stiffness_n_per_m: float = param(10000.0, "sponge stiffness along the tool axis [N/m]")
    tool_damping_ratio: float = param(0.7, "sponge damping, fraction of critical [-]")
    tool_friction: float = param(0.4, "pad–surface Coulomb friction coefficient [-]")
    tool_pad_radius_m: float = param(0.025, "sponge radius [m]")
    tool_pad_shape: str = param("cylinder", "pad shape: cylinder (flat sponge) or sphere")
    payload_mass_kg: float = param(0.0, "extra mass hung at the TCP, unknown to the F/T calibration [kg]")
    tool_mass_scale: float = param(
        1.0, "the wrist assembly's real mass and inertia as a multiple of its nominal one, which the gravity "
        "compensation keeps assuming: the robot's tool load mis-set (the F/T's own calibration is made with the "
        "tool as it is; a mis-calibrated sensor is ft_bias) [-]")
    camera_preset: str = param("d435i", "camera intrinsics preset: d435i or d415")
    camera_width: int = param(160, "camera image width [px]")
    camera_height: int = param(120, "camera image height [px]")
    camera_rate_hz: float = param(30.0, "camera frame rate [Hz]")
    camera_latency_s: float = param(0.0, "camera exposure-to-delivery delay [s], ≤ one frame period")
    camera_worker: bool = param(False, "ray cast the camera frames in a worker process on another core; a frame "
                                "is then delivered at the next exposure: one frame period of latency")
    camera_worker_timeout_s: float = param(60.0, "longest wait for the camera worker (its start included) [s]")
    camera_raycast: str = param("analytic", "depth ray casting: analytic (table + object) or mujoco (mj_multiRay)")
    depth_noise_m: float = param(0.0, "depth noise standard deviation at 1 m, grows with depth² [m]")
    ft_noise_n: float = param(0.0, "F/T force noise standard deviation [N]")
    ft_noise_nm: float = param(0.0, "F/T torque noise standard deviation [N·m]")
    ft_bias: tuple[float, float, float, float, float, float] = param(
        (0.0, 0.0, 0.0, 0.0, 0.0, 0.0), "F/T sensor bias [N, N·m] (uncalibrated offset)")
    ft_cutoff_hz: float = param(0.0, "F/T first-order low-pass cut-off [Hz] (0 = none)")
    joint_damping: float = param(0.1, "viscous joint damping [N·m·s/rad]")
    joint_frictionloss: float = param(0.0, "dry joint friction [N·m]")
    armature: float = param(0.0, "reflected rotor inertia per joint [kg·m²]")
    gravity_compensation: bool = param(True, "add g(q) to the commanded torque, like the Franka firmware")
    dirt_resolution_m: float = param(0.002, "dirt grid cell size [m]")
    preston_coefficient: float = param(5e-3, "Preston wear coefficient [1/(Pa·m)]")
    dirt_force_threshold_n: float = param(2.0, "normal force below which no dirt is removed [N]")
    contact_sample_ticks: int = param(5, "ticks between contact ground-truth samples and dirt updates [-]")
    timestep_s: float = param(0.001, "physics and control period [s]")
    command_delay_ticks: int = param(
        0, "control periods between apply_torque and the torque acting (a FIFO) [-]: a real Franka applies the "
        "torque computed from state k one cycle later (1), franky-sim over libfranka's protocol 0–2 cycles later")
    seed: int = param(0, "seed of sensor noise")

    def __post_init__(self) -> None:
        if int(self.seed) != self.seed or self.seed < 0:
            raise ConfigError(f"seed must be an integer ≥ 0, got {self.seed!r}")
        check_units(self.object_units)
        obj = object_or_part(self.object_name, self.object_units)
        if self.object_position is None:
            object.__setattr__(self, "object_position", tuple(float(v) for v in obj.position_m))
        if self.marking and self.marking not in MARKINGS:
            raise ConfigError(f"unknown marking '{self.marking}'; valid: {', '.join(sorted(MARKINGS))} or ''")
        if self.camera_preset not in CAMERA_PRESETS:
            raise ConfigError(f"unknown camera preset '{self.camera_preset}'; valid: {', '.join(CAMERA_PRESETS)}")
        if self.camera_raycast not in ("analytic", "mujoco"):
            raise ConfigError(f"camera_raycast must be 'analytic' or 'mujoco', got '{self.camera_raycast}'")
        if self.camera_worker and self.camera_raycast != "analytic":
            raise ConfigError("camera_worker needs camera_raycast='analytic' (the worker has no MuJoCo data)")
        period = 1.0 / self.camera_rate_hz if self.camera_rate_hz > 0 else 0.0
        if self.camera_worker and 1e-9 < self.camera_latency_s < period - 1e-9:
            raise ConfigError(f"with camera_worker a frame arrives one frame period ({period:.4g} s) after its "
                              f"exposure; camera_latency_s must be 0 or that period, got {self.camera_latency_s}")
        if not (np.isfinite(self.camera_worker_timeout_s) and self.camera_worker_timeout_s > 0):
            raise ConfigError(f"camera_worker_timeout_s must be > 0 s, got {self.camera_worker_timeout_s}")
        if self.tool_pad_shape not in ("cylinder", "sphere"):
            raise ConfigError(f"tool_pad_shape must be 'cylinder' or 'sphere', got '{self.tool_pad_shape}'")
        positive = {
            "tool_mass_scale": (0.1, 10.0),
            "tool_stiffness_n_per_m": (100.0, 1e6),
            "tool_pad_radius_m": (0.005, 0.1),
            "camera_rate_hz": (0.1, 1000.0),
            "timestep_s": (1e-4, 0.005),
        }
        for name, (lo, hi) in positive.items():
            v = getattr(self, name)
            if not (np.isfinite(v) and lo <= v <= hi):
                raise ConfigError(f"{name} must be in [{lo:g}, {hi:g}], got {v}")
        nonneg = ("tool_damping_ratio", "tool_friction", "payload_mass_kg", "depth_noise_m", "ft_noise_n",
                  "ft_noise_nm", "ft_cutoff_hz", "joint_damping", "joint_frictionloss", "armature",
                  "preston_coefficient", "dirt_force_threshold_n")
        for name in nonneg:
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ConfigError(f"{name} must be a finite number ≥ 0, got {v}")
        if not (0.0 <= self.camera_latency_s <= 1.0 / self.camera_rate_hz + 1e-9):
            raise ConfigError(
                f"camera_latency_s must be in [0, 1/camera_rate_hz = {1.0 / self.camera_rate_hz:.4g}] s, "
                f"got {self.camera_latency_s}"
            )
        if isinstance(self.command_delay_ticks, bool) or not (
                isinstance(self.command_delay_ticks, (int, np.integer)) and 0 <= self.command_delay_ticks <= 50):
            raise ConfigError(f"command_delay_ticks must be an integer in [0, 50], got {self.command_delay_ticks!r}")
        if not (isinstance(self.contact_sample_ticks, int) and 1 <= self.contact_sample_ticks <= 100):
            raise ConfigError(f"contact_sample_ticks must be an integer in [1, 100], got {self.contact_sample_ticks!r}")
        if not (8 <= self.camera_width <= 4096 and 8 <= self.camera_height <= 4096):
            raise ConfigError(f"camera size must be within 8..4096 px, got {self.camera_width}×{self.camera_height}")
        for name, n in (("object_position", 3), ("object_rpy_deg", 3), ("ft_bias", 6)):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != (n,) or not np.isfinite(v).all():
                raise ConfigError(f"{name} must be {n} finite numbers, got {getattr(self, name)!r}")
        pos, rot = self.object_pose()
        check_reach(obj, pos, rot)

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return CAMERA_PRESETS[self.camera_preset].scaled(self.camera_width, self.camera_height)

    @property
    def tool(self) -> ToolGeometry:
        return ToolGeometry(
            pad_radius_m=self.tool_pad_radius_m,
            pad_shape=self.tool_pad_shape,
            stiffness_n_per_m=self.tool_stiffness_n_per_m,
            damping_ratio=self.tool_damping_ratio,
            friction=self.tool_friction,
            payload_mass_kg=self.payload_mass_kg,
        )

    @property
    def sim_object(self) -> SimObject:
        return object_or_part(self.object_name, self.object_units)

    def object_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """World position [m] and rotation of the object frame (scene pose ∘ intrinsic tilt)."""
        obj = self.sim_object
        rot = rotation_from_rpy_deg(self.object_rpy_deg) @ rotation_from_rpy_deg(obj.intrinsic_rpy_deg)
        pos = np.asarray(self.object_position, dtype=float) + np.array([0.0, 0.0, obj.lift_m])
        return pos, rot


@dataclass
class Scene:
    """A compiled scene: the MuJoCo model and the ids/helpers of its parts."""

    config: SceneConfig
    model: mujoco.MjModel
    xml: str
    sim_object: SimObject
    dirt: DirtField
    arm_qpos: np.ndarray  # (7,) qpos addresses of the arm joints
    arm_dof: np.ndarray  # (7,) dof addresses
    torque_limits: np.ndarray
    ids: dict[str, int]

    @property
    def n_joints(self) -> int:
        return 7


def _scene_xml(cfg: SceneConfig) -> str:
    intr = cfg.intrinsics
    arm = franka_arm_xml(
        tool_xml(cfg.tool, intr.fovy_deg),
        joint_damping=cfg.joint_damping,
        joint_frictionloss=cfg.joint_frictionloss,
        armature=cfg.armature,
        gravcomp=True,  # always computed (g(q) for the state); the backend cancels it when disabled
    )
    pos, rot = cfg.object_pose()
    asset, body = cfg.sim_object.mjcf("object", pos, rot)
    act = "".join(
        f'<motor name="motor{i + 1}" joint="panda_joint{i + 1}" ctrlrange="{-lim:g} {lim:g}"/>'
        for i, lim in enumerate(FRANKA_TORQUE_LIMITS)
    )
    return f"""<mujoco model="tactex_scene">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{cfg.timestep_s:g}" integrator="implicitfast" cone="elliptic" gravity="0 0 -9.81"/>
  <visual>
    <global offwidth="1280" offheight="960"/><quality shadowsize="2048"/>
    <headlight ambient="0.35 0.35 0.35" diffuse="0.5 0.5 0.5"/>
  </visual>
  <default>
    <default class="arm_visual">
      <geom contype="0" conaffinity="0" group="2" rgba="0.92 0.92 0.95 1" density="0"/>
    </default>
    <default class="tool_visual"><geom contype="0" conaffinity="0" group="2" density="0"/></default>
  </default>
  <asset>
    <texture name="grid" type="2d" builtin="checker" rgb1="0.35 0.3 0.25" rgb2="0.4 0.35 0.3" width="256" height="256"/>
    <material name="table" texture="grid" texrepeat="8 8"/>
    {asset}
  </asset>
  <worldbody>
    <light pos="0.5 0 1.5" dir="0 0 -1" diffuse="0.8 0.8 0.8"/>
    <camera name="overview" pos="1.25 -0.85 0.75" mode="targetbody" target="object"/>
    <geom name="table" type="box" pos="0.4 0 -0.02" size="0.8 0.8 0.02" material="table" rgba="0.4 0.35 0.3 1"
          contype="0" conaffinity="2" group="0"/>
    {arm}
    {body}
  </worldbody>
  <actuator>{act}</actuator>
  <sensor>
    <force name="ft_force" site="ft_site"/>
    <torque name="ft_torque" site="ft_site"/>
  </sensor>
</mujoco>"""


#: The wrist assembly's bodies (sensor, adapter with the camera, sponge pad): what a tool load declares.
TOOL_BODIES = ("ft_sensor", "tool_body", "pad")


def _scale_tool_mass(model: mujoco.MjModel, scale: float) -> None:
    """The wrist assembly ``scale`` × as heavy as declared: its bodies' masses and inertias scaled, their
    gravity compensation kept at the nominal weight (``gravcomp`` 1/scale of the new weight), as a robot
    compensates the load it was told, whatever hangs on its flange."""
    for name in TOOL_BODIES:
        b = model.body(name).id
        model.body_mass[b] *= scale
        model.body_inertia[b] *= scale
        model.body_gravcomp[b] = model.body_gravcomp[b] / scale
    mujoco.mj_setConst(model, mujoco.MjData(model))


def build_scene(cfg: SceneConfig | None = None) -> Scene:
    """Compile the scene of ``cfg`` (default: VA-UFIC sine panel in front of the robot)."""
    cfg = cfg or SceneConfig()
    xml = _scene_xml(cfg)
    try:
        model = mujoco.MjModel.from_xml_string(xml)
    except ValueError as exc:
        raise SimulationError(f"the scene for object '{cfg.object_name}' does not compile: {exc}") from exc
    if cfg.tool_mass_scale != 1.0:
        _scale_tool_mass(model, cfg.tool_mass_scale)
    obj = cfg.sim_object
    marking = cfg.marking or obj.marking
    dirt = DirtField(
        obj.surface, marking, cfg.dirt_resolution_m,
        PrestonParams(cfg.preston_coefficient, cfg.dirt_force_threshold_n, cfg.tool_pad_radius_m),
    )
    names = TOOL_SITE_NAMES
    ids = {
        "ft_site": model.site(names["ft_site"]).id,
        "tcp": model.site(names["tcp"]).id,
        "flange": model.site("flange").id,
        "ft_body": model.body(names["tool_body"]).id,
        "pad_body": model.body(names["pad_body"]).id,
        "pad_geom": model.geom(names["pad_geom"]).id,
        "pad_joint": model.joint(names["pad_joint"]).id,
        "camera": model.camera(names["camera"]).id,
        "object_body": model.body("object").id,
        "object_geom": model.geom("object_geom").id,
        "object_mocap": int(model.body("object").mocapid[0]),
        "table_geom": model.geom("table").id,
        "ft_force_adr": int(model.sensor("ft_force").adr[0]),
        "ft_torque_adr": int(model.sensor("ft_torque").adr[0]),
        "link7": model.body("panda_link7").id,
    }
    joints = [model.joint(f"panda_joint{i + 1}") for i in range(7)]
    return Scene(
        config=cfg,
        model=model,
        xml=xml,
        sim_object=obj,
        dirt=dirt,
        arm_qpos=np.array([int(j.qposadr[0]) for j in joints]),
        arm_dof=np.array([int(j.dofadr[0]) for j in joints]),
        torque_limits=FRANKA_TORQUE_LIMITS.copy(),
        ids=ids,
    )
