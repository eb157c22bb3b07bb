"""VA-UFIC's controller driving its compiled tick (:mod:`tactex.control.va_ufic_tick`).

:class:`CompiledTick` belongs to one :class:`~tactex.control.va_ufic.VaUficController`. It packs
the controller's state (its UFIC filter and integrator, ρ_align, the offset and R_d, the
re-orientation, both tanks, the friction feed-forward) into one float64 vector, runs the compiled
tick on it every control period, and unpacks it into the Python objects when Python code asks for
them. While it runs (``live``) the vector holds the truth; the objects are brought up to date by
the controller's properties (``tank_i``, ``shaper``, ...) before anyone reads them.
"""

from __future__ import annotations

import math
import warnings
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any

import numpy as np

from tactex.control.friction import FrictionCompensator
from tactex.errors import ControllerFault, InputError

if TYPE_CHECKING:
    from tactex.control.references import PoseForceReference
    from tactex.control.state import RobotState

__all__ = ["CompiledTick"]

_NO_NORMAL = np.zeros(3)


class CompiledTick:
    """The compiled tick of one VA-UFIC controller (see the module docstring).

    ``ctrl`` is the :class:`~tactex.control.va_ufic.VaUficController` it belongs to, typed ``Any`` here:
    that module imports this one, and the tick reads the controller's own fields by name anyway.
    """

    def __init__(self, ctrl: Any, kernel, layout) -> None:
        self.ctrl = ctrl
        self.kernel = kernel
        self.m = layout  # the tick module: its S_*/P_* indices
        self.ks = np.zeros(layout.S_SIZE)
        self.kp = self._constants()
        self.f_world = np.zeros(6)
        self.d_view = self.ks[layout.S_D:layout.S_D + 6]  # D_C, as the joint-torque kernel takes it
        self.live = False
        self.state: RobotState | None = None  # the last tick's state (telemetry's kinetic energy)

    @classmethod
    def make(cls, ctrl: Any) -> CompiledTick | None:
        """The compiled tick for ``ctrl``, or None when it runs Python: no kernels (numba missing or
        disabled), or a port feed-forward other than :class:`FrictionCompensator` (the tick compiles
        that one only)."""
        kernels = ctrl._kernels
        if kernels is None or kernels.va_ufic_tick is None:
            return None
        ff = ctrl._port_feedforward
        if ff is not None and type(ff) is not FrictionCompensator:
            return None
        from tactex.control import va_ufic_tick

        return cls(ctrl, kernels.va_ufic_tick, va_ufic_tick)

    def _constants(self) -> np.ndarray:
        m, c = self.m, self.ctrl
        v, u = c.va, c.params
        kp = np.zeros(m.P_SIZE)
        kp[m.P_ALPHA], kp[m.P_XI], kp[m.P_GAMMA], kp[m.P_C_MARGIN] = v.alpha, v.xi, v.gamma, v.c_margin
        kp[m.P_RHO_MIN], kp[m.P_COMPLIANT], kp[m.P_DELTA_C] = v.rho_min, v.compliant_below, v.delta_c
        kp[m.P_REALIGN_T], kp[m.P_REALIGN_MIN] = v.realign_time, v.realign_min_angle
        kp[m.P_DAMP_FF] = float(v.damping_feedforward)
        kp[m.P_K_CONST:m.P_K_CONST + 6] = c._k_const
        kp[m.P_K_MAX_T:m.P_K_MAX_T + 6] = c._k_max_t
        kp[m.P_D_CONTACT:m.P_D_CONTACT + 6] = c._d_contact_f
        kp[m.P_D_FREE:m.P_D_FREE + 6] = c._d_free_f
        kp[m.P_CONTACT_N], kp[m.P_SWITCH_S], kp[m.P_TAU_W] = u.contact_threshold_n, u.damping_switch_s, c._tau_w
        kp[m.P_KP_F], kp[m.P_KI_F], kp[m.P_ILIM], kp[m.P_DT] = u.kp, u.ki, c._ilim, u.dt
        kp[m.P_AXES:m.P_AXES + 6] = c._axes_f
        for on, up, low, band, tank in ((m.P_TI_ON, m.P_TI_UP, m.P_TI_LOW, m.P_TI_BAND, c._tank_i),
                                        (m.P_TF_ON, m.P_TF_UP, m.P_TF_LOW, m.P_TF_BAND, c._tank_f)):
            kp[on], kp[up], kp[low], kp[band] = float(tank.enabled), tank.upper, tank.lower, tank.band
        kp[m.P_TF_LAM_BAND] = c._tank_f.lambda_band_w
        kp[m.P_HOLD] = v.tangent_hold
        kp[m.P_FOLLOW], kp[m.P_FOLLOW_TAU] = v.follow_planned_rate, v.follow_planned_tau
        ff = c._port_feedforward
        if ff is not None:
            p = ff.params
            kp[m.P_FR_ON], kp[m.P_FR_GAIN], kp[m.P_FR_CUTOFF] = 1.0, p.gain, p.cutoff_hz
            kp[m.P_FR_MU], kp[m.P_FR_MAX] = p.mu_max, p.max_force_n
        return kp

    # -- objects ↔ vector ---------------------------------------------------------------------------
    def pack(self) -> None:
        """The Python objects' state (and their settings, which set-up code may have changed) into
        the vector; the vector holds the truth from now on."""
        self.kp = self._constants()
        m, c, ks = self.m, self.ctrl, self.ks
        ks[m.S_T_PREV] = math.nan if c._t_prev is None else c._t_prev
        ks[m.S_W_OK] = float(c._w_filt is not None)
        ks[m.S_W:m.S_W + 6] = c._w_filt if c._w_filt is not None else 0.0
        ks[m.S_INTEG:m.S_INTEG + 6] = c._integral
        ks[m.S_D:m.S_D + 6] = c._d_tool_f
        ks[m.S_RHO] = c._shaper.rho
        ks[m.S_OFFSET:m.S_OFFSET + 3] = c._offset
        ks[m.S_ANCHOR_OK] = float(c._anchor is not None)
        ks[m.S_ANCHOR:m.S_ANCHOR + 3] = c._anchor if c._anchor is not None else 0.0
        ks[m.S_ROT_D_OK] = float(c._rot_d is not None)
        ks[m.S_ROT_D:m.S_ROT_D + 9] = np.ravel(c._rot_d) if c._rot_d is not None else 0.0
        ks[m.S_RE_ON] = float(c._realign is not None)
        if c._realign is not None:
            t0, r_init, w = c._realign
            ks[m.S_RE_T0] = t0
            ks[m.S_RE_INIT:m.S_RE_INIT + 9] = np.ravel(r_init)
            ks[m.S_RE_LOG:m.S_RE_LOG + 3] = w
        for b, tank in ((m.S_TANK_I, c._tank_i), (m.S_TANK_F, c._tank_f)):
            ks[b + m.T_ENERGY], ks[b + m.T_DELIVERED] = tank.energy, tank.delivered
            ks[b + m.T_HARVESTED] = tank.harvested
            ks[b + m.T_HAS_LAST] = float(tank._last is not None)
            ks[b + m.T_LAST:b + m.T_LAST + 7] = tank._last if tank._last is not None else 0.0
        ks[m.S_TANK_F + m.T_DAMP_HARVESTED] = c._tank_f.damping_harvested_w
        ff = c._port_feedforward
        if ff is not None:
            f = m.S_FRIC
            ks[f:f + 2] = ff._f
            ks[f + 2], ks[f + 3], ks[f + 4] = float(ff._started), ff._a, ff._a_dt
            ks[f + 5:f + 11] = ff._last
        ks[m.S_RAW_OK] = float(c._raw is not None)
        if c._raw is not None:
            raw = c._raw
            ks[m.S_RAW:m.S_RAW + 10] = [raw[0], raw[1], raw[2], raw[3], raw[4], raw[5], float(raw[6]), raw[7], raw[8],
                                        raw[9]]
            ks[m.S_RAW + 10:m.S_RAW + 16] = raw[10]
            self.state = raw[11]
        c._d_tool = self.d_view
        self._packed = self._held_values()
        self.live = True

    def _held_values(self) -> tuple:
        """What code holding a tank, the shaper or the friction feed-forward could have written."""
        c = self.ctrl
        ff = c._port_feedforward
        return (c._tank_i.energy, c._tank_i.delivered, c._tank_i.harvested, c._tank_f.energy, c._tank_f.delivered,
                c._tank_f.harvested, c._shaper.rho, None if ff is None else ff._f)

    def unpack(self) -> None:
        """The vector back into the Python objects; they hold the truth from now on."""
        if self._held_values() != self._packed:
            warnings.warn("a VA-UFIC tank, shaper or friction feed-forward held from before was written while the "
                          "compiled tick ran: that write is lost. Read them through the controller's properties "
                          "(ctrl.tank_i, ...) each time, not through a reference kept across ticks",
                          RuntimeWarning, stacklevel=4)
        m, c = self.m, self.ctrl
        ks = self.ks.tolist()
        c._t_prev = None if math.isnan(ks[m.S_T_PREV]) else ks[m.S_T_PREV]
        c._w_filt = ks[m.S_W:m.S_W + 6] if ks[m.S_W_OK] else None
        c._integral = ks[m.S_INTEG:m.S_INTEG + 6]
        c._d_tool_f = tuple(ks[m.S_D:m.S_D + 6])
        c._d_tool = np.array(c._d_tool_f)
        c._shaper.rho = ks[m.S_RHO]
        c._offset = tuple(ks[m.S_OFFSET:m.S_OFFSET + 3])
        c._anchor = tuple(ks[m.S_ANCHOR:m.S_ANCHOR + 3]) if ks[m.S_ANCHOR_OK] else None
        rows = ks[m.S_ROT_D:m.S_ROT_D + 9]
        c._rot_d = [rows[0:3], rows[3:6], rows[6:9]] if ks[m.S_ROT_D_OK] else None
        if ks[m.S_RE_ON]:
            r_init = ks[m.S_RE_INIT:m.S_RE_INIT + 9]
            c._realign = (ks[m.S_RE_T0], [r_init[0:3], r_init[3:6], r_init[6:9]], tuple(ks[m.S_RE_LOG:m.S_RE_LOG + 3]))
        else:
            c._realign = None
        for b, tank in ((m.S_TANK_I, c._tank_i), (m.S_TANK_F, c._tank_f)):
            tank.energy, tank.delivered = ks[b + m.T_ENERGY], ks[b + m.T_DELIVERED]
            tank.harvested = ks[b + m.T_HARVESTED]
            tank._last = tuple(ks[b + m.T_LAST:b + m.T_LAST + 7]) if ks[b + m.T_HAS_LAST] else None
        c._tank_f.damping_harvested_w = ks[m.S_TANK_F + m.T_DAMP_HARVESTED]
        ff = c._port_feedforward
        if ff is not None:
            f = m.S_FRIC
            ff._f = (ks[f], ks[f + 1])
            ff._started, ff._a, ff._a_dt = bool(ks[f + 2]), ks[f + 3], ks[f + 4]
            ff._last = tuple(ks[f + 5:f + 11])
        c._raw = self._raw(ks) if ks[m.S_RAW_OK] else None
        self.live = False

    def _raw(self, ks: list[float]) -> tuple:
        r = self.m.S_RAW
        return (*ks[r:r + 6], bool(ks[r + 6]), ks[r + 7], ks[r + 8], ks[r + 9], tuple(ks[r + 10:r + 16]), self.state)

    # -- the tick -----------------------------------------------------------------------------------
    def torque(self, state: RobotState, reference: PoseForceReference) -> np.ndarray | None:
        """The joint torque [N·m] of one tick; None (warned) when the kernel cannot take the arrays."""
        if not self.live:
            self.pack()
        est = reference.surface
        if est is None or not est.valid or not (0.0 <= state.t - est.timestamp <= self.ctrl.va.surface_max_age):
            ok, normal, curvature = 0.0, _NO_NORMAL, 0.0
        else:
            ok, normal, curvature = (2.0 if est.planned else 1.0), est.normal_world, est.curvature
        try:
            code = self.kernel(self.ks, self.kp, state.t, state.ee_rotation, state.ee_position, state.ee_twist,
                               state.wrench_tool, reference.position_world, reference.rotation_world,
                               reference.wrench_tool, reference.twist_world, ok, normal, curvature, self.f_world)
        except TypeError as exc:  # arrays of another dtype: nothing has changed yet
            warnings.warn(f"VA-UFIC's compiled tick cannot take these arrays ({exc}); this controller runs its "
                          "Python tick from now on", RuntimeWarning, stacklevel=3)
            self.unpack()
            return None
        if code == self.m.FAULT_ROTATION:
            raise InputError(f"rot_current must be a finite 3×3 rotation matrix, got {state.ee_rotation!r}")
        if code:
            raise ControllerFault(self._fault(code, state))
        self.state = state
        return self.ctrl.joint_torque(state, self.f_world)

    def _fault(self, code: int, state: RobotState) -> str:
        m = self.m
        if code == m.FAULT_FRICTION_FORCE:
            return f"friction compensation got a non-finite measured force {state.wrench_tool[:3]!r}"
        if code == m.FAULT_FRICTION_RHO:
            return f"friction compensation needs ρ_align in [0, 1], got {self.ks[m.S_RHO]!r}"
        return "friction compensation needs a tick period dt > 0 [s]"

    # -- reads without leaving the vector -----------------------------------------------------------
    def tick_telemetry(self) -> dict[str, float]:
        m, ks = self.m, self.ks
        if not ks[m.S_RAW_OK]:
            return {}
        r = m.S_RAW
        return {"rho_align": float(ks[r]), "rho_frc": float(ks[r + 1]), "tank_i_valve": float(ks[r + 7]),
                "tank_i_energy_j": float(ks[m.S_TANK_I]), "tank_f_energy_j": float(ks[m.S_TANK_F])}

    def rotation_desired(self) -> np.ndarray | None:
        m = self.m
        return self.ks[m.S_ROT_D:m.S_ROT_D + 9].reshape(3, 3).copy() if self.ks[m.S_ROT_D_OK] else None

    def position_offset(self) -> np.ndarray:
        return self.ks[self.m.S_OFFSET:self.m.S_OFFSET + 3].copy()

    def port_wrench_last(self) -> np.ndarray | None:
        if not self.kp[self.m.P_FR_ON]:
            return None
        f = self.m.S_FRIC
        return self.ks[f + 5:f + 11].copy()

    def snapshot(self) -> tuple[tuple | None, SimpleNamespace, SimpleNamespace, bool]:
        """(raw values as VaUficController._raw, impedance tank, force tank, re-orienting) read from
        the vector, for telemetry at the recording rate without unpacking."""
        m = self.m
        ks = self.ks.tolist()
        raw = self._raw(ks) if ks[m.S_RAW_OK] else None
        tanks = []
        for b in (m.S_TANK_I, m.S_TANK_F):
            e = ks[b + m.T_ENERGY]
            tanks.append(SimpleNamespace(energy=e, state=math.sqrt(max(2.0 * e, 0.0)), delivered=ks[b + m.T_DELIVERED],
                                         harvested=ks[b + m.T_HARVESTED]))
        return raw, tanks[0], tanks[1], bool(ks[m.S_RE_ON])
