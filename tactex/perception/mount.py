"""Camera extrinsics: where the wrist camera sits on the tool (VA-UFIC eq. 22).

``tool_T_camera`` is R_c^ee with its offset: eq. 22 composes R_c^0 = R_ee^0 R_c^ee, here as full
poses, world_T_camera = world_T_tool · tool_T_camera. The paper mounts the camera so that its
optical z axis is parallel to the tool z axis; :meth:`CameraMount.parallel` builds that.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tactex.perception.depth import check_pose

__all__ = ["CameraMount", "mount_offset"]


@dataclass(frozen=True)
class CameraMount:
    """Rigid camera-on-tool extrinsics.

    Attributes:
        tool_T_camera: (4, 4) camera optical frame expressed in the tool (TCP) frame.
    """

    tool_T_camera: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self) -> None:
        object.__setattr__(self, "tool_T_camera", check_pose(self.tool_T_camera, "tool_T_camera"))

    @classmethod
    def parallel(cls, offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0), roll_rad: float = 0.0) -> CameraMount:
        """Camera z parallel to the tool z (the paper's mount), shifted by ``offset_m`` in the tool
        frame [m] and rolled about z by ``roll_rad``."""
        c, s = np.cos(roll_rad), np.sin(roll_rad)
        T = np.eye(4)
        T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
        T[:3, 3] = offset_m
        return cls(T)

    def world_T_camera(self, world_T_tool: np.ndarray) -> np.ndarray:
        """Camera pose from the tool pose (eq. 22 with positions)."""
        return check_pose(world_T_tool, "world_T_tool") @ self.tool_T_camera

    def world_T_tool(self, world_T_camera: np.ndarray) -> np.ndarray:
        """Tool pose from the camera pose."""
        return check_pose(world_T_camera, "world_T_camera") @ np.linalg.inv(self.tool_T_camera)


def mount_offset(tilt_deg, shift_m) -> np.ndarray:
    """(4, 4) a camera moved on its mount, in its own optical frame: turned by x-y-z Euler angles ``tilt_deg``
    [deg], shifted by ``shift_m`` [m]; nominal_T_moved, so that tool_T_moved = tool_T_nominal · this."""
    from scipy.spatial.transform import Rotation

    offset = np.eye(4)
    offset[:3, :3] = Rotation.from_euler("xyz", np.asarray(tilt_deg, dtype=float), degrees=True).as_matrix()
    offset[:3, 3] = np.asarray(shift_m, dtype=float)
    return offset
