"""Hand-eye calibration: where the wrist camera sits on the tool (``tool_T_camera``), from views of
a chessboard lying still while the arm moves (AX = XB, solved by OpenCV's ``calibrateHandEye``).

At each pose the robot reports ``base_T_tool`` (A's) and the camera sees the board: its inner
corners are found (``findChessboardCorners``, refined to sub-pixel), put in order (the board's
colours tell its two possible orders apart, :mod:`tactex.sim.board`), and the board's pose in the
camera follows by PnP (B's). The solution X is checked pose by pose: with it, every view places the
board at one pose in the base frame, and each view's distance from their mean is its residual.

Motions that rotate the tool about one axis only leave X's translation along that axis unknown (a
degenerate set, refused with what to do), so the generated poses tilt the camera around the board
in two directions and roll it about its axis. In simulation (:func:`calibrate_in_simulation`) the
arm of tactex's scene visits them, a board of geoms lies on the table, and the recovered mount is
compared with the scene's own.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from tactex.config import param
from tactex.errors import ConfigError, InputError, MissingDependencyError, SimulationError
from tactex.perception.frame import CameraIntrinsics
from tactex.perception.mount import mount_offset
from tactex.sim.board import ChessBoard, board_model, render_colour

__all__ = [
    "METHODS",
    "MIN_POSES",
    "HandEyeConfig",
    "HandEyeResult",
    "PoseResidual",
    "board_pose",
    "calibrate_in_simulation",
    "check_motions",
    "detect_board",
    "generated_tool_poses",
    "solve_hand_eye",
    "solve_views",
    "write_hand_eye",
]

#: OpenCV's hand-eye methods by name.
METHODS = ("tsai", "park", "horaud", "andreff", "daniilidis")
#: Views with the board found that AX = XB needs at the least (two motions about different axes).
MIN_POSES = 3
#: Relative rotations below this are no motion for the degeneracy check [deg].
MIN_MOTION_DEG = 2.0


def _cv2() -> Any:
    try:
        import cv2
    except ImportError as exc:
        raise MissingDependencyError("opencv-python-headless", "realsense",
                                     "Hand-eye calibration (board detection, calibrateHandEye)") from exc
    return cv2


@dataclass(frozen=True)
class HandEyeConfig:
    """The calibration's poses and solver (units in brackets)."""

    poses: int = param(12, "poses the arm visits around the board [-]")
    method: str = param("tsai", f"OpenCV's hand-eye method: {', '.join(METHODS)}")
    distance_m: float = param(0.35, "camera distance from the board's centre [m]")
    max_tilt_deg: float = param(25.0, "largest tilt of the view off the board's normal [deg]")
    max_roll_deg: float = param(30.0, "largest roll of the camera about its axis [deg]")
    seed: int = param(0, "seed of the generated poses [-]")

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ConfigError(f"unknown hand-eye method '{self.method}'; valid: {', '.join(METHODS)}")
        if isinstance(self.poses, bool) or not isinstance(self.poses, (int, np.integer)) or self.poses < MIN_POSES:
            raise ConfigError(f"hand-eye calibration needs at least {MIN_POSES} poses, got {self.poses!r}: give "
                              "--poses 10 or more (15 is plenty)")
        if self.poses > 100:
            raise ConfigError(f"poses must be at most 100, got {self.poses}")
        if not (np.isfinite(self.distance_m) and 0.15 <= self.distance_m <= 1.0):
            raise ConfigError(f"distance_m must be in [0.15, 1] m, got {self.distance_m!r}")
        for name, hi in (("max_tilt_deg", 60.0), ("max_roll_deg", 90.0)):
            v = getattr(self, name)
            if not (np.isfinite(v) and 5.0 <= v <= hi):
                raise ConfigError(f"{name} must be in [5, {hi:g}] deg, got {v!r}")


class PoseResidual(NamedTuple):
    """How far one view's board pose (with the solved X) lies from the views' mean."""

    index: int
    position_mm: float
    rotation_deg: float


