"""The external wrench in franky-sim's robot state, where stock franky-sim reports zero.

``K_F_ext_hat_K`` / ``O_F_ext_hat_K`` / ``tau_ext_hat_filtered`` are what a Franka estimates from its
joint torques: what the tool does to the flange, less the weight and translational inertia of the load the
client declared (``set_load``, as a point mass; a wrongly declared load shows, as on the robot), plus the
contacts on the arm's own links (summed as a force and its moment: a Franka would report the wrench its
joint torques imply at K, which differs for a contact on a link; ``tau_ext_hat_filtered`` is exact).
Not the contact forces under the pad: the tool's sponge is a spring between them and the flange, and
MuJoCo's contact force on a pad sliding over a height field jumps from one step to the next (a step
without force, then one at nearly twice it) where the flange feels a smooth push. Sign as libfranka
documents it: the wrench the robot exerts on the environment is positive (``robot_state.h``: "Forces
applied by the robot to the environment are positive, while forces applied by the environment on the
robot are negative"), about the K frame's origin (``O_T_EE · EE_T_K``). ``TwinConfig.ext_wrench_on_robot``
flips it, for clients written the other way round. The state also carries libfranka's
``control_command_success_rate`` as the twin counts it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["contact_aware_robot_class", "tool_wrench_on_environment", "wrench_about_k"]

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


def tool_wrench_on_environment(force_flange_on_tool, moment_flange_on_tool, flange_m, load_mass_kg, load_com_m,
                               load_acc_m_s2):
    """The wrench the tool exerts on the environment as the robot's model sees it: (force [N], moment
    about the world origin [N·m]), each 3 floats, world frame.

    ``force_flange_on_tool`` / ``moment_flange_on_tool``: what the flange exerts on the tool (a wrist
    F/T sensor at the flange reads it), world frame, the moment about ``flange_m`` (the flange's origin,
    world [m]). The declared load (``load_mass_kg`` at ``load_com_m``, world [m]) moves with the flange:
    ``load_acc_m_s2`` is its centre of mass's acceleration less gravity (+9.81 m/s² up at rest, what an
    accelerometer reads), world. The load's balance, m·(a − g) = f_flange + f_environment, gives the
    force; the moment follows about the load's centre of mass. A rigid load: the sponge's own motion is
    not modelled, as the robot's model does not know it. Python floats, for the twin's 1 kHz tick."""
    fx, fy, fz = force_flange_on_tool
    ax, ay, az = load_acc_m_s2
    m = float(load_mass_kg)
    # the tool's force on the environment: minus the environment's on the tool
    ex, ey, ez = fx - m * ax, fy - m * ay, fz - m * az
    px, py, pz = flange_m
    cx, cy, cz = load_com_m
    lx, ly, lz = -m * ax, -m * ay, -m * az  # the load's inertial force (with its weight), at its centre of mass
    mx = moment_flange_on_tool[0] + (py * fz - pz * fy) + (cy * lz - cz * ly)
    my = moment_flange_on_tool[1] + (pz * fx - px * fz) + (cz * lx - cx * lz)
    mz = moment_flange_on_tool[2] + (px * fy - py * fx) + (cx * ly - cy * lx)
    return (ex, ey, ez), (mx, my, mz)


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
