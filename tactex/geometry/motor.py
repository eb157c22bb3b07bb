"""Motors (rigid transformations of CGA, TEC eq. 13–14) in closed form, checked against pygafro.

A motor M = T·R is kept here as the pair (R, t): x ↦ R·x + t, exactly what
``pygafro.Motor.toTransformationMatrix`` returns. The logarithm follows gafro's definition
(``Motor::Logarithm``): the generator B = log R + t·e∞ with the rotation bivector
(e12, e13, e23) = (ω_z, −ω_y, ω_x) and the translation (e1i, e2i, e3i) = t. In numpy order we
return the generator as ``[t (3), ω (3)]`` ([linear; angular], like every twist in tactex).

Why closed forms: a controller tick at 1 kHz needs a handful of these, and one pygafro call costs
several times more than the numpy formulas below; tests assert they agree with pygafro to 1e-12.
"""

from __future__ import annotations

import math

import numpy as np

from tactex.geometry.line import Line3
from tactex.geometry.so3 import exp_so3, log_so3

__all__ = [
    "gafro_generator_from_twist",
    "line_motor",
    "motor_between_lines",
    "motor_exp",
    "motor_log",
    "motor_to_gafro",
    "twist_from_gafro_generator",
    "twist_to_wrench",
    "z_line_motor_log",
    "z_line_motor_log_floats",
]


def motor_between_lines(line_from: Line3, line_to: Line3) -> tuple[np.ndarray, np.ndarray]:
    """The motor that maps ``line_from`` onto ``line_to`` (TEC eq. 36, normalised as in [54]).

    Equal to ``line_from.to_gafro().getMotor(line_to.to_gafro())``: a screw about the common
    perpendicular of the two lines, rotating by the angle between the directions and
    translating by their distance. Returns (R, t) with x ↦ R·x + t.
    """
    return line_motor(line_from.point, line_from.direction, line_to.point, line_to.direction)


def line_motor(p1: np.ndarray, d1: np.ndarray, p2: np.ndarray, d2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`motor_between_lines` on raw arrays (unit directions ``d1``, ``d2``; no checks: per tick).

    For parallel lines it is the pure translation between them; for anti-parallel lines (angle
    π, axis not unique, where gafro's normalisation divides by zero) the rotation axis is taken
    perpendicular to the line and to the offset between the lines.
    """
    w = p2 - p1
    cross = np.cross(d1, d2)
    s = math.sqrt(float(cross @ cross))
    c = float(d1 @ d2)
    if c < -1.0 + 1e-9:
        perp = w - float(w @ d1) * d1
        if float(perp @ perp) > 1e-18:
            axis = np.cross(d1, perp)
        else:
            axis = np.cross(d1, np.eye(3)[int(np.argmin(np.abs(d1)))])
        rot = exp_so3(math.pi * axis / np.linalg.norm(axis))
        return rot, p1 + perp - rot @ p1
    rot = exp_so3(cross * (math.atan2(s, c) / s)) if s > 1e-12 else np.eye(3)
    # The screw axis is the common perpendicular: t = c2 − R·c1 for the closest points c1, c2, and
    # since R·d1 = d2 this is p2 − R·p1 + (s2 − s1)·d2 with s2 − s1 = −(d1·w + d2·w)/(1 + d1·d2),
    # a form that stays well conditioned when the lines become parallel.
    return rot, p2 - rot @ p1 - (float(d1 @ w + d2 @ w) / (1.0 + c)) * d2


def z_line_motor_log(point: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """``motor_log(*line_motor(0, e_z, point, direction))`` in scalar closed form (the per-tick path):
    :func:`z_line_motor_log_floats` as an array."""
    return np.array(z_line_motor_log_floats(float(point[0]), float(point[1]), float(point[2]),
                                            float(direction[0]), float(direction[1]), float(direction[2])))


def z_line_motor_log_floats(px: float, py: float, pz: float, dx: float, dy: float, dz: float
                            ) -> tuple[float, float, float, float, float, float]:
    """:func:`z_line_motor_log` of the line through (px, py, pz) along the unit (dx, dy, dz), on Python
    floats and returning six of them (a controller tick calls it: no array in, none out).

    For the z-axis through the origin and a line (p, d) with d_z > −1 the screw axis is
    a = e_z × d / |e_z × d| and the angle φ = atan2(|e_z × d|, d_z), so ω = φ·a (no z-component);
    the closest points give t = p − ((p_z + d·p) / (1 + d_z))·d, which reduces to the lateral offset
    (p_x, p_y, 0) for parallel lines. Anti-parallel lines (d_z = −1) fall back to :func:`line_motor`.
    """
    s = math.sqrt(dx * dx + dy * dy)
    if dz <= -1.0 + 1e-12:
        g = motor_log(*line_motor(np.zeros(3), np.array([0.0, 0.0, 1.0]), np.array([px, py, pz]),
                                  np.array([dx, dy, dz]))).tolist()
        return g[0], g[1], g[2], g[3], g[4], g[5]
    scale = math.atan2(s, dz) / s if s > 1e-12 else 1.0
    k = (pz + dx * px + dy * py + dz * pz) / (1.0 + dz)
    return px - k * dx, py - k * dy, pz - k * dz, -dy * scale, dx * scale, 0.0


def motor_log(rot: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """gafro's motor logarithm as ``[t, ω]`` (6,): ω = log R [rad], t the translation [m]."""
    return np.concatenate([np.asarray(trans, dtype=float), log_so3(rot)])


def motor_exp(generator: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`motor_log`: M = T(t)·R(ω), returned as (R, t)."""
    g = np.asarray(generator, dtype=float)
    return exp_so3(g[3:]), g[:3].copy()


def gafro_generator_from_twist(xi: np.ndarray) -> np.ndarray:
    """numpy ``[t, ω]`` → pygafro generator vector ``[e12, e13, e23, e1i, e2i, e3i]``."""
    return np.array([xi[5], -xi[4], xi[3], xi[0], xi[1], xi[2]])


def twist_from_gafro_generator(b: np.ndarray) -> np.ndarray:
    """pygafro generator vector ``[e12, e13, e23, e1i, e2i, e3i]`` → numpy ``[t, ω]``."""
    return np.array([b[3], b[4], b[5], b[2], -b[1], b[0]])


def motor_to_gafro(rot: np.ndarray, trans: np.ndarray):
    """The pygafro.Motor T(t)·R for x ↦ R·x + t (used by tests and tools, not per tick)."""
    import pygafro

    return pygafro.Motor.exp(pygafro.MotorGenerator(gafro_generator_from_twist(motor_log(rot, trans)))).evaluate()


def twist_to_wrench(xi: np.ndarray) -> np.ndarray:
    """TEC eq. 38, W = V·I_c, as the power-conjugate identification [t, ω] → [f, m].

    The paper replaces an inertia tensor by the conjugate pseudoscalar I_c = I·e₀ "purely
    algebraically". With pygafro's blade conventions the literal grade-2 part of V·I_c sends
    the translational generator e3i to the torque blade e12 and the rotational e12 to the force
    blade e03 (``tests/test_geometry_motor.py`` records this), i.e. it pairs a position error
    with a torque. The controller needs the pairing under which ⟨V, W⟩ is the power, so a
    translation error yields a force along it and a rotation error a torque about it; that is
    the identity on ``[linear; angular]`` — the "scalar inertia" the paper chose — and the
    stiffness K then scales each component.
    """
    return np.asarray(xi, dtype=float).copy()
