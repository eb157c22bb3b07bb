"""The calling thread's scheduling (policy, priority, CPU affinity), kept and given back.

A torque control raises the thread that runs it to SCHED_FIFO: libfranka does it when control starts
(its highest priority, 99, whatever its RealtimeConfig), and :func:`~tactex.robots.libfranka_backend.
pin_control_thread` pins it to a core. Both outlive the robot: a program that closes its backend and goes
on (a notebook, a test session, a study) would run the rest of its work, and every process it starts,
at real-time priority, where a busy loop starves the whole machine. Reading one state is enough:
libfranka's ``Robot`` raises the thread when it connects. :class:`Scheduling` keeps what the thread had
before and gives it back; :func:`kept_scheduling` does it around a block.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

__all__ = ["Scheduling", "kept_scheduling"]


@dataclass(frozen=True)
class Scheduling:
    """One thread's scheduling: ``policy`` (``os.SCHED_*``), ``priority`` and the CPUs it may run on."""

    policy: int
    priority: int
    cpus: frozenset[int]

    @classmethod
    def current(cls) -> Scheduling | None:
        """The calling thread's scheduling now; None where the system does not say (not Linux)."""
        if not (hasattr(os, "sched_getscheduler") and hasattr(os, "sched_getaffinity")):
            return None
        return cls(os.sched_getscheduler(0), os.sched_getparam(0).sched_priority, frozenset(os.sched_getaffinity(0)))

    def restore(self) -> list[str]:
        """Give the calling thread this scheduling back; what could not be restored, one line each (a
        real-time policy may need a permission the process has lost; lowering one never does)."""
        problems = []
        if Scheduling.current() == self:
            return problems
        try:
            os.sched_setscheduler(0, self.policy, os.sched_param(self.priority))
        except OSError as exc:
            problems.append(f"scheduling policy {self.policy} priority {self.priority}: {exc}")
        try:
            os.sched_setaffinity(0, self.cpus)
        except OSError as exc:
            problems.append(f"CPU affinity {sorted(self.cpus)}: {exc}")
        return problems


@contextmanager
def kept_scheduling() -> Iterator[None]:
    """Run the block and give the calling thread back the scheduling it had before it."""
    before = Scheduling.current()
    try:
        yield
    finally:
        if before is not None:
            before.restore()
