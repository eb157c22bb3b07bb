"""Virtual energy tanks of VA-UFIC §II-C: the force tank (eq. 37–45) and the impedance tank (eq. 55–63).

Both are ports of a power-preserving Dirac structure (eq. 42, 61): the power the tank gives to
the controller port, f_varᵀẋ, is exactly what leaves the tank, −u_t·y_t. We integrate the tank
energy S = ½x² directly (explicit Euler on S, then x = √(2S)) so the discrete balance is exact to
round-off, and the valve σ is reduced within a step if a draw would cross the lower limit, so
S never goes below S_low (the singularity the paper guards against with S_low).

Dissipation is harvested once. Eq. 39 and eq. 57 both store β·ẋᵀD_Cẋ, the same dissipated
power, so the two tanks together could give back up to twice what the damping took from the
robot, and an independent ∫τ·q̇ audit of a wiping run with contact loss shows the controller
delivering more energy than its storage lost. Here the force tank (small, and usually full) takes
its share first (:attr:`ForceTank.damping_harvested_w`) and the impedance tank gets the rest of
ẋᵀD_Cẋ, so the pair never stores more than was dissipated (a deviation from the paper's literal
eq. 39/57, which is not passive as a pair).

``enabled=False`` keeps the accounting (a "shadow" tank, which may then run below its lower
limit or negative) but opens every valve: the controller behaves as if it had no tank, which is
what the passivity comparison needs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tactex.errors import ConfigError

__all__ = ["EnergyTank", "ForceTank", "ImpedanceTank", "TankStep", "smooth_fill_gate", "smooth_valve"]


def smooth_valve(energy: float, lower: float, band: float) -> float:
    """σ(S) of eq. 44/63: 0 at or below ``lower``, rising smoothly (cosine) to 1 at ``lower + band``."""
    if energy <= lower:
        return 0.0
    if band <= 0.0 or energy >= lower + band:
        return 1.0
    return 0.5 * (1.0 - math.cos(math.pi * (energy - lower) / band))


def smooth_fill_gate(energy: float, upper: float, band: float) -> float:
    """β(S) of eq. 45/60 with the smooth κ: 1 below ``upper − band``, cosine to 0, 0 at or above ``upper``."""
    if energy >= upper:
        return 0.0
    if band <= 0.0 or energy <= upper - band:
        return 1.0
    return 0.5 * (1.0 + math.cos(math.pi * (energy - (upper - band)) / band))


@dataclass(frozen=True, slots=True)
class TankStep:
    """One tick of a tank, for tests and logs. Powers in [W], energies in [J].

    port_power: f_varᵀẋ, power the tank's port delivers to the robot.
    tank_port_power: u_t·y_t, power entering the tank through the port (= −port_power).
    harvest_power: power stored from dissipation (β·ẋᵀDẋ, and λ·(−ẋᵀf_f) for the force tank).
    valve: σ used this tick; gate: β used this tick; lam: λ (force tank, else 1).
    """

    port_power: float
    tank_port_power: float
    harvest_power: float
    valve: float
    gate: float
    lam: float
    energy: float


class EnergyTank:
    """State x_t, energy S_t = ½x_t², limits S_low < S_up, smooth valve and fill gate.

    The tank never holds more than S_up: the fill gate β stops the harvest below it (eq. 45/60), and the
    energy a port gives back once the tank is full (the variable spring relaxing) is vented, not stored. The
    paper bounds only the harvest, so a spring driven far off its set point could fill the tank through its
    port without bound and hand it all back later; venting is dissipation, so the tank stays passive.
    :attr:`vented` [J] is what was vented (the books: S = S(0) + harvested − delivered − vented).
    """

    def __init__(self, x0: float, upper_j: float, lower_j: float, band_j: float = 0.1, enabled: bool = True) -> None:
        if not (np.isfinite([x0, upper_j, lower_j, band_j]).all() and 0.0 < lower_j < upper_j and band_j >= 0.0):
            raise ConfigError(
                f"energy tank needs 0 < lower < upper and band ≥ 0, got x0={x0}, lower={lower_j}, upper={upper_j}, "
                f"band={band_j}"
            )
        if 0.5 * x0 * x0 <= lower_j:
            raise ConfigError(f"energy tank initial state x0={x0} holds {0.5 * x0 * x0} J ≤ lower limit {lower_j} J")
        if 0.5 * x0 * x0 > upper_j:
            raise ConfigError(
                f"energy tank initial state x0={x0} holds {0.5 * x0 * x0} J > upper limit {upper_j} J; "
                f"use x0 ≤ √(2·upper) = {math.sqrt(2.0 * upper_j):.4g}"
            )
        self.x0, self.upper, self.lower = float(x0), float(upper_j), float(lower_j)
        self.band, self.enabled = float(band_j), bool(enabled)
        self.energy = 0.5 * self.x0 * self.x0
        self.delivered = 0.0  # ∫ port power [J] (energy given to the robot through the port)
        self.harvested = 0.0  # ∫ harvest power [J]
        self._last: tuple | None = None

    def reset(self) -> None:
        self.energy = 0.5 * self.x0 * self.x0
        self.delivered = 0.0
        self.harvested = 0.0
        self._last = None

    @property
    def vented(self) -> float:
        """Energy [J] the port gave back while the tank was full, let go instead of stored."""
        return 0.5 * self.x0 * self.x0 + self.harvested - self.delivered - self.energy

    @property
    def last(self) -> TankStep | None:
        """The last tick's powers and valves (built on demand: the tick itself only stores a tuple)."""
        return None if self._last is None else TankStep(*self._last)

    @property
    def state(self) -> float:
        """x_t = √(2 S_t) (0 when a disabled shadow tank ran dry)."""
        return math.sqrt(max(2.0 * self.energy, 0.0))

    def valve(self) -> float:
        return 1.0 if not self.enabled else smooth_valve(self.energy, self.lower, self.band)

    def gate(self) -> float:
        return smooth_fill_gate(self.energy, self.upper, self.band)

    def withdraw(self, energy_j: float) -> bool:
        """Pay ``energy_j`` [J] ≥ 0 at once (energy put into a storage outside the port, e.g. a spring
        whose set point moves). All or nothing: False, and nothing taken, when it would bring an enabled
        tank below its lower limit. A disabled (shadow) tank always pays, as it keeps only the books."""
        if not energy_j > 0.0:  # nothing to pay (and a NaN never drains the tank)
            return energy_j == 0.0
        if self.enabled and self.energy - energy_j < self.lower:
            return False
        self.energy -= energy_j
        self.delivered += energy_j
        return True

    def _commit(self, demand_w: float, valve: float, harvest_w: float, gate: float, lam: float, dt: float) -> float:
        """Apply one step. ``demand_w`` is the power the port would deliver with the valve fully
        open; returns the valve actually used (reduced so S stays ≥ S_low when enabled).
        The clamps are conditional expressions, not min/max (1 kHz path); they pick the same values."""
        if self.enabled and demand_w > 0.0 and valve > 0.0:
            room = self.energy - self.lower
            if valve * demand_w * dt > room:
                valve = room / (demand_w * dt)
                valve = valve if valve > 0.0 else 0.0
        port = valve * demand_w
        harvest = harvest_w if harvest_w > 0.0 else 0.0
        if harvest > 0.0:
            room = (self.upper - self.energy) / dt
            room = room if room > 0.0 else 0.0
            harvest = room if room < harvest else harvest
        # what the port gives back beyond S̄ is vented, not stored (see the class docstring)
        energy = self.energy + dt * (harvest - port)
        top = self.upper if self.upper > self.energy else self.energy
        self.energy = top if energy > top else energy
        self.delivered += dt * port
        self.harvested += dt * harvest
        self._last = (port, -port, harvest, valve, gate, lam, self.energy)
        return valve


