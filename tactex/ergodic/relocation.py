"""Relocation (lift-and-move): when walking on the surface makes no progress, go elsewhere through the air.

TEC §VI-B: an agent that walks on the surface cannot reach target on a part the Laplacian does not
connect to its own (heat does not diffuse there), nor across a gap wider than it may leave the cloud
to cross, nor past a keep-out zone; "for unconnected regions the robot can lift off and move". The
explorer watches for these cases (:class:`ProgressMonitor`) and then emits a
:class:`RelocationCommand` instead of a walking step: lift off along the normal where the agent is,
move through free space, touch down along the normal at the chosen point. A virtual agent jumps; a
robot (``tactex clean``) flies the waypoints.

Where to touch down (:func:`choose_touch_down`): among the target points no footprint has touched
yet (and that a footprint may touch: clear of keep-out zones), the one with the most such mass
within a footprint radius per metre of flight: ``score = m_r(j) / (|x_j − x| + r_a)``. Nearer wins,
and a clump beats a lone speck at the same distance.

Hops across scan holes (``HedacConfig.max_bridge_voxels``, :mod:`.bridges`) stay as they are: a hop is a
short in-contact slide along a link of the Laplacian (a few voxels, the tool never leaves the
surface); a relocation is the general fallback for everything a hop cannot join, and it costs a
lift-off. The explorer hops first when the Laplacian joins the two sides; it relocates only when
neither walking nor hopping makes progress.
"""

from __future__ import annotations

import logging
from collections import deque
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from tactex.ergodic.surface_fit import normal_at, tangent_basis

__all__ = [
    "RELOCATION_CHECK_EVERY",
    "RELOCATION_REASONS",
    "STALL_SAMPLE_EVERY",
    "ProgressMonitor",
    "Relocating",
    "RelocationCommand",
    "choose_touch_down",
]

_log = logging.getLogger(__name__)

#: Why the explorer relocated (RelocationCommand.reason).
RELOCATION_REASONS = ("part_done", "stall", "no_progress", "keep_out")
#: Candidates scored per relocation at most (the nearest ones; the score falls with distance).
MAX_CANDIDATES = 4000
#: Steps between the samples of the agent's position for the stall rule (a multiple of them is a
#: stall: an agent sampled inside the stall circle every time), and between the checks of the untouched
#: target (part done, no progress) of the relocation rules: cheap, but not worth paying every step.
STALL_SAMPLE_EVERY = 5
RELOCATION_CHECK_EVERY = 10


class RelocationCommand(NamedTuple):
    """A lift-and-move of one agent (world frame): lift off at ``lift_off`` along ``lift_off_normal``
    by ``clearance_m``, fly to ``clearance_m`` above ``point`` along ``normal``, touch down at ``point``.

    The first seven fields are those of :class:`~tactex.ergodic.command.ExplorationCommand`, at the
    touch-down: code that reads only ``point`` and ``normal`` sees the virtual agent jump.

    Attributes:
        point: touch-down point [m] (3,), a cloud point.
        velocity: zero [m/s] (3,): the agent lands at rest.
        normal: unit outward normal at the touch-down (3,); the approach runs along −normal.
        tangent_u, tangent_v: tangent-plane basis at the touch-down (3,) each.
        step: index of the step that produced the command.
        agent: index of the agent.
        lift_off: where the agent left the surface [m] (3,).
        lift_off_normal: unit outward normal there (3,); the lift-off runs along it.
        clearance_m: height of the flight above both ends along their normals [m].
        air_length_m: length of the flight through the waypoints [m].
        reason: one of :data:`RELOCATION_REASONS`.
    """

    point: np.ndarray
    velocity: np.ndarray
    normal: np.ndarray
    tangent_u: np.ndarray
    tangent_v: np.ndarray
    step: int
    agent: int
    lift_off: np.ndarray
    lift_off_normal: np.ndarray
    clearance_m: float
    air_length_m: float
    reason: str

    def waypoints(self) -> np.ndarray:
        """(4, 3) [m]: lift-off, above it, above the touch-down, touch-down."""
        c = self.clearance_m
        return np.array([self.lift_off, self.lift_off + c * self.lift_off_normal, self.point + c * self.normal,
                         self.point])


def air_length(lift_off: np.ndarray, lift_off_normal: np.ndarray, touch_down: np.ndarray, normal: np.ndarray,
               clearance_m: float) -> float:
    """Length [m] of the flight lift-off → clearance above it → clearance above the touch-down → touch-down."""
    a = lift_off + clearance_m * lift_off_normal
    b = touch_down + clearance_m * normal
    return float(2.0 * clearance_m + np.linalg.norm(b - a))


