"""A joint-space operator built after a command is sent and applied at the next tick.

The latency-shaped task operator and the null-space posture operator (:mod:`tactex.control.joint_kernels`)
depend on the arm's posture through J(q) and M(q), not on the tick's errors. A controller builds them
in ``prepare(state)``, which :class:`~tactex.tasks.runner.ControlLoop` calls once the torque for
``state`` is on its way (on a real robot: while the robot executes it), and the next tick, between
its state and its command, only multiplies. An operator is used while the joints stay within
:data:`POSTURE_TOLERANCE_RAD` of the posture it was built at; otherwise (the first tick, a jump after
a pause) the tick builds its own.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["POSTURE_TOLERANCE_RAD", "PreparedOperator"]

#: Largest joint displacement ‖q − q₀‖ [rad] over which a prepared operator is still used: two ticks
#: at the Franka's joint speed limit (2.6 rad/s), tens of ticks in contact. M(q) and J(q) change by a
#: fraction of a percent over it. (On a real robot a state's model terms are those of the state
#: before it, so an operator applied at the next tick is built from terms one cycle older still.)
POSTURE_TOLERANCE_RAD = 5e-3
_TOL2 = POSTURE_TOLERANCE_RAD * POSTURE_TOLERANCE_RAD


class PreparedOperator:
    """One operator (an array, or a tuple of arrays) and the joint positions q [rad] it was built at."""

    __slots__ = ("_op", "_q")

    def __init__(self) -> None:
        self._q: np.ndarray | None = None
        self._op: Any = None

    def store(self, q: np.ndarray, op: Any) -> None:
        """Keep ``op`` (an array or a tuple of arrays) for the posture ``q``; a non-finite operator is
        not kept (the previous one is dropped too), so a tick never applies one."""
        parts = op if isinstance(op, tuple) else (op,)
        if not math.isfinite(sum(float(a.sum()) for a in parts)):
            self.clear()
            return
        self._q, self._op = q.copy(), op

    def clear(self) -> None:
        self._q = self._op = None

    def get(self, q: np.ndarray) -> Any:
        """The operator if ``q`` is within :data:`POSTURE_TOLERANCE_RAD` of its posture, else None."""
        q0 = self._q
        if q0 is None or q0.shape != q.shape:
            return None
        d = q - q0
        return self._op if float(d @ d) <= _TOL2 else None  # a NaN deviation gives None
