"""Putting off the cleaning agent's steps while the tool lags it or is dragged against a wall."""

from __future__ import annotations

__all__ = ["StepHold"]


class StepHold:
    """At each due exploration step, whether to put it off: while the tool is ``behind`` (it lags the
    commanded point, or the contact force shows it dragged against a wall), for at most ``max_steps`` in a
    row. The count restarts only once the tool has caught up, so a point the tool can never reach holds the
    agent ``max_steps`` steps once, not ``max_steps`` of every ``max_steps + 1``.
    """

    def __init__(self, max_steps: int) -> None:
        if max_steps < 0:
            raise ValueError(f"max_steps must be ≥ 0, got {max_steps}")
        self.max_steps = int(max_steps)
        self.held = 0  # steps put off since the tool was last caught up

    def hold(self, behind: bool) -> bool:
        """True: put this step off. Call once per due step."""
        if not behind:
            self.held = 0
            return False
        if self.held < self.max_steps:
            self.held += 1
            return True
        return False