def choose_touch_down(points: np.ndarray, candidates: np.ndarray, mass: np.ndarray, x: np.ndarray,
                      radius_m: float) -> int | None:
    """The cloud point to touch down at, or None without candidates.

    Args:
        points: cloud points (N, 3) [m].
        candidates: indices of the target points not yet touched that a footprint may touch.
        mass: their target mass (same length as ``candidates``).
        x: where the agent lifts off [m] (3,).
        radius_m: footprint radius r_a [m].

    The score of candidate j is m_r(j) / (|x_j − x| + r_a), m_r(j) the candidates' mass within r_a of j.
    """
    if candidates.size == 0:
        return None
    pts = points[candidates]
    dist = np.linalg.norm(pts - x, axis=1)
    near = np.arange(candidates.size)
    if candidates.size > MAX_CANDIDATES:
        near = np.argpartition(dist, MAX_CANDIDATES)[:MAX_CANDIDATES]
    tree = cKDTree(pts)
    balls = tree.query_ball_point(pts[near], radius_m)
    clump = np.array([float(mass[b].sum()) for b in balls])
    score = clump / (dist[near] + radius_m)
    return int(candidates[near[int(np.argmax(score))]])


class ProgressMonitor:
    """Stall and progress bookkeeping of one agent.

    A stall: the agent stayed within ``radius_m`` of an anchor for ``stall_steps`` steps (the anchor
    moves to the agent whenever it leaves that circle). No progress: over the last ``progress_steps``
    steps the count of untouched target points fell by less than ``min_gain`` (0 steps = never).
    """

    def __init__(self, x: np.ndarray, step: int, radius_m: float, stall_steps: int, progress_steps: int,
                 min_gain: float = 1.0) -> None:
        self.radius2 = radius_m * radius_m
        self.stall_steps = stall_steps
        self.progress_steps = progress_steps
        self.min_gain = min_gain
        self.restart(x, step, None)

    def restart(self, x: np.ndarray, step: int, untouched: int | None) -> None:
        """Start watching afresh from x [m] at ``step`` (after a reset or a relocation)."""
        self.anchor = tuple(float(v) for v in x)
        self.anchor_step = step
        self.start_step = step
        self.history: deque[tuple[int, int]] = deque()
        if untouched is not None:
            self.history.append((step, untouched))

    def moved_to(self, x: np.ndarray, step: int) -> None:
        """The agent is at x [m] (3,) after ``step`` (Python floats: this runs every step)."""
        x0, x1, x2 = x.tolist()
        a0, a1, a2 = self.anchor
        d0, d1, d2 = x0 - a0, x1 - a1, x2 - a2
        if d0 * d0 + d1 * d1 + d2 * d2 > self.radius2:
            self.anchor = (x0, x1, x2)
            self.anchor_step = step

    def stalled(self, step: int) -> bool:
        return step - self.anchor_step >= self.stall_steps

    def no_progress(self, untouched: int, step: int) -> bool:
        """Record the untouched count at ``step``; True when over the last progress_steps steps it fell
        by less than min_gain."""
        if self.progress_steps <= 0:
            return False
        h = self.history
        h.append((step, untouched))
        while len(h) > 1 and h[1][0] <= step - self.progress_steps:
            h.popleft()
        first_step, first = h[0]
        return step - first_step >= self.progress_steps and first - untouched < self.min_gain


