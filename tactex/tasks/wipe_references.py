"""The wipe's references, one per control tick: the force-motion policy in the tool's tangent plane, on the
camera's surface estimate or on the surface an earlier pass explored (VA-UFIC §III and §V), with what that pass's
errors call for (:mod:`tactex.tasks.pass_learning`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

from tactex.control.references import PoseForceReference
from tactex.control.safety import MAX_FORCE_SET_POINT_N
from tactex.perception.estimate import SurfaceEstimate
from tactex.tasks.explored_surface import ExploredSurface
from tactex.tasks.pass_learning import PassCorrection
from tactex.tasks.policies import ForceMotionPolicy
from tactex.tasks.robot import SurfaceVision

#: A learned correction fades in over this long from where the pass aligned [s].
LEARN_FADE_IN_S = 0.5

__all__ = ["REPLAN_DEPTH_M", "REPLAN_GAP_M", "REPLAN_READ_EVERY_S", "WipeReferences"]

#: A re-plan puts the reference on the explored surface only this close to a contact point of the first pass
#: [m]: farther, the first pass never touched there. Its tracking error reaches a centimetre or two while
#: VA-UFIC is still compliant, and the local plane there is off a 10 cm sphere by d²/2R = 2 mm at 2 cm.
REPLAN_GAP_M = 0.02
#: ... and that far into it along the normal [m].
REPLAN_DEPTH_M = 0.01
#: How often a re-plan reads the explored surface [s]. A read (two KD-tree queries and a weighted plane fit)
#: costs a sizeable part of a 1 kHz tick; between reads the desired position is projected on the plane last
#: read, which the tool leaves by a fraction of a millimetre in that time.
REPLAN_READ_EVERY_S = 0.01


class WipeSettings(Protocol):
    """What the references read of the wipe's configuration (:class:`~tactex.tasks.wipe.WipeConfig`)."""

    baseline: str
    contact_threshold_n: float
    replan_lead_s: float
    policy_waits_for_alignment: bool
    align_wait_max_s: float


