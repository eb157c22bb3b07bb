"""tactex.robots: the backend protocol and its implementations (MuJoCo simulation, libfranka)."""

from tactex.robots.backend import RobotBackend
from tactex.robots.mujoco_backend import MujocoBackend

__all__ = ["MujocoBackend", "RobotBackend"]
