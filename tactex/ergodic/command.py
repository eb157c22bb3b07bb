"""What the explorer hands to the robot controller each step."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["ExplorationCommand"]


class ExplorationCommand(NamedTuple):
    """One agent's reference for one step (world frame).

    Attributes:
        point: agent position on the surface [m] (3,); the normal line and tangent plane pass here.
        velocity: agent velocity [m/s] (3,), tangent to the surface.
        normal: unit surface normal at ``point`` (3,), pointing out of the object (away from the
            surface, towards the tool); the normal line (eq. 28) is point + t·normal and the tool
            z axis is −normal.
        tangent_u, tangent_v: orthonormal tangent-plane basis (3,) each, (u, v, normal) right-handed;
            the tangent plane (eq. 29) is point + span(tangent_u, tangent_v).
        step: index of the step that produced the command.
        agent: index of the agent.
    """

    point: np.ndarray
    velocity: np.ndarray
    normal: np.ndarray
    tangent_u: np.ndarray
    tangent_v: np.ndarray
    step: int
    agent: int

    def normal_line_gafro(self):
        """The normal line as a pygafro ``Line`` through point and point + normal."""
        import pygafro as g

        p, q = self.point, self.point + self.normal
        return g.Line(g.Point(*map(float, p)), g.Point(*map(float, q)))

    def tangent_plane_gafro(self):
        """The tangent plane as a pygafro ``Plane``."""
        import pygafro as g

        p = self.point
        return g.Plane(
            g.Point(*map(float, p)),
            g.Point(*map(float, p + self.tangent_u)),
            g.Point(*map(float, p + self.tangent_v)),
        )
