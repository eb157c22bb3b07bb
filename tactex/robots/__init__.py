"""tactex.robots: the backend protocol and its implementations (MuJoCo simulation, libfranka)."""

from tactex.robots.backend import RobotBackend
from tactex.robots.libfranka_backend import LibfrankaBackend
from tactex.robots.mujoco_backend import MujocoBackend

__all__ = ["LibfrankaBackend", "MujocoBackend", "RobotBackend"]
