"""Reference types the controllers track: small frozen dataclasses, validated on construction."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from tactex.errors import InputError
from tactex.perception.estimate import SurfaceEstimate

__all__ = ["LineForceReference", "PoseForceReference"]


def _finite(name: str, value: object, shape: tuple[int, ...]) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != shape or not np.isfinite(arr).all():
        raise InputError(f"{name} must be a finite array of shape {shape}, got {arr!r} (shape {arr.shape})")
    return arr


@dataclass(frozen=True, slots=True)
class LineForceReference:
    """TEC reference: the line orthogonal to the surface through the agent point, and a force.

    Attributes:
        point_world: (3,) agent point on the surface P'_a [m].
        normal_world: (3,) outward surface normal at the agent point (unit after construction).
            The target line L_a,⊥ (TEC eq. 28) runs through ``point_world`` along
            ``-normal_world``, i.e. along the tool z-axis when the tool presses on the surface.
        force_n: pressing force along the tool z-axis [N], ≥ 0.
        approach_speed_m_s: out of contact, the speed along the tool z-axis (towards the surface) the
            line's damping lets the tool move at instead of holding it still [m/s], ≥ 0 (a feed-forward
            D_z·v; 0: the force loop alone drives the approach).
    """

    point_world: np.ndarray
    normal_world: np.ndarray
    force_n: float = 10.0
    approach_speed_m_s: float = 0.0

    def __post_init__(self) -> None:
        p = _finite("LineForceReference.point_world", self.point_world, (3,))
        n = _finite("LineForceReference.normal_world", self.normal_world, (3,))
        norm = float(np.linalg.norm(n))
        if norm < 1e-9:
            raise InputError(f"LineForceReference.normal_world must be non-zero, got {n!r}")
        f = float(self.force_n)
        if not np.isfinite(f) or f < 0.0:
            raise InputError(f"LineForceReference.force_n must be a finite force ≥ 0 N, got {self.force_n!r}")
        v = float(self.approach_speed_m_s)
        if not np.isfinite(v) or v < 0.0:
            raise InputError(f"LineForceReference.approach_speed_m_s must be a finite speed ≥ 0 m/s, got "
                             f"{self.approach_speed_m_s!r}")
        object.__setattr__(self, "point_world", p)
        object.__setattr__(self, "normal_world", n / norm)
        object.__setattr__(self, "force_n", f)
        object.__setattr__(self, "approach_speed_m_s", v)


@dataclass(frozen=True, slots=True)
class PoseForceReference:
    """UFIC / VA-UFIC / Cartesian-impedance reference: a TCP pose, a wrench and a twist.

    Attributes:
        position_world: (3,) desired TCP position x_d [m].
        rotation_world: (3, 3) desired orientation world_R_tool. VA-UFIC reads it once, at its
            first tick after a reset (a resume keeps its R_d), and from then on moves its own R_d
            by vision-driven re-orientations (``VaUficController.rotation_desired``); UFIC and the
            Cartesian impedance follow it every tick.
        wrench_tool: (6,) desired contact wrench f_d^ee in the tool frame [N, N·m]
            (``[0, 0, 15, 0, 0, 0]`` presses 15 N along the tool axis).
        twist_world: (6,) desired TCP twist [m/s, rad/s] (feed-forward for the damping term).
        surface: latest vision estimate (VA-UFIC only; None when there is none).
    """

    position_world: np.ndarray
    rotation_world: np.ndarray
    wrench_tool: np.ndarray = field(default_factory=lambda: np.zeros(6))
    twist_world: np.ndarray = field(default_factory=lambda: np.zeros(6))
    surface: SurfaceEstimate | None = None

    def __post_init__(self) -> None:
        if self._fast_valid():
            return
        pos = _finite("PoseForceReference.position_world", self.position_world, (3,))
        object.__setattr__(self, "position_world", pos)
        rot = _finite("PoseForceReference.rotation_world", self.rotation_world, (3, 3))
        if np.abs(rot @ rot.T - np.eye(3)).max() > 1e-6 or np.linalg.det(rot) < 0.0:
            raise InputError(f"PoseForceReference.rotation_world must be a rotation matrix, got {rot!r}")
        object.__setattr__(self, "rotation_world", rot)
        object.__setattr__(self, "wrench_tool", _finite("PoseForceReference.wrench_tool", self.wrench_tool, (6,)))
        object.__setattr__(self, "twist_world", _finite("PoseForceReference.twist_world", self.twist_world, (6,)))

    def _fast_valid(self) -> bool:
        """The common case, built once per tick at 1 kHz: float arrays of the right shapes, finite, a
        proper rotation. Checked with a handful of scalar operations; anything else goes through
        the full checks, which name the bad field."""
        pos, rot, wrench, twist = self.position_world, self.rotation_world, self.wrench_tool, self.twist_world
        if not (type(pos) is np.ndarray and type(rot) is np.ndarray and type(wrench) is np.ndarray
                and type(twist) is np.ndarray and pos.shape == (3,) and rot.shape == (3, 3)
                and wrench.shape == (6,) and twist.shape == (6,) and pos.dtype == rot.dtype == wrench.dtype
                == twist.dtype == np.float64):
            return False
        total = float(pos.sum()) + float(rot.sum()) + float(wrench.sum()) + float(twist.sum())
        if not math.isfinite(total):
            return False
        (a, b, c), (d, e, f), (g, h, i) = rot.tolist()
        det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
        gram = (a * a + b * b + c * c - 1.0, d * d + e * e + f * f - 1.0, g * g + h * h + i * i - 1.0,
                a * d + b * e + c * f, a * g + b * h + c * i, d * g + e * h + f * i)
        return det > 0.0 and max(abs(x) for x in gram) <= 1e-6
