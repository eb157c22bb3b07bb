"""Closed-form CGA helpers against pygafro (TEC eq. 10, 13, 36–38)."""

from __future__ import annotations

import numpy as np
import pygafro
import pytest

from tactex.errors import InputError
from tactex.geometry import (
    Line3,
    gafro_generator_from_twist,
    line_motor,
    motor_between_lines,
    motor_exp,
    motor_log,
    motor_to_gafro,
    twist_from_gafro_generator,
    twist_to_wrench,
    z_line_motor_log,
    z_line_motor_log_floats,
)
from tactex.geometry.so3 import exp_so3

TOL = 1e-10
N_RANDOM = 20


def _random_lines(rng: np.random.Generator) -> tuple[Line3, Line3]:
    return Line3(rng.normal(size=3), rng.normal(size=3)), Line3(rng.normal(size=3), rng.normal(size=3))


def _same_line(a: Line3, b: Line3, tol: float) -> None:
    np.testing.assert_allclose(a.direction, b.direction, atol=tol)
    assert b.distance_to_point(a.point) < tol


def test_motor_between_lines_matches_pygafro(rng):
    for _ in range(N_RANDOM):
        l1, l2 = _random_lines(rng)
        rot, trans = motor_between_lines(l1, l2)
        ref = l1.to_gafro().getMotor(l2.to_gafro()).toTransformationMatrix()
        np.testing.assert_allclose(rot, ref[:3, :3], atol=TOL)
        np.testing.assert_allclose(trans, ref[:3, 3], atol=TOL)


@pytest.mark.parametrize("case", ["random", "parallel", "antiparallel", "intersecting", "identical"])
def test_motor_maps_one_line_onto_the_other(rng, case):
    l1 = Line3(rng.normal(size=3), rng.normal(size=3))
    if case == "random":
        l2 = Line3(rng.normal(size=3), rng.normal(size=3))
    elif case == "parallel":
        l2 = Line3(l1.point + rng.normal(size=3), l1.direction)
    elif case == "antiparallel":
        l2 = Line3(l1.point + rng.normal(size=3), -l1.direction)
    elif case == "intersecting":
        l2 = Line3(l1.point + 0.7 * l1.direction, rng.normal(size=3))
    else:
        l2 = Line3(l1.point + 2.0 * l1.direction, l1.direction)
    rot, trans = motor_between_lines(l1, l2)
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=TOL)
    _same_line(l1.transformed(rot, trans), l2, 1e-9)
    if case == "identical":
        np.testing.assert_allclose(motor_log(rot, trans), np.zeros(6), atol=TOL)  # M = 1 ⇒ V = 0 (TEC §IV-B1)


def test_pygafro_motor_maps_line_too(rng):
    """The library's own sandwich M L M̃ (eq. 13) agrees: our (R, t) as a pygafro motor moves L1 onto L2."""
    l1, l2 = _random_lines(rng)
    rot, trans = motor_between_lines(l1, l2)
    moved = motor_to_gafro(rot, trans).apply(l1.to_gafro())
    np.testing.assert_allclose(moved.normalized().vector(), l2.to_gafro().normalized().vector(), atol=1e-9)


def test_log_matches_pygafro_and_round_trips(rng):
    for _ in range(N_RANDOM):
        rot = exp_so3(rng.normal(size=3) * 0.9)
        trans = rng.normal(size=3)
        xi = motor_log(rot, trans)
        m = motor_to_gafro(rot, trans)
        np.testing.assert_allclose(m.toTransformationMatrix()[:3, :3], rot, atol=TOL)
        np.testing.assert_allclose(m.toTransformationMatrix()[:3, 3], trans, atol=TOL)
        lg = m.log()
        b = np.array([lg.get_e12(), lg.get_e13(), lg.get_e23(), lg.get_e1i(), lg.get_e2i(), lg.get_e3i()])
        np.testing.assert_allclose(twist_from_gafro_generator(b), xi, atol=1e-8)  # gafro's log has a 1e-10 guard
        rot2, trans2 = motor_exp(xi)
        np.testing.assert_allclose(rot2, rot, atol=TOL)
        np.testing.assert_allclose(trans2, trans, atol=TOL)
        back = pygafro.Motor.exp(pygafro.MotorGenerator(gafro_generator_from_twist(xi))).evaluate()
        np.testing.assert_allclose(back.vector(), m.vector(), atol=TOL)


