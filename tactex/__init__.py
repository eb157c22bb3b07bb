"""tactex: tactile exploration for torque-controlled robots.

Stages (see DESIGN.md): ``pointcloud`` → ``perception`` → ``spectral`` → ``ergodic`` →
``control`` → ``robots``/``sim`` → ``tasks`` → ``report``. Import from the stage packages; the
top level re-exports the core types only.
"""

from tactex import errors
from tactex.control.controller import Controller
from tactex.control.state import RobotState
from tactex.perception.estimate import SurfaceEstimate
from tactex.perception.frame import CameraFrame, CameraIntrinsics
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.robots.backend import RobotBackend

__version__ = "0.1.0"

__all__ = [
    "CameraFrame",
    "CameraIntrinsics",
    "Controller",
    "RobotBackend",
    "RobotState",
    "SurfaceCloud",
    "SurfaceEstimate",
    "__version__",
    "errors",
]
