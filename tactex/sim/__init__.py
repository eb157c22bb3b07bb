"""tactex.sim: the MuJoCo world — Franka with F/T sensor, wiping pad and wrist camera, objects, dirt."""

from tactex.sim.camera import RayCastCamera
from tactex.sim.camera_worker import CameraWorker
from tactex.sim.dirt import DirtField, PrestonParams
from tactex.sim.franka import FRANKA_HOME_Q, FRANKA_TORQUE_LIMITS
from tactex.sim.ft_sensor import FTSensorModel
from tactex.sim.objects import (
    OBJECTS,
    SimObject,
    get_object,
    heightfield_from_image,
    heightfield_object,
    object_names,
    register_object,
)
from tactex.sim.scene import CAMERA_PRESETS, Scene, SceneConfig, build_scene
from tactex.sim.tool import ToolGeometry

__all__ = [
    "CAMERA_PRESETS",
    "FRANKA_HOME_Q",
    "FRANKA_TORQUE_LIMITS",
    "OBJECTS",
    "CameraWorker",
    "DirtField",
    "FTSensorModel",
    "PrestonParams",
    "RayCastCamera",
    "Scene",
    "SceneConfig",
    "SimObject",
    "ToolGeometry",
    "build_scene",
    "get_object",
    "heightfield_from_image",
    "heightfield_object",
    "object_names",
    "register_object",
]
