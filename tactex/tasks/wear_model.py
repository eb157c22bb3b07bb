"""The robot's own estimate of the dirt it has removed, from what it feels.

Between two camera views the cleaning program knows where the pad was, how hard it pressed and how
fast it slid: Preston's law (dh/dt = k_p · p · v, with p = F_n / (π r²) on the pad disc) turns that
into a predicted removal at each point of the captured cloud. The target the explorer follows is the
captured dirt times what the prediction says is left, so a point that is predicted clean stops
attracting the agent (the dirt is removed, not "covered ergodically"), and the program goes back to
the camera when the prediction says the job is done rather than after a fixed number of steps.
Vision stays the judge: each re-measurement replaces the prediction.

Only the robot's measurements are read (TCP position and twist, the F/T normal force), never the
simulator's dirt, so the same model runs on a real Franka.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from tactex.errors import ConfigError, InputError
from tactex.pointcloud.cloud import SurfaceCloud

__all__ = ["WearModel"]


class WearModel:
    """Predicted Preston removal on the points of a cloud.

    Args:
        cloud: the captured cloud (world frame) whose target is the dirt [m].
        preston_coefficient: k_p [1/(Pa·m)]: dirt level removed per pascal per metre slid.
        pad_radius_m: radius of the pad's pressure disc [m].
        force_threshold_n: normal force below which the pad removes nothing [N].
        margin: removal a point needs before it counts as clean (1 = exactly the model's; > 1 keeps
            attracting the agent until the model is this many times sure) [-].
    """

    def __init__(self, cloud: SurfaceCloud, preston_coefficient: float, pad_radius_m: float,
                 force_threshold_n: float = 0.0, margin: float = 1.0) -> None:
        checks = (("preston_coefficient", preston_coefficient, True), ("pad_radius_m", pad_radius_m, True),
                  ("force_threshold_n", force_threshold_n, False), ("margin", margin, True))
        for name, v, strict in checks:
            if not (np.isfinite(v) and (v > 0 if strict else v >= 0)):
                raise ConfigError(f"{name} must be {'> 0' if strict else '≥ 0'}, got {v!r}")
        self.cloud = cloud
        self.k_p = float(preston_coefficient)
        self.radius = float(pad_radius_m)
        self.threshold = float(force_threshold_n)
        self.margin = float(margin)
        self._tree = cKDTree(cloud.points)
        self._scale = self.k_p / (np.pi * self.radius**2)  # removal per N·m of ∫F·v dt
        self.removed = np.zeros(len(cloud))  # predicted removal per point [dirt level]
        self._target = np.asarray(cloud.target, dtype=float).copy()

    @property
    def tree(self) -> cKDTree:
        """KD-tree of the cloud's points (shared with whoever plans paths on the same cloud)."""
        return self._tree

    def reset(self, target: np.ndarray) -> None:
        """A new view of the dirt (target mass (N,) on the cloud's points): the prediction restarts."""
        t = np.asarray(target, dtype=float)
        if t.shape != (len(self.cloud),):
            raise InputError(f"target must have shape ({len(self.cloud)},), got {t.shape}")
        self._target = t.copy()
        self.removed[:] = 0.0

    def wipe(self, pad_centre_m: np.ndarray, force_slip_integral: float) -> None:
        """Add the removal of ∫F_n·v dt [N·m] (over ticks above the force threshold) under a pad
        centred at ``pad_centre_m`` (3,) [m, world]."""
        if not force_slip_integral > 0.0:
            return
        idx = self._tree.query_ball_point(np.asarray(pad_centre_m, dtype=float), self.radius)
        if idx:
            self.removed[idx] += self._scale * force_slip_integral

    def dirty(self) -> np.ndarray:
        """Points (N,) of the view's dirt the model has not yet seen wiped off once (predicted removal < 1,
        the margin left aside: an island is done when every point has had its pass; the margin only decides
        when a point stops attracting the agent)."""
        return (self._target > 0) & (self.removed < 1.0)

    def dirty_fraction(self, reference_total: float) -> float:
        """The view's dirt on the :meth:`dirty` points as a fraction of ``reference_total``."""
        return float(self._target[self.dirty()].sum()) / reference_total if reference_total > 0 else 0.0

    def dirt_near(self, here_m: np.ndarray, radius_m: float) -> float:
        """The view's dirt mass on the :meth:`dirty` points within ``radius_m`` of ``here_m`` (3,) [m]."""
        near = np.linalg.norm(self.cloud.points - np.asarray(here_m, dtype=float), axis=1) <= radius_m
        return float(self._target[near & self.dirty()].sum())

    def island_left(self, here_m: np.ndarray, radius_m: float) -> bool:
        """Whether dirt (:meth:`dirty`) is left within ``radius_m`` of ``here_m`` (3,) [m]."""
        return self.dirt_near(here_m, radius_m) > 0.0

    def next_island(self, here_m: np.ndarray, tried_m: list[np.ndarray], clearance_m: float,
                    allowed: np.ndarray | None = None) -> np.ndarray | None:
        """Where to touch down next (3,) [m]: the dirty point (:meth:`dirty`) nearest to ``here_m``, farther
        than ``clearance_m`` from it and from every earlier touch-down in ``tried_m`` (dirt the agent stalled on
        after touching down next to it is left to the camera), among the cloud points ``allowed`` (N,) (bool; e.g.
        those a footprint centred there keeps clear of a keep-out zone; None: all). None when there is no such
        point."""
        pts = self.cloud.points
        dirty = self.dirty()
        if allowed is not None:
            allowed = np.asarray(allowed, dtype=bool)
            if allowed.shape != dirty.shape:
                raise InputError(f"allowed must have shape ({len(dirty)},), got {allowed.shape}")
            dirty &= allowed
        for p in [here_m, *tried_m]:
            dirty &= np.linalg.norm(pts - np.asarray(p, dtype=float), axis=1) > clearance_m
        idx = np.flatnonzero(dirty)
        if idx.size == 0:
            return None
        return pts[idx[np.argmin(np.linalg.norm(pts[idx] - np.asarray(here_m, dtype=float), axis=1))]].copy()

    def remaining(self) -> np.ndarray:
        """Predicted dirt mass (N,): the view's target times the share the prediction leaves."""
        return self._target * np.clip(1.0 - self.removed / self.margin, 0.0, 1.0)

    def remaining_fraction(self, reference_total: float) -> float:
        """Predicted dirt left as a fraction of ``reference_total`` (e.g. the first capture's mass)."""
        return float(self.remaining().sum()) / reference_total if reference_total > 0 else 0.0