class WipeReferences:
    """The VA-UFIC §III policy as the controller's references, one per tick.

    :meth:`advance` makes :attr:`reference` the one for the tick that answers the next state, from
    the state just answered: on a real robot it runs while that command executes (``ControlLoop.tick``'s
    ``after_send``), so only the controller stands between a state and its command. The policy lives
    in the tool frame; its increments are applied in the tool frame of the state it is given (one
    tick, about a milliradian, before the state the torque answers).
    """

    def __init__(self, cfg: WipeSettings, vision: SurfaceVision, p_start: np.ndarray, r_start: np.ndarray,
                 policy: ForceMotionPolicy, explored: ExploredSurface | None = None,
                 offset: Callable[[], np.ndarray] | None = None, learned: PassCorrection | None = None,
                 aligned: Callable[[], bool] | None = None) -> None:
        self.cfg, self.vision, self.r_start, self.policy = cfg, vision, r_start, policy
        # with a re-plan: what the first pass's errors call for at each policy time (the policy's own set point
        # and path stay what the run is measured against)
        self.learned = learned
        # whether the controller has aligned (ρ_align = 1): the in-plane correction, learned where the first pass
        # was aligned, is applied from where this one is, faded in over LEARN_FADE_IN_S (None: from the start); the
        # force correction over the whole pass
        self.aligned, self.learn_from_s = aligned, (None if aligned is not None else -LEARN_FADE_IN_S)
        # with cfg.policy_waits_for_alignment: the policy held at its start until the controller aligns
        self.waiting = cfg.policy_waits_for_alignment and aligned is not None
        self.waited_s = 0.0  # [s] how long the policy has waited so far
        self.pos_ref = p_start.copy()
        self.estimate: SurfaceEstimate | None = None  # the camera's newest
        # with a re-plan: the explored surface, and how many references it placed
        self.explored, self.on_explored, self.advances = explored, 0, 0
        # the plane last read from it: (time [s], point [m], unit normal, the controller's surface) or, off
        # the explored surface, (time, None, None, None)
        self._plane: tuple | None = None
        # the controller's position offset [m] (VA-UFIC's, fed back while compliant): the desired position is
        # the reference plus it
        self.offset = offset
        self.estimates_total = self.estimates_valid = 0
        self.reference: PoseForceReference | None = None
        first = policy.at(0.0)
        self._x_prev = (first.u_m, first.v_m)
        self.force_set_n, self.segment, self.uv = first.force_n, 0, (first.u_m, first.v_m)
        # a constant set point keeps one wrench array for the whole run
        self._const = policy.constant_force_n if learned is None else None
        self.wrench_d = np.array([0.0, 0.0, first.force_n if self._const is None else self._const, 0.0, 0.0, 0.0])

    def advance(self, state, tau_t: float) -> None:
        """:attr:`reference` at run time ``tau_t`` [s] (the policy's own time is that less :attr:`waited_s`, the
        time it waited for the alignment), with the newest surface estimate and ``state``'s tool frame."""
        cfg = self.cfg
        if self.waiting:  # the policy's start, at its first set point, until the alignment (or the longest wait)
            self.waited_s = tau_t
            self.waiting = not (self.aligned() or tau_t >= cfg.align_wait_max_s)
        tau_t = max(tau_t - self.waited_s, 0.0)  # the policy's own time
        new_estimate = self.vision.update(state)
        if new_estimate is not None:
            self.estimate = new_estimate
            self.estimates_total += 1
            self.estimates_valid += int(new_estimate.valid)
        # the policy's increment and rate (tool frame, z = 0), applied in the tool frame of ``state``
        x0, x1, v0, v1, force = self.policy.at(tau_t)
        if self._const is None:
            self.wrench_d = np.array((0.0, 0.0, force, 0.0, 0.0, 0.0))
        self.force_set_n, self.segment, self.uv = force, self.policy.segment_index(tau_t), (x0, x1)
        p0, p1 = self._x_prev
        d0, d1 = x0 - p0, x1 - p1
        self._x_prev = (x0, x1)
        rot = state.ee_rotation
        (r00, r01, _), (r10, r11, _), (r20, r21, _) = rot.tolist()
        px, py, pz = self.pos_ref.tolist()
        self.pos_ref = np.array((px + r00 * d0 + r01 * d1, py + r10 * d0 + r11 * d1, pz + r20 * d0 + r21 * d1))
        twist_d = np.array((r00 * v0 + r01 * v1, r10 * v0 + r11 * v1, r20 * v0 + r21 * v1, 0.0, 0.0, 0.0))
        rot_ref = self.r_start if cfg.baseline == "cartesian" else rot
        surface = self.estimate
        self.advances += 1
        if self.explored is not None:
            surface = self._on_explored(state.t, twist_d)
        position = self.pos_ref
        if self.learned is not None:
            if self.learn_from_s is None and self.aligned():
                self.learn_from_s = tau_t
            share = 0.0 if self.learn_from_s is None else min(1.0, (tau_t - self.learn_from_s) / LEARN_FADE_IN_S)
            df, du, dv, vu, vv = self.learned.at(tau_t)  # the force's over the whole pass (PassCorrection)
            du, dv, vu, vv = share * du, share * dv, share * vu, share * vv
            self.wrench_d = np.array((0.0, 0.0, min(max(force + df, cfg.contact_threshold_n), MAX_FORCE_SET_POINT_N),
                                      0.0, 0.0, 0.0))
            position = self.pos_ref + np.array((r00 * du + r01 * dv, r10 * du + r11 * dv, r20 * du + r21 * dv))
            twist_d[:3] += (r00 * vu + r01 * vv, r10 * vu + r11 * vv, r20 * vu + r21 * vv)
        self.reference = PoseForceReference(position, rot_ref, self.wrench_d, twist_d, surface)

    def _on_explored(self, t: float, twist_d: np.ndarray) -> SurfaceEstimate | None:
        """Where the first pass touched: the reference moved along the explored surface's normal so that the
        desired position (reference plus the controller's offset) lies on it, and the normal the desired position
        reaches ``replan_lead_s`` ahead as the controller's surface (the camera's curvature where the first pass
        had none). Elsewhere the camera's estimate, and the reference where the tangent plane put it."""
        assert self.explored is not None
        desired = self.pos_ref + (self.offset() if self.offset is not None else 0.0)
        if self._plane is None or t - self._plane[0] >= REPLAN_READ_EVERY_S - 1e-9:
            self._plane = self._read_plane(t, desired, twist_d)
        _, point, normal, surface = self._plane
        if point is None:
            return self.estimate
        self.on_explored += 1
        # into the surface by REPLAN_DEPTH_M: VA-UFIC fades the force once the tool is past the desired
        # position along its axis (eq. 30), which a tool pressing a little deeper than the first pass would be
        depth = float((desired - point) @ normal) + REPLAN_DEPTH_M
        self.pos_ref = self.pos_ref - depth * normal
        return surface

    def _read_plane(self, t: float, desired: np.ndarray, twist_d: np.ndarray) -> tuple:
        """The explored surface's local plane at ``desired`` [m] and the controller's surface: the normal the
        reference reaches ``replan_lead_s`` ahead (the camera's curvature where the first pass had none)."""
        here = self.explored.near(desired)
        if here.gap_m > REPLAN_GAP_M:
            return (t, None, None, None)
        ahead = self.explored.near(here.point_m + self.cfg.replan_lead_s * twist_d[:3])
        curvature = ahead.curvature
        if not np.isfinite(curvature):
            est = self.estimate
            curvature = float(est.curvature) if est is not None and est.valid else 0.0
        surface = SurfaceEstimate(valid=True, timestamp=t, normal_world=ahead.normal, curvature=curvature, planned=True)
        return (t, here.point_m, here.normal, surface)
