"""The contact wrench in franky-sim's robot state, where stock franky-sim reports zero.

``K_F_ext_hat_K`` / ``O_F_ext_hat_K`` / ``tau_ext_hat_filtered`` come from the MuJoCo contact forces
on the robot, with libfranka's documented sign: the wrench the robot exerts on the environment is
positive (``robot_state.h``: "Forces applied by the robot to the environment are positive, while
forces applied by the environment on the robot are negative"), about the K frame's origin
(``O_T_EE · EE_T_K``). ``TwinConfig.ext_wrench_on_robot`` flips it, for clients written the other
way round. The state also carries libfranka's ``control_command_success_rate`` as the twin counts it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["contact_aware_robot_class", "wrench_about_k"]

_IDENTITY16 = (1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0)


def wrench_about_k(o_t_ee, ee_t_k, force_on_robot, moment_on_robot, sign: float):
    """The contact wrench as libfranka reports it: (``O_F_ext_hat_K``, ``K_F_ext_hat_K``), each
    (force [N], moment [N·m]) as 6 floats, from the force on the robot (world frame) and its moment
    about the world origin. The moment is taken about the K frame's origin (``O_T_EE · EE_T_K``, both
    16 floats, column-major); ``sign`` −1 gives the robot's wrench on the environment. Python floats,
    not numpy: the twin calls it every contact tick, where a dozen calls on 3-vectors would cost
    more in numpy's per-call overhead than the arithmetic."""
    a = o_t_ee if tuple(ee_t_k) == _IDENTITY16 else tuple(
        (np.asarray(o_t_ee, dtype=float).reshape(4, 4, order="F")
         @ np.asarray(ee_t_k, dtype=float).reshape(4, 4, order="F")).flatten(order="F").tolist())
    px, py, pz = a[12], a[13], a[14]
    fx, fy, fz = force_on_robot
    mx = moment_on_robot[0] - (py * fz - pz * fy)
    my = moment_on_robot[1] - (pz * fx - px * fz)
    mz = moment_on_robot[2] - (px * fy - py * fx)
    fx, fy, fz, mx, my, mz = sign * fx, sign * fy, sign * fz, sign * mx, sign * my, sign * mz
    world = (fx, fy, fz, mx, my, mz)
    k = (a[0] * fx + a[1] * fy + a[2] * fz, a[4] * fx + a[5] * fy + a[6] * fz, a[8] * fx + a[9] * fy + a[10] * fz,
         a[0] * mx + a[1] * my + a[2] * mz, a[4] * mx + a[5] * my + a[6] * mz, a[8] * mx + a[9] * my + a[10] * mz)
    return world, k


_ZERO6, _ZERO7 = (0.0,) * 6, (0.0,) * 7


def contact_aware_robot_class(base: type) -> type:
    """franky-sim's MuJoCo robot whose state carries the contact wrench and the command success rate
    (see the module docstring); the twin sets the class of the robot franky-sim built to it."""

    class TwinRobot(base):  # type: ignore[misc, valid-type]
        _twin_ext: Any = None
        _twin_on_robot = False
        _twin_success = 1.0

        @property
        def state(self):
            st = super().state
            # franky-sim builds a new frozen snapshot per call, so it is filled in place:
            # dataclasses.replace would build all of its ~40 fields a second time every tick
            put = object.__setattr__
            put(st, "control_command_success_rate", self._twin_success)
            ext = self._twin_ext
            if ext is None:
                put(st, "O_F_ext_hat_K", _ZERO6)
                put(st, "K_F_ext_hat_K", _ZERO6)
                put(st, "tau_ext_hat_filtered", _ZERO7)
                return st
            f_on, m0_on, tau_on = ext
            sign = 1.0 if self._twin_on_robot else -1.0  # libfranka: the robot's wrench on the environment
            world, k = wrench_about_k(st.O_T_EE, st.EE_T_K, f_on, m0_on, sign)
            put(st, "O_F_ext_hat_K", world)
            put(st, "K_F_ext_hat_K", k)
            put(st, "tau_ext_hat_filtered", tuple((sign * np.asarray(tau_on)).tolist()))
            return st

    return TwinRobot