class Relocating:
    """The explorer's relocations (mixed into :class:`~tactex.ergodic.explorer.HedacExplorer`): when an
    agent is due one (:meth:`_relocation_due`), it lifts off, flies and touches down at untouched target
    (:meth:`_relocate`); the other agents walk that step. It reads the explorer's target and coverage, the
    agents' state, the progress monitors and the passes' plan (a stall on a planned tour lands further on)."""

    def _untouched(self) -> np.ndarray:
        """Per target point, True when no footprint has touched it yet and one may (clear of keep-out)."""
        return (self._cov.take(self._tidx) < self._p_t) & self._t_safe

    def _relocation_due(self, i: int) -> str | None:
        """Why agent i should relocate now (a :data:`~.relocation.RELOCATION_REASONS` entry), or None."""
        if self._bridges[i] is not None:
            return None
        mon = self._monitors[i]
        k = self.step_count
        mon.moved_to(self._x[i], k)
        if self._ko_tree is not None and not self._clear_of_keep_out(self._x[i], int(self._near[i])):
            return "keep_out"
        stalled = mon.stalled(k)
        if not stalled and k % RELOCATION_CHECK_EVERY:
            return None
        untouched = self._untouched()
        count = int(np.count_nonzero(untouched))
        if count == 0:
            mon.restart(self._x[i], k, 0)  # nothing left to touch: HEDAC goes on revisiting in place
            return None
        if stalled:
            return "stall"
        part = self._labels.item(int(self._near[i]))
        if not (untouched & (self._t_part == part)).any():
            return "part_done"
        if self.planned_passes and not self._walkable_left(untouched):
            return "part_done"  # what is left of the part lies across a gap the agent may not walk
        if mon.no_progress(count, k):
            return "no_progress"
        return None

    def _step_with_relocations(self, moves: list[str | None], exact: bool) -> list:
        """One step in which some agents relocate; the others (and those with nowhere to go) walk."""
        out: list = [self._relocate(i, m) if m is not None else None for i, m in enumerate(moves)]
        walking = [i for i, c in enumerate(out) if c is None]
        if len(walking) == 1:
            out[walking[0]] = self._step_agent(walking[0], exact)
        elif walking:
            for i, cmd in zip(walking, self._step_together(walking, exact), strict=True):
                out[i] = cmd
        return out

    def _relocate(self, i: int, reason: str) -> RelocationCommand | None:
        """Agent i lifts off, flies to the chosen untouched target and lands there at rest."""
        untouched = self._untouched()
        cand = self._tidx[untouched]
        x = self._x[i].copy()
        j = self._next_on_tour(i) if reason == "stall" else None
        on_tour = j is not None
        if j is None and reason == "stall" and self.planned_passes:
            # A stall in the hunt touches down where the walks and hops from here still reach target: that side is
            # finished before the flight to a part they do not reach, which is then the only one left (else the
            # flight lands there, and another brings the agent back for the rest).
            same = self._passes.reach_mask(self._tpos.item(self._near[i]), untouched & ~self._given_up)
            if same.any():
                j = choose_touch_down(self._points, self._tidx[same], self._p_t[same], x, self._r_a)
        if j is None:
            j = choose_touch_down(self._points, cand, self._p_t[untouched], x, self._r_a)
        mon = self._monitors[i]
        if j is None:
            mon.restart(x, self.step_count, 0)
            return None
        end = self._points[j].copy()
        n_end = self._touch_down_normal(j, np.array(self._nrm_t[i]))
        n_start = np.array(self._nrm_t[i])
        c = self.config.relocation_clearance_m
        air = air_length(x, n_start, end, n_end, c)
        self._x[i] = end
        self._nrm_t[i] = tuple(n_end.tolist())
        self._near[i] = j
        self._agents[i].velocity = np.zeros(3)
        self.air_path_lengths[i] += air
        if self._passes is not None:
            self._passes.drop_goal(abandon=reason == "stall", replan=not on_tour)
            if reason == "stall" and self._leftover_goal >= 0:
                self._given_up[self._leftover_goal] = True  # it stalled on the way: not a goal again
            self._leftover_goal = -1
        mon.restart(end, self.step_count, None)
        t1, t2 = tangent_basis(n_end)
        cmd = RelocationCommand(end.copy(), np.zeros(3), n_end, t1, t2, self.step_count, i, x, n_start, c, air, reason)
        self.relocations.append(cmd)
        _log.info("agent %d relocates (%s) from %s to %s m, %.3f m through the air", i, reason,
                  np.round(x, 4).tolist(), np.round(end, 4).tolist(), air)
        return cmd

    def _touch_down_normal(self, j: int, current: np.ndarray) -> np.ndarray:
        """Unit outward normal at cloud point j: the fitted patch's, oriented along the cloud's own normal
        when it has normals, else away from the cloud's centroid (a closed object) or, where that is
        ambiguous (an open sheet seen edge-on from its centroid), along the agent's current normal."""
        end = self._points[j]
        if self.cloud.normals is not None:
            ref = self.cloud.normals[j]
        else:
            ref = current
            radial = end - self._points.mean(axis=0)
            rn = float(np.sqrt(radial @ radial))
            if rn > 0.0:
                probe = normal_at(self._points, self._tree, self._n_n, end, radial / rn)
                if abs(float(probe @ radial)) > 0.3 * rn:
                    ref = radial / rn
        n = normal_at(self._points, self._tree, self._n_n, end, ref)
        return n