class ForceTank(EnergyTank):
    """VA-UFIC eq. 37–45. Defaults from Table I: x_t,f(0) = 2, S̄ = 2 J, S_low = 1 J.

    ``lambda_band_w`` [W] ramps eq. 38's switch λ over ẋᵀf_f ∈ [−band, 0] instead of stepping it at 0.
    The paper's λ jumps from 1 (the force controller dissipates: it acts unmodified) to 0 (it is
    routed through the tank, σ(S)) as the sign of ẋᵀf_f changes. With the tank full (σ = 1) that changes
    nothing; with the tank drained (σ ≈ 0: a force pushing through free space, no surface where one
    was expected) the force multiplier jumps between 1 and 0 whenever the velocity along the force
    changes sign, and the whole force (the 15 N set point, 13 N·m on the shoulder) comes and goes
    from one 1 ms tick to the next: the commanded torque stays clipped at the robot's rate limit until
    the robot aborts (controller_torque_discontinuity). Ramped, the multiplier λ + σ(1 − λ) is continuous in
    ẋᵀf_f; inside the band the force is still dissipative (ẋᵀf_f < 0 and a multiplier in [0, 1]), and
    all it dissipates is what the tank stores, so the tank stays passive. 0: the paper's step.
    """

    def __init__(self, x0: float = 2.0, upper_j: float = 2.0, lower_j: float = 1.0, band_j: float = 0.1,
                 enabled: bool = True, lambda_band_w: float = 0.0) -> None:
        super().__init__(x0, upper_j, lower_j, band_j, enabled)
        if not (math.isfinite(lambda_band_w) and lambda_band_w >= 0.0):
            raise ConfigError(f"force tank lambda_band_w must be finite and ≥ 0, got {lambda_band_w!r}")
        self.lambda_band_w = float(lambda_band_w)

    damping_harvested_w: float = 0.0
    """Part of this tick's ẋᵀD_Cẋ [W] the force tank stored; the impedance tank may store only the rest."""

    def step(self, damping_power: float, force_power: float, dt: float) -> float:
        """One tick with ẋᵀD_Cẋ [W] and ẋᵀf_f [W] of the force-control wrench f_f that would be
        applied; returns the multiplier λ + σ(1−λ) of eq. 51/73 for f_f.

        λ = 1 when the force controller dissipates (ẋᵀf_f < 0, eq. 38; ramped from 0 at ẋᵀf_f = 0 to 1
        at −``lambda_band_w``): it acts unmodified and the tank stores β·(ẋᵀDẋ − m·ẋᵀf_f) (eq. 39, m
        the multiplier applied). Otherwise it is routed through the tank: the port force
        f_f,var = ω_f y_t = σ f_f (eq. 42–43; ω_f has y_t, not u_t, in its denominator, as
        f_f,var = ω_f y_t requires) and the tank loses u_t y_t = −σ ẋᵀf_f.
        """
        gate = self.gate()
        self.damping_harvested_w = 0.0
        if force_power < 0.0:
            band = self.lambda_band_w
            lam = 1.0 if band <= 0.0 or force_power <= -band else -force_power / band
            m = 1.0 if lam >= 1.0 else lam + self.valve() * (1.0 - lam)
            damping = 0.0 if 0.0 > damping_power else damping_power  # max(damping_power, 0), NaN kept
            dissipated = damping - m * force_power
            self._commit(0.0, 0.0, gate * dissipated, gate, lam, dt)
            # what was stored, split between the two dissipations in proportion
            self.damping_harvested_w = self._last[2] * damping / dissipated if dissipated > 0.0 else 0.0
            return m
        return self._commit(force_power, self.valve(), 0.0, gate, 0.0, dt)


class ImpedanceTank(EnergyTank):
    """VA-UFIC eq. 55–63. Defaults from Table I: x_t,i(0) = 7, S̄ = 32 J, S_low = 1 J."""

    def __init__(self, x0: float = 7.0, upper_j: float = 32.0, lower_j: float = 1.0, band_j: float = 0.5,
                 enabled: bool = True) -> None:
        super().__init__(x0, upper_j, lower_j, band_j, enabled)

    def step(self, damping_power: float, spring_power: float, dt: float) -> float:
        """One tick with ẋᵀD_Cẋ [W] (less what the force tank already stored of it, see the module
        docstring) and ẋᵀK_var(t)x̃ [W]. Returns σ(S_t,i) of eq. 62/72: the variable spring force
        applied is f_i,var = ω_i y_t = −σ·K_var·x̃, delivering −σ ẋᵀK_var x̃ to the robot, and the tank
        stores β·ẋᵀDẋ (eq. 57)."""
        gate = self.gate()
        return self._commit(-spring_power, self.valve(), gate * damping_power, gate, 1.0, dt)
