"""A calibration chessboard in the simulated scene, and colour images of it by ray casting.

The board is made of MuJoCo geoms (a white plate, one thin black box per dark square), so it is
part of the scene like the table; it lies flat on the table and collides with nothing. Its colour
images are ray cast in numpy, as :mod:`tactex.sim.raycast` casts the table: each ray meets the
board's plane in closed form (``mujoco.mj_multiRay`` against the squares' boxes costs seconds per
640×480 frame), and takes the colour of the square it lands on, averaged over ``supersample``² rays
per pixel so that square edges are grey where a pixel straddles them, as a real camera's are
(corner refinement relies on it).

The board has an even and an odd number of squares along its sides (``cols + 1`` by ``rows + 1``),
so it is not the same turned by 180°: the square beyond its first inner corner is dark, the one
beyond the last is light, which tells a detection's two possible orders apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from tactex.errors import ConfigError, SimulationError
from tactex.perception.frame import CameraIntrinsics

__all__ = ["BESIDE_OBJECTS_XY_M", "BOARD_GROUP", "ChessBoard", "board_model", "overlay_board", "render_colour"]

#: The geom group of the board (seen with the table and the object in MuJoCo's own renderings).
BOARD_GROUP = 0
#: Where a board lies beside every object at its default placement (the door's edge is at y = 0.3 m) with all the
#: default calibration poses within the arm's reach: its centre x y in the robot base frame [m].
BESIDE_OBJECTS_XY_M = (0.35, 0.45)
#: Brightness of what lies around the board (the table) in its images [0–1].
_TABLE_GREY = 0.4


@dataclass(frozen=True)
class ChessBoard:
    """A chessboard of ``(cols + 1) × (rows + 1)`` squares, i.e. ``cols × rows`` inner corners.

    Attributes:
        cols, rows: inner corners along the board's x and y axes [-] (OpenCV's pattern size).
        square_m: edge of a square [m].
        centre_m: where the board's centre lies in the world, on the table [m].
        yaw_deg: rotation of the board about the world z axis [deg].
    """

    cols: int = 9
    rows: int = 6
    square_m: float = 0.025
    centre_m: tuple[float, float, float] = (0.55, 0.0, 0.0)
    yaw_deg: float = 0.0

    def __post_init__(self) -> None:
        for name in ("cols", "rows"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 2 <= v <= 30:
                raise ConfigError(f"board {name} (inner corners) must be a whole number in [2, 30], got {v!r}")
        if not (np.isfinite(self.square_m) and 0.005 <= self.square_m <= 0.2):
            raise ConfigError(f"board square_m must be in [0.005, 0.2] m, got {self.square_m!r}")

    def world_T_board(self) -> np.ndarray:
        """(4, 4) pose of the board frame: origin at the first inner corner, x along ``cols``, z up."""
        c, s = np.cos(np.radians(self.yaw_deg)), np.sin(np.radians(self.yaw_deg))
        T = np.eye(4)
        T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
        half = 0.5 * self.square_m * np.array([self.cols - 1, self.rows - 1, 0.0])
        T[:3, 3] = np.asarray(self.centre_m, dtype=float) + T[:3, :3] @ np.array([-half[0], -half[1], 0.0])
        T[2, 3] += 0.001  # the squares' top face, 1 mm above the table
        return T

    def object_points(self) -> np.ndarray:
        """(cols·rows, 3) inner corners in the board frame [m], row by row as OpenCV finds them."""
        j, i = np.mgrid[0:self.rows, 0:self.cols]
        return np.stack([i.ravel(), j.ravel(), np.zeros(i.size)], axis=1) * self.square_m

    def xml(self) -> str:
        """The board's geoms (worldbody XML): a white plate one square wider all round, black squares."""
        T = self.world_T_board()
        from tactex.sim.franka import mat_to_quat

        quat = " ".join(f"{v:.8g}" for v in mat_to_quat(T[:3, :3]))
        s = self.square_m
        w, h = (self.cols + 3) * s / 2, (self.rows + 3) * s / 2
        cx, cy = (self.cols - 1) * s / 2, (self.rows - 1) * s / 2
        common = f'contype="0" conaffinity="0" group="{BOARD_GROUP}"'
        geoms = [f'<geom name="board_plate" type="box" pos="{cx:.6g} {cy:.6g} -0.0006" size="{w:.6g} {h:.6g} 0.0004" '
                 f'rgba="1 1 1 1" {common}/>']
        for r in range(self.rows + 1):
            for c in range(self.cols + 1):
                if (r + c) % 2 == 0:
                    x, y = (c - 0.5) * s, (r - 0.5) * s
                    geoms.append(f'<geom type="box" pos="{x:.6g} {y:.6g} -0.0001" size="{s / 2:.6g} {s / 2:.6g} '
                                 f'0.0001" rgba="0 0 0 1" {common}/>')
        pos = " ".join(f"{v:.8g}" for v in T[:3, 3])
        return f'<body name="board" pos="{pos}" quat="{quat}">{"".join(geoms)}</body>'