@dataclass
class HandEyeResult:
    """A solved calibration: ``tool_T_camera`` (4, 4) [m], the residual of each view used, the
    indices of the poses skipped (and why), and in simulation the scene's own mount."""

    tool_T_camera: np.ndarray
    residuals: list[PoseResidual]
    method: str
    skipped: dict[int, str] = field(default_factory=dict)
    truth: np.ndarray | None = None

    def error(self) -> tuple[float, float]:
        """Distance [mm] and angle [deg] of the solution from ``truth``."""
        if self.truth is None:
            raise InputError("this calibration has no known mount to compare with")
        d = np.linalg.inv(self.truth) @ self.tool_T_camera
        return float(np.linalg.norm(self.tool_T_camera[:3, 3] - self.truth[:3, 3]) * 1e3), _angle_deg(d[:3, :3])


def _angle_deg(rot: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(rot) - 1.0) / 2.0, -1.0, 1.0))))


def _rotvec(rot: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(rot).as_rotvec()


def detect_board(rgb: np.ndarray, board: ChessBoard) -> np.ndarray | None:
    """The board's inner corners (cols·rows, 2) [px] in the colour image, in the board's own order
    (first corner beside a dark outer square), or None when the board is not found."""
    cv2 = _cv2()
    gray = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)
    found, corners = cv2.findChessboardCorners(gray, (board.cols, board.rows),
                                               flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found:
        return None
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
    corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), criteria).reshape(-1, 2)
    # the outer square diagonally beyond corner 0: dark in the board's order, light when found reversed
    c0, along, down = corners[0], corners[1] - corners[0], corners[board.cols] - corners[0]
    u, v = np.rint(c0 - 0.5 * along - 0.5 * down).astype(int)
    if not (0 <= v < gray.shape[0] and 0 <= u < gray.shape[1]):
        return None
    if gray[v, u] > 0.5 * (float(gray.max()) + float(gray.min())):
        corners = corners[::-1].copy()
    return corners


