"""The simulated world a task runs in: the fields every task configuration shares (object, tool,
camera size, recording rate, seed) and the :class:`SceneConfig` they make.

A task's configuration derives from :class:`SimWorldParams` and redefines a field where its default
differs (the object to work on, the capture resolution); dataclass inheritance keeps one place
for the tool's parameters, their checks and the scene they build.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from tactex.config import param
from tactex.errors import ConfigError
from tactex.pointcloud.units import check_units
from tactex.sim.part import is_part_file, resolve_object_or_part
from tactex.sim.scene import SceneConfig

__all__ = ["JOINT_FRICTION_N_M", "SimWorldParams"]

#: Dry joint friction [N·m] that ``joint_friction_scale`` multiplies: what a real arm's friction
#: compensation leaves (an assumption: 0.1 N·m, a tenth of the stock friction franky-sim and franka-sim
#: put on an uncompensated FR3 joint, 0.25–1.14 N·m); the scene itself has none.
JOINT_FRICTION_N_M = 0.1


@dataclass(frozen=True)
class SimWorldParams:
    """Object, tool and camera of a simulated task (units in brackets)."""

    object_name: str = param("sine_panel", "object from the registry (tactex.sim.objects), or a part's mesh or scan "
                             "file (.stl/.obj/.ply/.pcd/.npz) made a height-field object (tactex.sim.part)",
                             option="object", aliases=("--object-name",))
    object_position: tuple[float, float, float] | None = param(
        None, "object position in the world [m]; default: the object's own placement (0.5 0 0; the cup 0.42 0 0, "
        "its marked wall well inside the arm's reach)")
    tool_stiffness_n_per_m: float = param(2500.0, "sponge stiffness [N/m] (a kitchen sponge: ~2–3 kN/m)")
    tool_pad_shape: str = param("sphere", "pad shape: sphere (domed sponge) or cylinder (flat)")
    tool_friction: float = param(0.4, "pad–surface Coulomb friction [-]")
    camera_width: int = param(160, "wrist camera image width [px]")
    camera_height: int = param(120, "wrist camera image height [px]")
    record_hz: float = param(100.0, "rate of the recorded time series [Hz]")
    ft_noise_n: float = param(0.0, "F/T force noise standard deviation [N]")
    ft_noise_nm: float = param(0.0, "F/T torque noise standard deviation [N·m]")
    depth_noise_m: float = param(0.0, "depth noise standard deviation at 1 m, grows with depth² [m]")
    command_delay_ticks: int = param(
        0, "control periods before a torque command acts (1: a real Franka's one-cycle latency) [-]")
    tool_mass_scale: float = param(
        1.0, "model mismatch: the tool's real mass as a multiple of the load the robot compensates (its F/T "
        "calibration made with the tool as it is) [-]")
    joint_friction_scale: float = param(
        1.0, "model mismatch: the arm's joint friction; 1 is the scene's own (viscous 0.1 N·m·s/rad, no dry "
        "friction), s ≠ 1 scales the viscous friction by s and adds s × 0.1 N·m of dry friction per joint [-]")
    units: str = param("m", "length unit of the --object FILE: m, mm or in; its coordinates are converted to metres "
                            "as it is read")
    seed: int = param(0, "seed of the sensor noise (the physics is deterministic: with the noise at its "
                         "default 0 the seed changes nothing but what a task seeds itself)")

    def __post_init__(self) -> None:
        object.__setattr__(self, "object_name", resolve_object_or_part(self.object_name))  # 'Plate' is plate
        check_units(self.units)
        if is_part_file(self.object_name):  # the part's file read, its size, overhangs and place checked up front
            SceneConfig(object_name=self.object_name, object_position=self.object_position, object_units=self.units)
        for name in ("tool_stiffness_n_per_m", "record_hz"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be a positive number, got {getattr(self, name)!r}")
        for name in ("tool_friction", "ft_noise_n", "ft_noise_nm", "depth_noise_m", "joint_friction_scale"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"{name} must be a finite number ≥ 0, got {getattr(self, name)!r}")
        if int(self.seed) != self.seed or self.seed < 0:
            raise ConfigError(f"seed must be an integer ≥ 0, got {self.seed!r}")

    def scene(self, **scene_fields: Any) -> SceneConfig:
        """The task's :class:`SceneConfig`: these fields plus the task's own ``scene_fields``."""
        if self.joint_friction_scale != 1.0:
            nominal = SceneConfig()
            scene_fields.setdefault("joint_damping", nominal.joint_damping * self.joint_friction_scale)
            scene_fields.setdefault("joint_frictionloss", JOINT_FRICTION_N_M * self.joint_friction_scale)
        return SceneConfig(
            object_name=self.object_name, object_position=self.object_position, object_units=self.units,
            camera_width=self.camera_width,
            camera_height=self.camera_height, seed=self.seed, tool_stiffness_n_per_m=self.tool_stiffness_n_per_m,
            tool_pad_shape=self.tool_pad_shape, tool_friction=self.tool_friction, ft_noise_n=self.ft_noise_n,
            ft_noise_nm=self.ft_noise_nm, depth_noise_m=self.depth_noise_m,
            command_delay_ticks=self.command_delay_ticks, tool_mass_scale=self.tool_mass_scale, **scene_fields,
        )
