"""Where the arm cannot go on: a touch-down whose hover is out of reach, and a tool that can no longer follow the
agent in contact, because a joint reached its limit's margin (the safety layer's repulsion, not the controller, then
moves the arm) or the wall it is dragged against holds it a pad radius behind the agent. Pressing on there scrapes
the pad sideways at twice the set point and more: the program lifts off and touches down again from a posture
planned afresh, or moves on."""

from __future__ import annotations

import warnings

import numpy as np

from tactex.ergodic.command import ExplorationCommand
from tactex.robots.loop import ControlLoop
from tactex.tasks.clean.motion import _lag_m
from tactex.tasks.wear_model import WearModel

__all__ = ["LEFT_BEHIND_FORCE_RATIO", "LEFT_BEHIND_PAD_RADII", "cannot_follow", "past_hover", "regrip_at"]

#: The tool counts as held back when it is this many pad radii from the agent's point along the surface [-] ...
LEFT_BEHIND_PAD_RADII = 0.5
#: ... while it presses with more than this multiple of the set point [-]. A tool that keeps up lags by a few
#: millimetres, and one climbing a bowl's wall lags further at up to 1.7 times the set point while the agent waits
#: for it (CleanConfig.hold_force_ratio); one held back by the wall of a bowl near the arm's reach drifted 3 cm from
#: its agent while the force rose through 1.5 to 2 times the set point in a quarter of a second.
LEFT_BEHIND_FORCE_RATIO = 1.8


def cannot_follow(loop: ControlLoop, cmd: ExplorationCommand, pad_radius_m: float, set_point_n: float) -> str | None:
    """Why the tool cannot follow the agent at ``cmd`` any more, after the tick just run, or None when it can."""
    if loop.safety.repelling:
        return "a joint reached its limit's margin"
    s = loop.state
    f = s.wrench_tool
    if (float(np.sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2])) > LEFT_BEHIND_FORCE_RATIO * set_point_n
            and _lag_m(s.ee_position, cmd) > LEFT_BEHIND_PAD_RADII * pad_radius_m):
        return "a wall held the tool back half a pad radius behind the agent"
    return None


def regrip_at(point_m: np.ndarray, regrips: list[np.ndarray], wear: WearModel, islands_tried: list[np.ndarray],
              pad_radius_m: float, touch_down_ok: np.ndarray | None) -> np.ndarray | None:
    """Where the tool touches down after it could not follow the agent at ``point_m`` (3,) [m]: the same point the
    first time near there (within two pad radii of the earlier ``regrips`` since the last view, to which it is
    added): the hover's posture is planned afresh on the capture posture's branch, free of the drift in contact that
    took the arm where it could not go on. A second time near there: the nearest other island the wear model calls
    dirty (this point joins ``islands_tried``), or None when there is none (the camera judges what is left)."""
    point_m = np.asarray(point_m, dtype=float)
    again = any(float(np.linalg.norm(point_m - p)) < 2.0 * pad_radius_m for p in regrips)
    regrips.append(point_m.copy())
    if not again:
        return point_m.copy()
    islands_tried.append(point_m.copy())
    return wear.next_island(point_m, islands_tried, 2.0 * pad_radius_m, touch_down_ok)


def past_hover(point_m: np.ndarray, wear: WearModel, islands_tried: list[np.ndarray], pad_radius_m: float,
               touch_down_ok: np.ndarray | None) -> np.ndarray | None:
    """After a touch-down at ``point_m`` (3,) [m] whose hover is out of reach (the far side of the cup): the nearest
    other island the wear model calls dirty (this point joins ``islands_tried``), or None when there is none (the
    program ends). Either is said in a warning."""
    islands_tried.append(np.asarray(point_m, dtype=float).copy())
    island = wear.next_island(point_m, islands_tried, 2.0 * pad_radius_m, touch_down_ok)
    out = np.round(point_m, 3).tolist()
    if island is None:
        warnings.warn(f"clean: no hover pose over {out} m within reach and no other dirt left to the wear model; "
                      "ending the program", RuntimeWarning, stacklevel=3)
    else:
        warnings.warn(f"clean: no hover pose over {out} m within reach; moving on to the dirt at "
                      f"{np.round(island, 3).tolist()} m", RuntimeWarning, stacklevel=3)
    return island