def board_pose(corners: np.ndarray, board: ChessBoard, intrinsics: CameraIntrinsics) -> np.ndarray:
    """camera_T_board (4, 4) [m] from the ordered corners (PnP, no lens distortion)."""
    cv2 = _cv2()
    ok, rvec, tvec = cv2.solvePnP(board.object_points(), corners.astype(np.float64), intrinsics.K, None,
                                  flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        raise InputError("the board's pose could not be solved from its corners")
    out = np.eye(4)
    out[:3, :3] = cv2.Rodrigues(rvec)[0]
    out[:3, 3] = tvec.ravel()
    return out


def check_motions(base_T_tools: Sequence[np.ndarray]) -> None:
    """Refuse a set of tool poses whose motions do not determine X: fewer than :data:`MIN_POSES`, no
    rotation between them, or every rotation about one axis."""
    if len(base_T_tools) < MIN_POSES:
        raise InputError(f"hand-eye calibration needs the board seen from at least {MIN_POSES} poses, got "
                         f"{len(base_T_tools)}: add poses (--poses 10 or more)")
    axes = []
    for i in range(len(base_T_tools)):
        for j in range(i + 1, len(base_T_tools)):
            rv = _rotvec(base_T_tools[i][:3, :3].T @ base_T_tools[j][:3, :3])
            if np.degrees(np.linalg.norm(rv)) > MIN_MOTION_DEG:
                axes.append(rv / np.linalg.norm(rv))
    if not axes:
        raise InputError(f"the poses barely rotate the tool (no two differ by {MIN_MOTION_DEG:g}°): tilt the tool "
                         "by 10–30° between poses, about at least two different axes")
    a = np.asarray(axes)
    spread = np.linalg.eigvalsh(a.T @ a / len(a))  # ascending; one axis: a single non-zero eigenvalue
    if spread[1] < 0.02:
        axis = np.linalg.eigh(a.T @ a)[1][:, -1]
        raise InputError(f"the poses rotate the tool about one axis only (≈ {np.round(axis, 2).tolist()} in the tool "
                         "frame), which leaves the camera's offset along it unknown: tilt the tool about at least "
                         "two different axes between poses")


def solve_hand_eye(base_T_tools: Sequence[np.ndarray], camera_T_boards: Sequence[np.ndarray],
                   method: str = "tsai") -> tuple[np.ndarray, list[PoseResidual]]:
    """tool_T_camera (4, 4) [m] solving AX = XB by OpenCV's ``method``, and each view's residual."""
    cv2 = _cv2()
    if method not in METHODS:
        raise ConfigError(f"unknown hand-eye method '{method}'; valid: {', '.join(METHODS)}")
    if len(base_T_tools) != len(camera_T_boards):
        raise InputError(f"{len(base_T_tools)} tool poses but {len(camera_T_boards)} board poses")
    check_motions(base_T_tools)
    flag = getattr(cv2, f"CALIB_HAND_EYE_{method.upper()}")
    rot, trans = cv2.calibrateHandEye(
        [t[:3, :3] for t in base_T_tools], [t[:3, 3] for t in base_T_tools],
        [b[:3, :3] for b in camera_T_boards], [b[:3, 3] for b in camera_T_boards], method=flag)
    x = np.eye(4)
    x[:3, :3], x[:3, 3] = rot, np.asarray(trans).ravel()
    if not np.isfinite(x).all():
        raise InputError(f"OpenCV's {method} method returned no solution: add poses with larger rotations")
    boards = [t @ x @ b for t, b in zip(base_T_tools, camera_T_boards, strict=True)]
    mean_t = np.mean([b[:3, 3] for b in boards], axis=0)
    u, _, vt = np.linalg.svd(sum(b[:3, :3] for b in boards))
    mean_r = u @ vt
    residuals = [PoseResidual(i, float(np.linalg.norm(b[:3, 3] - mean_t) * 1e3), _angle_deg(mean_r.T @ b[:3, :3]))
                 for i, b in enumerate(boards)]
    return x, residuals


def write_hand_eye(path: str | Path, tool_T_camera: np.ndarray) -> Path:
    """Write ``tool_T_camera`` as ``--hand-eye`` reads it (.json nested list, or .npy), then read it back."""
    from tactex.tasks.hand_eye import load_hand_eye

    out = Path(path)
    if out.suffix not in (".json", ".npy"):
        raise InputError(f"the hand-eye file is .json or .npy (what --hand-eye reads), got '{out}'")
    out.parent.mkdir(parents=True, exist_ok=True)
    if out.suffix == ".json":
        out.write_text(json.dumps(np.asarray(tool_T_camera, dtype=float).tolist(), indent=1) + "\n")
    else:
        np.save(out, np.asarray(tool_T_camera, dtype=float), allow_pickle=False)
    load_hand_eye(out)
    return out


# -- simulation ------------------------------------------------------------------------------------
def _rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def generated_tool_poses(board: ChessBoard, cfg: HandEyeConfig, tool_T_camera: np.ndarray) -> list[np.ndarray]:
    """base_T_tool targets that put the camera (its nominal mount) ``distance_m`` from the board's
    centre, tilted up to ``max_tilt_deg`` in all directions and rolled up to ``max_roll_deg``."""
    from tactex.tasks.runner import tool_rotation_for_normal

    rng = np.random.default_rng(cfg.seed)
    centre = np.asarray(board.centre_m, dtype=float)
    out = []
    for k in range(cfg.poses):
        tilt = np.radians(cfg.max_tilt_deg * (0.35 + 0.65 * rng.random()))
        azimuth = 2.0 * np.pi * (k / cfg.poses) + rng.uniform(-0.3, 0.3)
        look = np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), np.cos(tilt)])
        rot = tool_rotation_for_normal(look) @ _rot_z(cfg.max_roll_deg * (2.0 * rng.random() - 1.0))
        pose = np.eye(4)
        pose[:3, :3] = rot
        pose[:3, 3] = centre + cfg.distance_m * look - rot @ tool_T_camera[:3, 3]
        out.append(pose)
    return out


