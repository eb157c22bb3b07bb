"""Vision-augmented unified force-impedance control with energy tanks (VA-UFIC §II-B/C).

Per tick:
1. pose error x̃ (world) and x̃^ee (tool frame) against the effective desired pose;
2. contact-alignment monitor C (eq. 17) from the tactile error f_extᵀx̃, the orientation error θ
   and the curvature l_s of the latest :class:`SurfaceEstimate`; h = 1 − C/C_m (eq. 18);
3. ρ_align dynamics (eq. 20–21); K_C,t = ρ_align R K_max,t Rᵀ (eq. 19);
4. while ρ_align ≈ 0 (below ``compliant_below``) the actual translation is fed back as the
   desired one (the motion policy is shifted to where the tool is), and if the camera sees the
   surface tilted w.r.t. the tool a re-orientation to the surface normal starts (eq. 22–27),
   interpolated over T (eq. 28–29); the energy that moving R_d puts into the constant rotational
   spring is paid from the impedance tank (R_d waits while the tank cannot pay), so eq. 64's storage
   stays a storage. Once aligned, R_d turns toward a *planned* normal (a re-plan's explored surface,
   ``SurfaceEstimate.planned``) at ``follow_planned_rate`` at most, paid the same way.
   In contact the tool's tangent plane (tool x, y) keeps a stiffness of at least ``tangent_hold``·K_max:
   while compliant a spring to where the tool touched down, above it a floor under ρ_align K_max
   (see ``tangent_hold``; 0 gives the paper's law);
5. force shaping ρ_frc (eq. 30) with margin δ_c;
6. energy tanks (eq. 37–45, 55–63) and the final law eq. 72–73:
   f = −K_const x̃ − D ẋ + σ_i (−ρ_align K_max x̃ + D ẋ_d) + ρ_frc (λ + σ_f (1−λ)) f_f,  τ = Jᵀ f,
   (with the tangential hold of step 4 in the variable spring's place on tool x, y),
   where the damping feed-forward D ẋ_d (``damping_feedforward``, on by default; eq. 8 has none)
   shares the impedance tank's port with the variable spring, as does any extra active wrench of
   a ``port_feedforward`` (e.g. :class:`tactex.control.friction.FrictionCompensator`; none by
   default, the wiping task turns it on), and the tangential hold: the tank pays for whatever is
   added there.

Where the other equations live: eq. 1–2 and 13 are the torque interface (gravity added by the
robot), eq. 7–12 :mod:`tactex.control.ufic`, eq. 14–16 :mod:`tactex.perception` (θ is re-evaluated
here against the current tool axis), eq. 17–21 and 30 :mod:`tactex.control.alignment`, eq. 37–45
and 55–63 :mod:`tactex.control.energy_tank`. The storage functions of the passivity analysis —
S_r = ½ẋᵀM_Cẋ = ½q̇ᵀMq̇ (eq. 32, with M_C of eq. 3–6), the springs ½x̃ᵀK x̃ (eq. 34, 52, 64) and
S_overall (eq. 46, 69) — are reported by :meth:`VaUficController.telemetry` for the energy logs;
their derivatives (eq. 33–36, 47–50, 53–54, 65–71) are what the tank tests check step by step.

The two tanks harvest the damping dissipation once between them (force tank first), not twice
as eq. 39 and 57 literally do; see :mod:`tactex.control.energy_tank`.

A missing, invalid or stale estimate (older than ``surface_max_age``) contributes θ = l_s = 0 and
never triggers a re-orientation: the controller then runs on touch alone.

Convention: ``SurfaceEstimate.normal_world`` points out of the surface (to the camera); the paper's
n_s is the direction the tool z-axis should take, so r'_z = −normal_world.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from tactex.config import param
from tactex.control.alignment import AlignmentShaper, alignment_coefficient, contact_alignment, force_shaping
from tactex.control.energy_tank import ForceTank, ImpedanceTank
from tactex.control.references import PoseForceReference
from tactex.control.state import RobotState
from tactex.control.ufic import UficController, UficParams
from tactex.control.va_ufic_compiled import CompiledTick
from tactex.errors import ConfigError, ControllerFault, InputError
from tactex.geometry.so3 import exp_so3_rows, log_so3, log_so3_rows, matmul3_rows, matmul3_tn_rows
from tactex.perception.estimate import SurfaceEstimate

__all__ = ["TANK_F_LAMBDA_BAND_W", "PortFeedforward", "VaUficController", "VaUficParams",
           "desired_rotation_from_normal"]

#: The force tank's λ ramp [W] (:class:`~tactex.control.energy_tank.ForceTank`): 15 N at 2 cm/s.
TANK_F_LAMBDA_BAND_W = 0.3


@dataclass(frozen=True)
class VaUficParams:
    """VA-UFIC Table I defaults; the UFIC gains live in ``ufic``."""

    ufic: UficParams = field(default_factory=UficParams, metadata={"cli": False})
    c_margin: float = param(0.9, "contact alignment margin C_m [-]")
    alpha: float = param(1.0, "signal strength of the tactile error α [1/(N·m)]")
    xi: float = param(0.08, "signal strength of the orientation error ξ [1/rad]")
    gamma: float = param(10.0, "signal strength of the curvature γ [-]")
    rho_min: float = param(0.001, "ρ_min of eq. 21 [1/s]")
    rho_align_initial: float = param(0.0, "ρ_align(0) (the paper starts compliant: 0) [-]")
    delta_c: float = param(0.04, "force-shaping margin δ_c [m]")
    compliant_below: float = param(
        0.01,
        "ρ_align under which the robot counts as fully compliant (the paper's ρ_align = 0): with ρ_min > 0, "
        "eq. 20–21 settle at −ρ_min/h > 0 when misaligned and never reach 0 exactly [-]",
    )
    tangent_hold: float = param(
        0.5,
        "share of K_max,t kept in the tool's tangent plane (x, y) while in contact (f_z ≥ the UFIC contact "
        "threshold), whatever ρ_align: pressing f_d on a convex part of radius r acts on the tool as a tangential "
        "stiffness of −f_d/r (−375 N/m at 15 N on a 4 cm cup), which the paper's compliance (ρ_align ≈ 0, the "
        "position fed back) leaves unopposed, so the tool rolls round the part and off it. While compliant it is a "
        "spring to where the tool touched down; above, a floor under ρ_align. Both through the impedance tank's "
        "port. 0: the paper's law [-]",
    )
    follow_planned_rate: float = param(
        0.4,
        "while aligned (ρ_align above compliant_below), R_d turns toward a planned surface normal (SurfaceEstimate."
        "planned: a re-plan's explored surface, not the camera) at most this fast, once the tilt passes half of "
        "realign_min_angle, paid from the impedance tank; the paper re-orients only while compliant, so on a curved "
        "part the aligned tool keeps its orientation while the surface turns under it (tens of degrees on a bowl's "
        "wall). "
        "0: never [rad/s]",
    )
    follow_planned_tau: float = param(
        0.35,
        "time constant of the planned turn: below follow_planned_rate × it of tilt the turn's rate is the tilt over "
        "it, a first-order approach, so that the small corrections a gently curved part asks for do not jerk the "
        "pressed tool; 0: always at follow_planned_rate [s]",
    )
    stiffness_const: tuple[float, float, float, float, float, float] = param(
        (0.0, 0.0, 0.0, 200.0, 200.0, 200.0),
        "K_const, tool frame (eq. 56); the rotational part of K_max is kept constant (eq. 19 shapes "
        "only the translation) [N/m ×3, N·m/rad ×3]",
    )
    realign_time: float = param(1.0, "T of eq. 28, duration of a re-orientation [s]")
    realign_min_angle: float = param(math.radians(2.0), "smallest tilt that triggers a re-orientation [rad]")
    surface_max_age: float = param(0.5, "older surface estimates are ignored [s]")
    damping_feedforward: bool = param(
        True,
        "damp the velocity error D(ẋ − ẋ_d) instead of eq. 8's D ẋ; the feed-forward D ẋ_d goes through the "
        "impedance tank's port with the variable spring, so the tank pays for the energy it injects",
    )
    tanks_enabled: bool = param(True, "energy tanks on (False: plain VA-UFIC, for the passivity comparison)")
    tank_i_x0: float = param(7.0, "x_t,i(0) [√J]")
    tank_i_upper: float = param(32.0, "S̄_t,i [J]")
    tank_i_lower: float = param(1.0, "S_t,i lower limit [J]")
    tank_f_x0: float = param(2.0, "x_t,f(0) [√J]")
    tank_f_upper: float = param(2.0, "S̄_t,f [J]")
    tank_f_lower: float = param(1.0, "S_t,f lower limit [J]")
    tank_f_lambda_band_w: float = param(
        TANK_F_LAMBDA_BAND_W, "eq. 38's switch λ ramps from 1 to 0 as ẋᵀf_f rises from −band to 0 (the paper steps "
        "it at 0, which bangs a drained tank's force on and off tick to tick; tactex.control.energy_tank) [W]")

    def __post_init__(self) -> None:
        for name in ("c_margin", "delta_c", "realign_time"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise ConfigError(f"VaUficParams.{name} must be finite and > 0, got {v!r}")
        for name in ("alpha", "xi", "gamma", "rho_min", "realign_min_angle", "surface_max_age", "compliant_below",
                     "tangent_hold", "follow_planned_rate", "follow_planned_tau"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ConfigError(f"VaUficParams.{name} must be finite and ≥ 0, got {v!r}")
        if not 0.0 <= self.rho_align_initial <= 1.0:
            raise ConfigError(f"VaUficParams.rho_align_initial must be in [0, 1], got {self.rho_align_initial!r}")
        k = np.asarray(self.stiffness_const, dtype=float)
        if k.shape != (6,) or not np.isfinite(k).all() or (k < 0).any():
            raise ConfigError(f"VaUficParams.stiffness_const must be 6 finite values ≥ 0, got {self.stiffness_const!r}")


def desired_rotation_from_normal(rot_current: np.ndarray, tool_z_world: np.ndarray) -> np.ndarray:
    """Eq. 23–27: keep the current x-axis projected on the plane ⟂ r'_z, r'_y = r'_z × r'_x.

    Args:
        rot_current: (3, 3) current orientation world_R_tool.
        tool_z_world: (3,) direction the tool z-axis should take (any length > 0).
    """
    tool_z_world = np.asarray(tool_z_world, dtype=float)
    rot_current = np.asarray(rot_current, dtype=float)
    if rot_current.shape != (3, 3) or not np.isfinite(rot_current).all():
        raise InputError(f"rot_current must be a finite 3×3 rotation matrix, got {rot_current!r}")
    norm_z = float(np.linalg.norm(tool_z_world)) if tool_z_world.shape == (3,) else float("nan")
    if not (np.isfinite(norm_z) and norm_z > 1e-12):
        raise InputError(f"tool_z_world must be a finite, non-zero 3-vector, got {tool_z_world!r}")
    rz = tool_z_world / norm_z
    rx = rot_current[:, 0] - float(rot_current[:, 0] @ rz) * rz
    n = float(np.linalg.norm(rx))
    if n < 1e-6:  # current x-axis along the normal: fall back to the current y-axis
        rx = rot_current[:, 1] - float(rot_current[:, 1] @ rz) * rz
        rx = np.cross(rx, rz)
        n = float(np.linalg.norm(rx))
    rx = rx / n
    return np.column_stack([rx, np.cross(rz, rx), rz])


def _tilt(rows: list[list[float]], z: tuple[float, float, float]) -> float:
    """The angle [rad] between the z axis of the rotation given as ``rows`` (Python floats) and the unit
    vector ``z``; the cosine clamped to [−1, 1] as the compiled tick clamps it, NaN included."""
    cos_tilt = rows[0][2] * z[0] + rows[1][2] * z[1] + rows[2][2] * z[2]
    cos_tilt = cos_tilt if cos_tilt < 1.0 else 1.0
    cos_tilt = cos_tilt if cos_tilt > -1.0 else -1.0
    return math.acos(cos_tilt)


class PortFeedforward(Protocol):
    """An extra active tool-frame wrench [N, N·m] that VA-UFIC applies through the impedance tank's
    port (so the tank pays for it), e.g. :class:`tactex.control.friction.FrictionCompensator`;
    ``wrench_tool`` returns six numbers (a sequence of floats or a (6,) array)."""

    def reset(self) -> None: ...

    def wrench_tool(self, state: RobotState, rho_align: float, dt: float) -> Sequence[float] | np.ndarray: ...


class VaUficController(UficController):
    """VA-UFIC (eq. 1–73). Reference: :class:`PoseForceReference` whose ``surface`` carries the
    latest :class:`SurfaceEstimate` (or None).

    With the ``fast`` extra the tick runs compiled (:mod:`tactex.control.va_ufic_tick`, driven by
    :class:`~tactex.control.va_ufic_compiled.CompiledTick`); the Python tick below is the reference,
    and runs without numba or with a ``port_feedforward`` other than
    :class:`~tactex.control.friction.FrictionCompensator`."""

    name = "va_ufic"

    def __init__(self, params: VaUficParams | None = None, port_feedforward: PortFeedforward | None = None) -> None:
        self.va = params or VaUficParams()
        super().__init__(self.va.ufic)
        v = self.va
        self._shaper = AlignmentShaper(v.rho_min, v.rho_align_initial)
        self._tank_i = ImpedanceTank(v.tank_i_x0, v.tank_i_upper, v.tank_i_lower, enabled=v.tanks_enabled)
        self._tank_f = ForceTank(v.tank_f_x0, v.tank_f_upper, v.tank_f_lower, enabled=v.tanks_enabled,
                                 lambda_band_w=v.tank_f_lambda_band_w)
        self._k_const = np.asarray(v.stiffness_const, dtype=float)
        self._k_max_t = np.concatenate([self._k_max[:3], np.zeros(3)])
        self._neg_k_const_f = tuple((-self._k_const).tolist())  # the same gains as Python floats (hot path)
        self._k_max_t_f = tuple(self._k_max_t.tolist())
        self._offset = (0.0, 0.0, 0.0)
        # where the tool touched down while compliant (world [m]): the tangential hold's anchor; None out of it
        self._anchor: tuple[float, float, float] | None = None
        # R_d and R_init as rows of Python floats (see tactex.geometry.so3: the re-orienting tick is
        # cheaper on floats than with numpy 3×3 products)
        self._rot_d: list[list[float]] | None = None
        self._realign: tuple[float, list, tuple[float, float, float]] | None = None  # (t0, R_init, log(R_d R_initᵀ))
        self._raw: tuple | None = None
        self._port_feedforward = port_feedforward
        self._compiled = CompiledTick.make(self)  # None: the Python tick below

    # The objects holding the tick's state (tanks, ρ_align's integrator, the friction feed-forward).
    # With the compiled tick their values live in its state vector between ticks: reading one of
    # these properties brings them back first (tests and set-up code read them; the loop does not).
    @property
    def tank_i(self) -> ImpedanceTank:
        """The impedance tank, up to date now; read it through this property each time (a reference
        kept across ticks of the compiled tick goes stale, and writes to it are lost, with a warning)."""
        self._objects()
        return self._tank_i

    @property
    def tank_f(self) -> ForceTank:
        """The force tank (as :attr:`tank_i`)."""
        self._objects()
        return self._tank_f

    @property
    def shaper(self) -> AlignmentShaper:
        """ρ_align's integrator (as :attr:`tank_i`)."""
        self._objects()
        return self._shaper

    @property
    def port_feedforward(self) -> PortFeedforward | None:
        """The port feed-forward (as :attr:`tank_i`)."""
        self._objects()
        return self._port_feedforward

    def __getstate__(self) -> dict:
        # the compiled tick holds a view of its vector and the tick module: rebuilt on unpickling
        self._objects()
        state = self.__dict__.copy()
        state["_compiled"] = self._compiled is not None
        return state

    def __setstate__(self, state: dict) -> None:
        compiled = state.pop("_compiled")
        self.__dict__.update(state)
        self._compiled = None
        if compiled:
            self._compiled = CompiledTick.make(self)

    @property
    def _live(self) -> CompiledTick | None:
        """The compiled tick while its vector holds the state, else None."""
        tick = self._compiled
        return tick if tick is not None and tick.live else None

    def _objects(self) -> None:
        """The compiled tick's state back into the Python objects (a no-op when they hold it)."""
        if (tick := self._live) is not None:
            tick.unpack()

    def reset(self, state: RobotState) -> None:
        self.resume(state)
        self._tank_i.reset()
        self._tank_f.reset()
        self._rot_d = None  # taken from the reference at the next tick

    def resume(self, state: RobotState) -> None:
        """:meth:`reset` except what holds energy: the tanks (energy and ledgers) and the desired
        orientation R_d the vision moved the constant rotational spring to (re-reading the reference
        would swing that spring by the whole re-orientation, unpaid). A re-orientation under way stops
        where it is."""
        self._objects()
        super().reset(state)
        if self._port_feedforward is not None:
            self._port_feedforward.reset()
        self._shaper.reset()
        self._offset = (0.0, 0.0, 0.0)
        self._anchor = None
        self._realign = None
        self._raw = None

    def _surface(self, state: RobotState, est: SurfaceEstimate | None, rl: list[list[float]]
                 ) -> tuple[bool, float, float, tuple[float, float, float] | None]:
        """(usable, θ [rad], l_s, desired tool z in the world) from the latest estimate; ``rl`` is the
        tool rotation R as nested Python floats."""
        if est is None or not est.valid or not (0.0 <= state.t - est.timestamp <= self.va.surface_max_age):
            return False, 0.0, 0.0, None
        nx, ny, nz = est.normal_world.tolist()
        ls = float(est.curvature)
        norm = math.sqrt(nx * nx + ny * ny + nz * nz)
        if not (math.isfinite(norm) and math.isfinite(ls)) or norm < 1e-9:
            return False, 0.0, 0.0, None
        z_des = (-nx / norm, -ny / norm, -nz / norm)
        cos_t = rl[0][2] * z_des[0] + rl[1][2] * z_des[1] + rl[2][2] * z_des[2]
        theta = math.acos(max(-1.0, min(1.0, cos_t)))  # eq. 15, now
        return True, theta, ls, z_des

    def _rotational_spring_energy(self, rot_d: list[list[float]], rl: list[list[float]]) -> float:
        """½ x̃ᵀK_const x̃ of the rotational part [J] for desired rows ``rot_d`` and tool rows ``rl``."""
        e3, e4, e5 = log_so3_rows(matmul3_tn_rows(rot_d, rl))
        _, _, _, k3, k4, k5 = self._neg_k_const_f
        return -0.5 * (k3 * e3 * e3 + k4 * e4 * e4 + k5 * e5 * e5)

    def _advance_realign(self, t: float, dt: float, rl: list[list[float]]) -> None:
        """Move R_d along the re-orientation (eq. 28–29), paying the energy the move puts into the
        constant rotational spring from the impedance tank.

        The passivity argument (eq. 64) stores ½x̃ᵀK_const x̃ for a fixed set point; moving R_d changes
        that storage with nothing paying for it (up to ~0.9 J per re-orientation at the defaults).
        So each tick the tank pays the increase at the current pose; when it cannot, R_d waits (the
        interpolation is shifted by dt) until the tank has harvested enough. A move that releases
        spring energy costs nothing."""
        t0, r_init, (lx, ly, lz) = self._realign
        zeta = (t - t0) / self.va.realign_time
        zeta = zeta if zeta < 1.0 else 1.0  # min(1, ·)
        rot_new = matmul3_rows(exp_so3_rows(zeta * lx, zeta * ly, zeta * lz), r_init)
        cost = self._rotational_spring_energy(rot_new, rl) - self._rotational_spring_energy(self._rot_d, rl)
        if cost > 0.0 and not self._tank_i.withdraw(cost):
            self._realign = (t0 + dt, r_init, (lx, ly, lz))
            return
        self._rot_d = rot_new
        if zeta >= 1.0:
            self._realign = None

    def _follow_planned(self, z_des: tuple[float, float, float], dt: float, rl: list[list[float]]) -> None:
        """Turn R_d toward the planned inward normal ``z_des`` at min(follow_planned_rate, tilt / follow_planned_tau),
        paying the constant rotational spring's extra energy from the impedance tank (no turn while it cannot pay)."""
        rd = self._rot_d
        if _tilt(rd, z_des) < 0.5 * self.va.realign_min_angle:
            return
        rd_np = np.array(rd)
        wx, wy, wz = log_so3(desired_rotation_from_normal(rd_np, np.array(z_des)) @ rd_np.T).tolist()
        angle = math.sqrt(wx * wx + wy * wy + wz * wz)
        rate, tau = self.va.follow_planned_rate, self.va.follow_planned_tau
        if tau > 0.0 and angle < rate * tau:
            rate = angle / tau
        step = rate * dt / angle if angle > 1e-12 else 1.0
        step = step if step < 1.0 else 1.0
        rot_new = matmul3_rows(exp_so3_rows(step * wx, step * wy, step * wz), rd)
        cost = self._rotational_spring_energy(rot_new, rl) - self._rotational_spring_energy(rd, rl)
        if cost > 0.0 and not self._tank_i.withdraw(cost):
            return
        self._rot_d = rot_new

    def torque(self, state: RobotState, reference: PoseForceReference) -> np.ndarray:
        if not isinstance(reference, PoseForceReference):
            raise ControllerFault(f"{self.name} needs a PoseForceReference, got {type(reference).__name__}")
        if self._compiled is not None:
            tau = self._compiled.torque(state, reference)
            if tau is not None:
                return tau
            self._compiled = None  # it could not take these arrays: Python from now on (warned)
        # The whole tick runs on Python floats, 6-vectors unpacked into locals: at 1 kHz a numpy call on
        # a 3- or 6-vector, a list comprehension or a zip costs more than the float operations it replaces.
        v = self.va
        dt = self._dt(state)
        rot = state.ee_rotation
        rl = rot.tolist()
        if self._rot_d is None:
            self._rot_d = reference.rotation_world.tolist()
        if self._realign is not None:  # eq. 28–29: (R_d R_initᵀ)^ζ R_init = exp(ζ·log(R_d R_initᵀ)) R_init
            self._advance_realign(state.t, dt, rl)

        # x̃^ee: Rᵀ(x − x_d) and Rᵀlog(R R_dᵀ) = log(R_dᵀR) (the adjoint of a rotation on its own log)
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rl
        px, py, pz = state.ee_position.tolist()
        dx, dy, dz = reference.position_world.tolist()
        ox, oy, oz = self._offset
        ex, ey, ez = px - dx - ox, py - dy - oy, pz - dz - oz
        e0, e1, e2 = r00 * ex + r10 * ey + r20 * ez, r01 * ex + r11 * ey + r21 * ez, r02 * ex + r12 * ey + r22 * ez
        e3, e4, e5 = log_so3_rows(matmul3_tn_rows(self._rot_d, rl))
        usable, theta, ls, z_des = self._surface(state, reference.surface, rl)

        wm = self._wrench_filtered(state, dt)
        c = contact_alignment(wm, (e0, e1, e2, e3, e4, e5), theta, ls, v.alpha, v.xi, v.gamma)  # eq. 17
        h = alignment_coefficient(c, v.c_margin)  # eq. 18
        rho_align = self._shaper.step(h, dt)  # eq. 20–21

        # the tangential hold (tangent_hold): in contact, a spring to the touch-down point while compliant
        hold = v.tangent_hold if wm[2] >= self.params.contact_threshold_n else 0.0
        a0 = a1 = 0.0
        if rho_align <= v.compliant_below and hold > 0.0:
            if self._anchor is None:
                self._anchor = (px, py, pz)
            qx, qy, qz = px - self._anchor[0], py - self._anchor[1], pz - self._anchor[2]
            a0 = -hold * self._k_max_t_f[0] * (r00 * qx + r10 * qy + r20 * qz)
            a1 = -hold * self._k_max_t_f[1] * (r01 * qx + r11 * qy + r21 * qz)
        else:
            self._anchor = None

        if rho_align <= v.compliant_below:  # fully compliant: feed the actual translation back as desired
            self._offset = (px - dx, py - dy, pz - dz)
            e0 = e1 = e2 = 0.0
            if usable and self._realign is None:
                rd = self._rot_d
                if _tilt(rd, z_des) > v.realign_min_angle:  # eq. 22–27 (once per re-orientation: numpy is fine here)
                    r_goal = desired_rotation_from_normal(rot, np.array(z_des))
                    w_goal = log_so3(r_goal @ np.array(rd).T).tolist()
                    self._realign = (state.t, rd, (w_goal[0], w_goal[1], w_goal[2]))
        elif (usable and v.follow_planned_rate > 0.0 and self._realign is None and reference.surface is not None
              and reference.surface.planned):
            self._follow_planned(z_des, dt, rl)
        e = (e0, e1, e2, e3, e4, e5)

        wd = reference.wrench_tool.tolist()
        rho_frc = force_shaping(wd, e, v.delta_c)  # eq. 30
        # Gains are diagonal in the tool frame (eq. 19: K_C,t = ρ R K_max,t Rᵀ), so every product is
        # taken there; the powers ẋᵀ(·) are frame-independent. Twists to the tool frame: Rᵀv, Rᵀω.
        vx, vy, vz, wx, wy, wz = state.ee_twist.tolist()
        x0, x1, x2 = r00 * vx + r10 * vy + r20 * vz, r01 * vx + r11 * vy + r21 * vz, r02 * vx + r12 * vy + r22 * vz
        x3, x4, x5 = r00 * wx + r10 * wy + r20 * wz, r01 * wx + r11 * wy + r21 * wz, r02 * wx + r12 * wy + r22 * wz
        self._select_damping(wm[2], dt)
        d0, d1, d2, d3, d4, d5 = self._d_tool_f
        dx0, dx1, dx2, dx3, dx4, dx5 = d0 * x0, d1 * x1, d2 * x2, d3 * x3, d4 * x4, d5 * x5  # D ẋ
        f0, f1, f2, f3, f4, f5 = self.force_wrench_tool(state, wd, dt, rho_frc > 1e-3, wm)
        f0, f1, f2, f3, f4, f5 = rho_frc * f0, rho_frc * f1, rho_frc * f2, rho_frc * f3, rho_frc * f4, rho_frc * f5

        # Tracking a moving x_d, eq. 8's −D ẋ lags by D·v/K (6 mm at the policy's 8 cm/s). With
        # damping_feedforward the damping acts on the velocity error; its active part +D ẋ_d joins the
        # variable spring at the impedance tank's port (both are non-passive), so σ_i scales both.
        neg_rho = -rho_align
        neg_t = -hold if rho_align < hold else neg_rho  # the hold's floor in the tangent plane
        k0, k1, k2, k3, k4, k5 = self._k_max_t_f
        port = [neg_t * k0 * e0 + a0, neg_t * k1 * e1 + a1, neg_rho * k2 * e2,  # −K_var(t)·x̃, eq. 56
                neg_rho * k3 * e3, neg_rho * k4 * e4, neg_rho * k5 * e5]
        if v.damping_feedforward:
            ux, uy, uz, qx, qy, qz = reference.twist_world.tolist()
            port[0] += d0 * (r00 * ux + r10 * uy + r20 * uz)
            port[1] += d1 * (r01 * ux + r11 * uy + r21 * uz)
            port[2] += d2 * (r02 * ux + r12 * uy + r22 * uz)
            port[3] += d3 * (r00 * qx + r10 * qy + r20 * qz)
            port[4] += d4 * (r01 * qx + r11 * qy + r21 * qz)
            port[5] += d5 * (r02 * qx + r12 * qy + r22 * qz)
        p0, p1, p2, p3, p4, p5 = port
        if self._port_feedforward is not None:
            w = self._port_feedforward.wrench_tool(state, rho_align, dt)
            w0, w1, w2, w3, w4, w5 = w.tolist() if isinstance(w, np.ndarray) else w
            p0, p1, p2, p3, p4, p5 = p0 + w0, p1 + w1, p2 + w2, p3 + w3, p4 + w4, p5 + w5
        p_damp = x0 * dx0 + x1 * dx1 + x2 * dx2 + x3 * dx3 + x4 * dx4 + x5 * dx5
        p_force = x0 * f0 + x1 * f1 + x2 * f2 + x3 * f3 + x4 * f4 + x5 * f5
        m_f = self._tank_f.step(p_damp, p_force, dt)  # eq. 38–45: λ + σ_f(1 − λ)
        # the impedance tank harvests only the dissipation the force tank did not store (no double count)
        p_port = x0 * p0 + x1 * p1 + x2 * p2 + x3 * p3 + x4 * p4 + x5 * p5
        sigma_i = self._tank_i.step(p_damp - self._tank_f.damping_harvested_w, -p_port, dt)  # eq. 57–63
        nk0, nk1, nk2, nk3, nk4, nk5 = self._neg_k_const_f
        # eq. 72–73, tool frame
        g0 = nk0 * e0 - dx0 + sigma_i * p0 + m_f * f0
        g1 = nk1 * e1 - dx1 + sigma_i * p1 + m_f * f1
        g2 = nk2 * e2 - dx2 + sigma_i * p2 + m_f * f2
        g3 = nk3 * e3 - dx3 + sigma_i * p3 + m_f * f3
        g4 = nk4 * e4 - dx4 + sigma_i * p4 + m_f * f4
        g5 = nk5 * e5 - dx5 + sigma_i * p5 + m_f * f5

        # raw values only: the dict is built on demand in telemetry() (1 kHz budget)
        self._raw = (rho_align, rho_frc, c, h, theta, ls, usable, sigma_i, m_f, wd[2] - wm[2], e, state)
        # τ = Jᵀ [R f_lin; R f_ang]: the rotation on floats, one (6,) · (6, 7) product
        f_world = (r00 * g0 + r01 * g1 + r02 * g2, r10 * g0 + r11 * g1 + r12 * g2, r20 * g0 + r21 * g1 + r22 * g2,
                   r00 * g3 + r01 * g4 + r02 * g5, r10 * g3 + r11 * g4 + r12 * g5, r20 * g3 + r21 * g4 + r22 * g5)
        return self.joint_torque(state, f_world)

    @property
    def rotation_desired(self) -> np.ndarray | None:
        """The desired orientation R_d (world_R_tool) the controller tracks now: the reference's at the
        first tick, then moved by the re-orientations (eq. 22–29); None before the first tick."""
        if (tick := self._live) is not None:
            return tick.rotation_desired()
        return None if self._rot_d is None else np.array(self._rot_d)

    @property
    def position_offset(self) -> np.ndarray:
        """Offset [m] (world) added to the reference position: the actual translation fed back while
        fully compliant (eq. 20–21 with ρ_align ≈ 0). The effective desired position is
        ``reference.position_world + position_offset``."""
        if (tick := self._live) is not None:
            return tick.position_offset()
        return np.array(self._offset)

    def tick_telemetry(self) -> dict[str, float]:
        """What a task reads every tick, cheaply: ρ_align, ρ_frc, the tank energies and the impedance
        tank's valve σ_i (the full :meth:`telemetry` costs ~10× more: read it at the recording rate)."""
        if (tick := self._live) is not None:
            return tick.tick_telemetry()
        if self._raw is None:
            return {}
        raw = self._raw
        return {"rho_align": raw[0], "rho_frc": raw[1], "tank_i_valve": raw[7], "tank_i_energy_j": self._tank_i.energy,
                "tank_f_energy_j": self._tank_f.energy}

    def port_wrench_last(self) -> np.ndarray | None:
        """(6,) the port feed-forward's last wrench [N, N·m] (tool frame), None without one."""
        if (tick := self._live) is not None:
            return tick.port_wrench_last()
        return None if self._port_feedforward is None else np.asarray(self._port_feedforward.last, dtype=float)

    def telemetry(self) -> dict[str, float]:
        """ρ_align, ρ_frc, C, h, θ, l_s, tank energies/states/valves and their energy ledgers."""
        if (tick := self._live) is not None:  # read from the compiled tick's vector as it is
            raw, ti, tf, realigning = tick.snapshot()
        else:
            raw, ti, tf, realigning = self._raw, self._tank_i, self._tank_f, self._realign is not None
        if raw is None:
            return {}
        rho_align, rho_frc, c, h, theta, ls, usable, sigma_i, m_f, f_err, x_err, state = raw
        x_err = np.array(x_err)
        kinetic = 0.5 * float(state.dq @ state.mass_matrix @ state.dq)  # S_r, eq. 32
        spring_const = 0.5 * float(x_err @ (self._k_const * x_err))  # ½x̃ᵀK_const x̃, eq. 64
        spring_var = 0.5 * rho_align * float(x_err @ (self._k_max_t * x_err))  # ½x̃ᵀK_var x̃
        tanks = ti.energy + tf.energy
        return {
            "rho_align": rho_align,
            "rho_frc": rho_frc,
            "alignment_c": c,
            "alignment_h": h,
            "theta_rad": theta,
            "curvature": ls,
            "surface_usable": float(usable),
            "realigning": float(realigning),
            "tank_i_energy_j": ti.energy,
            "tank_f_energy_j": tf.energy,
            "tank_i_state": ti.state,
            "tank_f_state": tf.state,
            "tank_i_valve": sigma_i,
            "tank_f_multiplier": m_f,
            "tank_i_delivered_j": ti.delivered,
            "tank_f_delivered_j": tf.delivered,
            "tank_i_harvested_j": ti.harvested,
            "tank_f_harvested_j": tf.harvested,
            "force_error_n": f_err,
            "pose_error_m": float(np.linalg.norm(x_err[:3])),
            "kinetic_energy_j": kinetic,
            "spring_energy_const_j": spring_const,
            "spring_energy_var_j": spring_var,
            "storage_controller_j": spring_const + tanks,  # S_c of eq. 64 plus the force tank (eq. 46)
            "storage_overall_j": spring_const + tanks + kinetic,  # S_overall, eq. 46/69
        }
