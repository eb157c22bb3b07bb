"""tactex: tactile exploration for torque-controlled robots.

Stages (see DESIGN.md; a module imports only from its own stage or earlier ones): ``geometry`` →
``pointcloud`` → ``perception``/``spectral``/``ergodic`` → ``control`` → ``sim`` → ``robots`` →
``twin`` → ``tasks`` → ``report`` → ``experiments`` → ``commands``. Import from the stage packages;
the top level re-exports the core types only.
"""

from importlib import import_module
from typing import TYPE_CHECKING

from tactex import errors

if TYPE_CHECKING:
    from tactex.control.controller import Controller
    from tactex.control.state import RobotState
    from tactex.perception.estimate import SurfaceEstimate
    from tactex.perception.frame import CameraFrame, CameraIntrinsics
    from tactex.pointcloud.cloud import SurfaceCloud
    from tactex.robots.backend import RobotBackend

# The core types load on first use (PEP 562): `import tactex` stays light for the CLI and for
# the simulator's camera worker process, which need none of them at start.
_LAZY = {
    "Controller": "tactex.control.controller",
    "RobotState": "tactex.control.state",
    "SurfaceEstimate": "tactex.perception.estimate",
    "CameraFrame": "tactex.perception.frame",
    "CameraIntrinsics": "tactex.perception.frame",
    "SurfaceCloud": "tactex.pointcloud.cloud",
    "RobotBackend": "tactex.robots.backend",
}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'tactex' has no attribute {name!r}")


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
