"""The clean's exploration step taken one control tick early, while the robot executes a command.

On a real robot a control tick is: the state arrives, the torque is computed and sent, and the
robot executes it for a millisecond before the next state. Only the torque may sit between a state
and its command (libfranka's budget); the explorer's step (HEDAC on the cloud, more on large clouds),
the wear model's reads and a target update (a projection on the eigenbasis) would make the cycle late
on the ticks they run. :class:`StepAhead` is the contact loop's ``after_send`` (``ControlLoop.tick``): when
the next tick is a step tick it takes the explorer's step now, with what that step's decisions will
read, and it applies a target update the last step asked for. The decisions themselves (island
moves, strokes, when to go to the camera) stay in the loop, at the step tick, on these values.

What is read one tick earlier than in a loop that steps in place: the measured TCP (only with
``agent_feedback``) and the wear model, which lacks the one tick not yet accounted (its update is
batched over ten ticks anyway). The step itself does not read the robot's state otherwise.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tactex.ergodic.explorer import HedacExplorer
from tactex.ergodic.relocation import RelocationCommand
from tactex.tasks.path_source import PathSource

__all__ = ["ERGODICITY_EVERY_STEPS", "StepAhead"]

#: Exploration steps between two reads of the explorer's ergodicity (and coverage residual).
ERGODICITY_EVERY_STEPS = 20


class StepAhead:
    """The explorer's next step and its reads, prepared in ``after_send`` (see the module docstring).

    Args:
        source: what the agent follows (a :class:`~tactex.tasks.path_source.PathSource`).
        dt_s: the control period [s].
        wear: the wear model (None without one), read at model-update steps.
        settle: called first in every ``after_send`` (the wear accounting of the last tick), or None.
        agent_feedback: the step reads the measured TCP (TEC eq. 22).
        read_residual: the coverage residual is read with the ergodicity (a given target cloud).
        model_update_steps: steps between wear-model updates.
        island_radius_m: the radius [m] within which ``island_left`` looks for dirt at the new point.
        explorer: the HEDAC explorer when it is ``source``, whose ergodicity is read; None: none is.

    Before each tick, :meth:`arm` says when the next step is due and whether the explorer takes it;
    at a step tick, :meth:`take` hands over the prepared step, if any.
    """

    def __init__(self, source: PathSource, dt_s: float, *, wear=None, settle=None, agent_feedback: bool = False,
                 read_residual: bool = False, model_update_steps: int = 10, island_radius_m: float = 0.05,
                 explorer: HedacExplorer | None = None) -> None:
        self.source, self.dt_s, self.wear, self.settle = source, float(dt_s), wear, settle
        self.explorer = explorer
        self.agent_feedback, self.read_residual = agent_feedback, read_residual
        self.model_update_steps, self.island_radius_m = int(model_update_steps), float(island_radius_m)
        self._next: tuple[Any, dict[str, Any]] | None = None
        self._target: np.ndarray | None = None
        self._due_t = float("inf")
        self._step_index = 0
        self._enabled = False

    @property
    def pending(self) -> bool:
        """A step was taken ahead and not handed over yet."""
        return self._next is not None

    def arm(self, due_t: float, step_index: int, enabled: bool) -> None:
        """The next step is due at ``due_t`` [s] (loop time) and will be the ``step_index``-th since the
        last view; ``enabled``: the explorer takes it (False while a stroke path drives the agent)."""
        self._due_t, self._step_index, self._enabled = float(due_t), int(step_index), bool(enabled)

    def update_target_later(self, target: np.ndarray) -> None:
        """Set the explorer's target after this tick's command is sent (before its next step)."""
        self._target = target

    def take(self) -> tuple[Any, dict[str, Any]] | None:
        """(command, :meth:`read`) of the step taken ahead, or None: then the loop steps in place and calls
        :meth:`read` itself."""
        out, self._next = self._next, None
        return out

    def read(self, cmd, step_index: int, model: bool = True) -> dict[str, Any]:
        """What the decisions of the ``step_index``-th step since the last view read, after its command
        ``cmd``: ``ergodicity`` and ``residual`` (None unless ``read_residual``) every
        :data:`ERGODICITY_EVERY_STEPS` steps of the explorer; ``predicted`` (the wear model's
        remaining dirt, the last tick accounted first) and ``island_left`` at the model-update steps when
        ``model`` (the explorer drives the agent, not a stroke). Nothing after a relocation."""
        reads: dict[str, Any] = {}
        if isinstance(cmd, RelocationCommand):
            return reads
        k = step_index
        if self.explorer is not None and k % ERGODICITY_EVERY_STEPS == 0:
            reads["ergodicity"] = self.explorer.ergodicity()
            reads["residual"] = self.explorer.coverage_residual() if self.read_residual else None
        if model and self.wear is not None and k % self.model_update_steps == 0:
            if self.settle is not None:
                self.settle()
            reads["predicted"] = self.wear.remaining()
            reads["island_left"] = self.wear.island_left(cmd.point, self.island_radius_m)
        return reads

    def __call__(self, state) -> None:
        if self.settle is not None:
            self.settle()
        if self._target is not None:
            target, self._target = self._target, None
            self.source.update_target(target, keep_coverage=True)
        if self._next is not None or not self._enabled or state.t + self.dt_s < self._due_t - 1e-9:
            return
        cmd = self.source.step(state.ee_position if self.agent_feedback else None)
        self._next = (cmd, self.read(cmd, self._step_index))
