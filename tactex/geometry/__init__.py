"""tactex.geometry: the few CGA helpers the controllers need (TEC eq. 7–17), in closed form
numpy checked against pygafro, plus SO(3) helpers (VA-UFIC eq. 28–29)."""

from tactex.geometry.line import Line3
from tactex.geometry.motor import (
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
from tactex.geometry.so3 import exp_so3, hat, interpolate_rotation, log_so3, orthonormalize, rotation_error_world

__all__ = [
    "Line3",
    "exp_so3",
    "gafro_generator_from_twist",
    "hat",
    "interpolate_rotation",
    "line_motor",
    "log_so3",
    "motor_between_lines",
    "motor_exp",
    "motor_log",
    "motor_to_gafro",
    "orthonormalize",
    "rotation_error_world",
    "twist_from_gafro_generator",
    "twist_to_wrench",
    "z_line_motor_log",
    "z_line_motor_log_floats",
]