def test_generator_index_maps_are_inverse(rng):
    xi = rng.normal(size=6)
    np.testing.assert_allclose(twist_from_gafro_generator(gafro_generator_from_twist(xi)), xi, atol=0)


def test_literal_conjugate_pseudoscalar_pairs_translation_with_torque():
    """Records why twist_to_wrench is the power-conjugate identity: in pygafro's blades the literal
    grade-2 part of V·I_c (I_c = I e0) sends the translation e3i to the torque blade e12."""
    ic = pygafro.E0123i(1.0) * pygafro.E0(1.0)
    w = pygafro.Twist(np.array([0, 0, 0, 0, 0, 1.0])) * ic  # pure translation along z
    coeffs = dict(zip(w.blades(), w.vector(), strict=True))
    assert coeffs[6] == pytest.approx(1.0)  # blade 6 = e12, the z-torque of pygafro.Wrench
    assert coeffs[9] == pytest.approx(0.0)  # blade 9 = e03, the z-force
    xi = np.array([0.1, -0.2, 0.3, 0.01, 0.02, -0.03])
    np.testing.assert_allclose(twist_to_wrench(xi), xi)
    assert float(xi @ twist_to_wrench(xi)) > 0.0  # power-positive pairing


@pytest.mark.parametrize(
    ("point", "direction"),
    [([0, 0], [0, 0, 1]), ([0, 0, np.nan], [0, 0, 1]), ([0, 0, 0], [0, 0, 0]), ([0, 0, 0], [np.inf, 0, 0])],
)
def test_line_rejects_bad_input(point, direction):
    with pytest.raises(InputError, match="Line3"):
        Line3(np.asarray(point, float), np.asarray(direction, float))


def test_z_line_fast_path_matches_general_motor(rng):
    """The controller's per-tick closed form against line_motor and against pygafro's getMotor/log."""
    z_axis = Line3(np.zeros(3), np.array([0.0, 0.0, 1.0]))
    for k in range(200):
        p = rng.normal(size=3)
        d = rng.normal(size=3)
        if k % 4 == 0:  # nearly parallel, down to 1e-12 rad
            d = np.array([0.0, 0.0, 1.0]) + 10.0 ** rng.uniform(-12, -3) * rng.normal(size=3)
        d /= np.linalg.norm(d)
        fast = z_line_motor_log(p, d)
        np.testing.assert_allclose(fast, motor_log(*line_motor(np.zeros(3), np.array([0.0, 0.0, 1.0]), p, d)),
                                   atol=1e-9)
        assert fast[5] == 0.0  # never a rotation about the tool axis
        if k % 4 != 0:
            m = z_axis.to_gafro().getMotor(Line3(p, d).to_gafro())
            lg = m.log()
            b = np.array([lg.get_e12(), lg.get_e13(), lg.get_e23(), lg.get_e1i(), lg.get_e2i(), lg.get_e3i()])
            np.testing.assert_allclose(fast, twist_from_gafro_generator(b), atol=1e-7)


def test_z_line_float_form_is_the_array_form_and_handles_antiparallel_lines(rng):
    """The per-tick float variant returns six Python floats equal to z_line_motor_log, including the
    anti-parallel fallback (d = −e_z), which must still map the z-axis onto the line (pygafro's
    normalisation divides by zero there, so line_motor is the reference)."""
    cases = [(rng.normal(size=3), rng.normal(size=3)) for _ in range(20)]
    cases += [(rng.normal(size=3), np.array([0.0, 0.0, -1.0])), (np.zeros(3), np.array([0.0, 0.0, -1.0])),
              (rng.normal(size=3), np.array([0.0, 0.0, 1.0]))]
    for p, d in cases:
        d = d / np.linalg.norm(d)
        g = z_line_motor_log_floats(*p.tolist(), *d.tolist())
        assert len(g) == 6 and all(type(x) is float for x in g)
        np.testing.assert_array_equal(np.array(g), z_line_motor_log(p, d))
        np.testing.assert_allclose(np.array(g), motor_log(*line_motor(np.zeros(3), np.array([0.0, 0.0, 1.0]), p, d)),
                                   atol=1e-9)
        rot, trans = motor_exp(np.array(g))
        _same_line(Line3(trans, rot @ np.array([0.0, 0.0, 1.0])), Line3(p, d), 1e-9)