def board_model(scene_xml: str, board: ChessBoard) -> mujoco.MjModel:
    """The scene of ``scene_xml`` (:attr:`tactex.sim.scene.Scene.xml`) with ``board`` on the table."""
    if scene_xml.count("</worldbody>") != 1:
        raise SimulationError("the scene XML must hold one worldbody to place the board in")
    try:
        return mujoco.MjModel.from_xml_string(scene_xml.replace("</worldbody>", board.xml() + "</worldbody>"))
    except ValueError as exc:
        raise SimulationError(f"the scene with the board does not compile: {exc}") from exc


def _board_rays(board: ChessBoard, world_T_camera: np.ndarray, intrinsics: CameraIntrinsics,
                supersample: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each of the ``supersample``² rays per pixel met with the board's plane (the geoms' top faces):
    its brightness (0 on a dark square, 1 on the plate), whether it lands on the plate, and its depth
    along the optical axis [m] (inf: it never meets the plane); each (H, n, W, n)."""
    k, n = intrinsics, int(supersample)
    offsets = (np.arange(n) + 0.5) / n - 0.5
    u = (np.arange(k.width)[:, None] + offsets[None, :]).ravel()
    v = (np.arange(k.height)[:, None] + offsets[None, :]).ravel()
    uu, vv = np.meshgrid(u.astype(np.float32), v.astype(np.float32))  # float32: sub-micrometre on the board
    board_T_camera = np.linalg.inv(board.world_T_board()) @ np.asarray(world_T_camera, dtype=float)
    rot, origin = board_T_camera[:3, :3], board_T_camera[:3, 3]
    dx = (uu - np.float32(k.cx)) / np.float32(k.fx)
    dy = (vv - np.float32(k.cy)) / np.float32(k.fy)
    r = rot.astype(np.float32)
    dirs = [r[i, 0] * dx + r[i, 1] * dy + r[i, 2] for i in range(3)]  # in the board frame, unit optical depth
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -origin[2] / dirs[2]
    hit = np.isfinite(t) & (t > 0)
    x = np.where(hit, origin[0] + t * dirs[0], np.inf) / board.square_m
    y = np.where(hit, origin[1] + t * dirs[1], np.inf) / board.square_m
    # squares span [-1, cols] × [-1, rows] in units of a square, the plate one square more all round
    on_squares = (x >= -1) & (x < board.cols) & (y >= -1) & (y < board.rows)
    on_plate = (x >= -2) & (x < board.cols + 1) & (y >= -2) & (y < board.rows + 1)
    dark = on_squares & ((np.floor(x + 1) + np.floor(y + 1)) % 2 == 0)
    shape = (k.height, n, k.width, n)
    return (np.where(dark, 0.0, 1.0).reshape(shape), on_plate.reshape(shape),
            np.where(hit, t, np.inf).reshape(shape))


def render_colour(board: ChessBoard, world_T_camera: np.ndarray, intrinsics: CameraIntrinsics, *,
                  supersample: int = 2) -> np.ndarray:
    """(H, W, 3) uint8 colour image of ``board`` seen from ``world_T_camera`` (optical frame): each
    ray intersected with the board's plane (the geoms' top faces), black on a dark square, white on
    the plate, the table's colour elsewhere; ``supersample``² rays per pixel, averaged."""
    bright, on_plate, _ = _board_rays(board, world_T_camera, intrinsics, supersample)
    grey = np.where(on_plate, bright, _TABLE_GREY).mean(axis=(1, 3))
    return np.repeat(np.rint(grey * 255.0).astype(np.uint8)[..., None], 3, axis=2)


def overlay_board(rgb: np.ndarray, depth_m: np.ndarray, board: ChessBoard, world_T_camera: np.ndarray,
                  intrinsics: CameraIntrinsics, *, supersample: int = 2, tolerance_m: float = 0.003) -> np.ndarray:
    """``rgb`` (H, W, 3) uint8, a frame of the scene without the board, with ``board`` painted where the
    camera sees it: a ray lands on the board's plate and nothing of the scene (``depth_m`` (H, W) [m], 0 where
    nothing was met) lies more than ``tolerance_m`` in front of it. Edges are averaged over ``supersample``²
    rays per pixel, as in :func:`render_colour`."""
    bright, on_plate, t = _board_rays(board, world_T_camera, intrinsics, supersample)
    scene = np.nan_to_num(np.asarray(depth_m, dtype=np.float32), nan=0.0, posinf=0.0)[:, None, :, None]
    seen = on_plate & ((scene <= 0.0) | (t <= scene + np.float32(tolerance_m)))
    if not seen.any():
        return rgb
    frac = seen.mean(axis=(1, 3))[..., None]  # (H, W, 1) share of a pixel's rays on the visible board
    board_grey = np.where(seen, bright, 0.0).sum(axis=(1, 3))[..., None] / (seen.shape[1] * seen.shape[3])
    out = (1.0 - frac) * rgb.astype(np.float64) + 255.0 * board_grey
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)