def calibrate_in_simulation(
    config: HandEyeConfig | None = None,
    board: ChessBoard | None = None,
    scene_config=None,
    *,
    mount_tilt_deg: Sequence[float] = (0.0, 0.0, 0.0),
    mount_shift_m: Sequence[float] = (0.0, 0.0, 0.0),
    tool_poses: Sequence[np.ndarray] | None = None,
    scene_board: ChessBoard | None = None,
    note=None,
) -> HandEyeResult:
    """Calibrate the wrist camera of tactex's simulated scene: a board of geoms on the table, the arm
    at generated poses around it (or at ``tool_poses``, base_T_tool targets), the colour images ray cast.

    ``mount_tilt_deg`` (x, y, z Euler angles [deg]) and ``mount_shift_m`` [m] move the scene's camera
    off its nominal mount (in its optical frame): the poses are still planned with the nominal one,
    as a user plans them, and the result is compared with the moved mount (``truth``). ``scene_board``
    is the board lying in the scene when it is not the one searched for (``board``)."""
    import mujoco

    from tactex.sim.camera import optical_R_mujoco_camera
    from tactex.sim.franka import FRANKA_HOME_Q
    from tactex.sim.ik import solve_site_ik
    from tactex.sim.scene import SceneConfig, build_scene

    cfg = config or HandEyeConfig()
    board = board or ChessBoard()
    seen = scene_board or board
    say = note or (lambda msg: None)
    scene_cfg = scene_config or SceneConfig(object_position=(0.45, -0.5, 0.0), camera_width=640, camera_height=480)
    scene = build_scene(scene_cfg)
    model = board_model(scene.xml, seen)
    data = mujoco.MjData(model)
    cam, tcp = scene.ids["camera"], scene.ids["tcp"]

    def poses() -> tuple[np.ndarray, np.ndarray]:
        tool = np.eye(4)
        tool[:3, :3], tool[:3, 3] = data.site_xmat[tcp].reshape(3, 3), data.site_xpos[tcp]
        camera = np.eye(4)
        camera[:3, :3] = data.cam_xmat[cam].reshape(3, 3) @ optical_R_mujoco_camera
        camera[:3, 3] = data.cam_xpos[cam]
        return tool, camera

    data.qpos[:7] = FRANKA_HOME_Q
    mujoco.mj_forward(model, data)
    tool, camera = poses()
    nominal = np.linalg.inv(tool) @ camera
    # the camera moved on its mount, in its optical frame: body_T_cam' = body_T_cam · optical error
    moved = nominal @ mount_offset(mount_tilt_deg, mount_shift_m)
    body_T_tool = np.linalg.inv(_body_pose(data, model.cam_bodyid[cam])) @ tool
    body_T_cam = body_T_tool @ moved
    model.cam_pos[cam] = body_T_cam[:3, 3]
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, (body_T_cam[:3, :3] @ optical_R_mujoco_camera.T).reshape(9))
    model.cam_quat[cam] = quat
    mujoco.mj_forward(model, data)
    tool, camera = poses()
    truth = np.linalg.inv(tool) @ camera
    targets = list(tool_poses) if tool_poses is not None else generated_tool_poses(board, cfg, nominal)
    intr = scene_cfg.intrinsics
    tools, boards, skipped = [], [], {}
    qadr = dadr = np.arange(7)
    for i, target in enumerate(targets):
        try:
            q = solve_site_ik(model, tcp, qadr, dadr, target[:3, 3], target[:3, :3], FRANKA_HOME_Q, FRANKA_HOME_Q)
        except SimulationError:
            skipped[i] = "out of the arm's reach"
            continue
        data.qpos[:7] = q
        mujoco.mj_forward(model, data)
        tool, camera = poses()
        corners = detect_board(render_colour(seen, camera, intr), board)
        if corners is None:
            skipped[i] = "board not found"
            continue
        tools.append(tool)
        boards.append(board_pose(corners, board, intr))
    return solve_views(tools, boards, len(targets), skipped, board, cfg.method, say, truth=truth)


def solve_views(tools: Sequence[np.ndarray], boards: Sequence[np.ndarray], n_targets: int, skipped: dict[int, str],
                board: ChessBoard, method: str, say, *, where: str = "", truth: np.ndarray | None = None
                ) -> HandEyeResult:
    """The calibration from the views taken (``tools``: base_T_tool, ``boards``: camera_T_board) of ``n_targets``
    poses, ``skipped`` those without one (index → why); says how many found the board, and refuses too few with
    what to check (``where``: how the user told where the board lies, e.g. an option)."""
    say(f"{len(tools)} of {n_targets} poses with the board found"
        + (f" (skipped: {', '.join(f'{i + 1} {why}' for i, why in skipped.items())})" if skipped else ""))
    if len(tools) < MIN_POSES:
        raise InputError(
            f"the board was found from {len(tools)} of {n_targets} poses (needs {MIN_POSES}): check that its inner "
            f"corners are --board {board.cols} {board.rows}, that it lies{where} in the camera's view at the poses "
            "(--distance-m, --max-tilt-deg) and is evenly lit")
    x, residuals = solve_hand_eye(tools, boards, method)
    used = [i for i in range(n_targets) if i not in skipped]
    residuals = [r._replace(index=used[r.index]) for r in residuals]
    return HandEyeResult(x, residuals, method, skipped, truth=truth)


def _body_pose(data, body: int) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = data.xmat[body].reshape(3, 3), data.xpos[body]
    return out
