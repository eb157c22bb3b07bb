"""Energy tanks (VA-UFIC eq. 37–45, 55–63): Dirac power balance, valves, fill gate."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from tactex.control import ForceTank, ImpedanceTank, smooth_fill_gate, smooth_valve
from tactex.errors import ConfigError

DT = 1e-3
BALANCE_TOL = 1e-9
D = np.diag([50.0, 50.0, 50.0, 2.0, 2.0, 2.0])


def _check_balance(tank, energy_before: float, vented_before: float) -> None:
    step = tank.last
    # eq. 42 / 61: f_varᵀẋ + u_t y_t = 0 (power-preserving interconnection)
    assert step.port_power + step.tank_port_power == pytest.approx(0.0, abs=BALANCE_TOL)
    # and the tank's energy changes by exactly the port and harvest powers over the step, less what a full
    # tank vents; it only ever vents inflow above S̄
    vented = tank.vented - vented_before
    assert vented >= -BALANCE_TOL
    if vented > BALANCE_TOL:
        assert tank.energy == pytest.approx(tank.upper, abs=BALANCE_TOL)
    expected = DT * (step.harvest_power + step.tank_port_power) - vented
    assert tank.energy - energy_before == pytest.approx(expected, abs=BALANCE_TOL)
    assert tank.energy <= tank.upper + BALANCE_TOL


def test_impedance_tank_balance_per_step(rng):
    tank = ImpedanceTank()
    for _ in range(2000):
        xdot = rng.normal(size=6) * 0.2
        kvar_err = rng.normal(size=6) * 20.0
        s0, v0 = tank.energy, tank.vented
        sigma = tank.step(float(xdot @ D @ xdot), float(xdot @ kvar_err), DT)
        _check_balance(tank, s0, v0)
        # the port force is −σ K_var x̃; its power is what the tank reports as delivered
        assert float(xdot @ (-sigma * kvar_err)) == pytest.approx(tank.last.port_power, abs=BALANCE_TOL)


def test_force_tank_balance_per_step(rng):
    tank = ForceTank(x0=2.0, upper_j=3.0, lower_j=1.0)
    for _ in range(2000):
        xdot = rng.normal(size=6) * 0.2
        f_f = rng.normal(size=6) * 10.0
        s0, v0 = tank.energy, tank.vented
        m = tank.step(float(xdot @ D @ xdot), float(xdot @ f_f), DT)
        _check_balance(tank, s0, v0)
        lam = 1.0 if xdot @ f_f < 0 else 0.0
        assert tank.last.lam == lam  # eq. 38
        if lam == 1.0:
            assert m == 1.0 and tank.last.port_power == 0.0  # dissipating: passes unmodified, tank fills
        else:
            assert float(xdot @ (m * f_f)) == pytest.approx(tank.last.port_power, abs=BALANCE_TOL)


def test_impedance_valve_closes_at_lower_limit():
    tank = ImpedanceTank(x0=2.0, upper_j=32.0, lower_j=1.0)
    xdot = np.array([0.1, 0, 0, 0, 0, 0])
    kvar_err = np.array([-100.0, 0, 0, 0, 0, 0])  # stiffness pushing along the motion: drains 10 W
    sigmas = []
    for _ in range(20000):
        sigmas.append(tank.step(0.0, float(xdot @ kvar_err), DT))
        assert tank.energy >= 1.0  # never below the lower limit, not even by one step
    assert sigmas[0] == 1.0
    # the smooth valve closes as S reaches S_low: the drain slows to nothing right at the limit
    assert tank.energy - 1.0 < 2e-3 and sigmas[-1] < 0.01
    assert all(b <= a + 1e-15 for a, b in itertools.pairwise(sigmas[1000:]))


def test_valve_clamps_a_large_single_draw_at_the_lower_limit():
    tank = ImpedanceTank(x0=2.0, upper_j=32.0, lower_j=1.0, band_j=0.0)  # hard valve
    sigma = tank.step(0.0, -5000.0, DT)
    assert tank.energy == pytest.approx(1.0, abs=1e-12)  # drew exactly the 1 J above the limit
    assert sigma == pytest.approx(1.0 / 5.0)
    assert tank.step(0.0, -5000.0, DT) == 0.0


def test_what_the_port_gives_back_past_the_upper_limit_is_vented_not_stored():
    """A variable spring relaxing (spring power ẋᵀK_var x̃ > 0: the port gives energy back) fills the tank
    only up to S̄; the rest is vented and the books still balance."""
    tank = ImpedanceTank(x0=7.0, upper_j=32.0, lower_j=1.0)  # 24.5 J
    for _ in range(5000):
        tank.step(0.0, 50.0, DT)  # 50 W back through the port for 5 s: 250 J offered
        assert tank.energy <= 32.0 + 1e-12
    assert tank.energy == pytest.approx(32.0)
    assert tank.delivered == pytest.approx(-250.0)  # the port's own books: it took 250 J from the robot
    assert tank.vented == pytest.approx(250.0 - 7.5)  # all but the 7.5 J of room was let go
    assert tank.last.tank_port_power == pytest.approx(50.0)
    tank.step(0.0, -10.0, DT)  # and it pays from the top, as a full tank does
    assert tank.energy == pytest.approx(32.0 - 10.0 * DT)


def test_force_valve_closes_at_lower_limit():
    tank = ForceTank(x0=2.0, upper_j=2.0, lower_j=1.0)
    xdot = np.array([0, 0, 0.2, 0, 0, 0])
    f_f = np.array([0, 0, 15.0, 0, 0, 0])  # contact lost: force control accelerates the tool (3 W)
    for _ in range(5000):
        m = tank.step(0.0, float(xdot @ f_f), DT)
        assert tank.energy >= 1.0
    assert m < 0.01 and tank.energy - 1.0 < 1e-3
    assert tank.delivered == pytest.approx(2.0 - tank.energy, abs=1e-9)  # all it gave came out of the tank


def test_fill_stops_at_upper_limit():
    tank = ImpedanceTank(x0=7.0, upper_j=32.0, lower_j=1.0)
    xdot = np.array([0.5, 0.5, 0, 0, 0, 0])
    for _ in range(20000):
        tank.step(float(xdot @ D @ xdot), 0.0, DT)
        assert tank.energy <= 32.0 + 1e-12
    assert 32.0 - tank.energy < 1e-3  # β fades to 0 as S reaches S̄
    assert tank.last.gate < 0.01 and tank.last.harvest_power < 0.01 * float(xdot @ D @ xdot)
    full = ImpedanceTank(x0=8.0, upper_j=32.0, lower_j=1.0)  # ½·8² = 32 J: at the limit
    full.step(float(xdot @ D @ xdot), 0.0, DT)
    assert full.last.gate == 0.0 and full.last.harvest_power == 0.0 and full.energy == 32.0


def test_force_tank_table_defaults_stay_full():
    """Table I: x_t,f(0)=2 → S = 2 J = S̄: β = 0, the tank cannot overfill (paper Fig. 3d: constant 2 J)."""
    tank = ForceTank()
    xdot = np.array([0, 0, -0.1, 0, 0, 0])
    for _ in range(100):
        assert tank.step(float(xdot @ D @ xdot), float(xdot @ np.array([0, 0, 15.0, 0, 0, 0])), DT) == 1.0
    assert tank.energy == pytest.approx(2.0)


def test_disabled_tank_keeps_accounting_but_never_closes():
    tank = ImpedanceTank(x0=2.0, enabled=False)
    xdot = np.array([0.1, 0, 0, 0, 0, 0])
    for _ in range(3000):
        assert tank.step(0.0, float(xdot @ np.array([-100.0, 0, 0, 0, 0, 0])), DT) == 1.0
    assert tank.energy < 0.0  # the shadow tank shows the energy a real tank could not have given


def test_smooth_valve_and_gate_shapes():
    assert smooth_valve(1.0, 1.0, 0.1) == 0.0
    assert smooth_valve(0.5, 1.0, 0.1) == 0.0
    assert 0.0 < smooth_valve(1.05, 1.0, 0.1) < 1.0
    assert smooth_valve(1.2, 1.0, 0.1) == 1.0
    assert smooth_fill_gate(2.0, 2.0, 0.1) == 0.0
    assert 0.0 < smooth_fill_gate(1.95, 2.0, 0.1) < 1.0
    assert smooth_fill_gate(1.0, 2.0, 0.1) == 1.0


@pytest.mark.parametrize(
    ("kwargs"),
    [{"x0": 1.0, "upper_j": 32.0, "lower_j": 1.0}, {"x0": 7.0, "upper_j": 1.0, "lower_j": 2.0},
     {"x0": 7.0, "upper_j": 32.0, "lower_j": 0.0}, {"x0": float("nan"), "upper_j": 32.0, "lower_j": 1.0}],
)
def test_tank_config_validation(kwargs):
    with pytest.raises(ConfigError, match="energy tank"):
        ImpedanceTank(**kwargs)


def test_a_tank_cannot_start_above_its_upper_limit():
    with pytest.raises(ConfigError, match=r"upper limit 32\.0 J"):
        ImpedanceTank(x0=20.0, upper_j=32.0, lower_j=1.0)  # 200 J in a 32 J tank
    assert ImpedanceTank(x0=8.0, upper_j=32.0, lower_j=1.0).energy == 32.0  # exactly full is allowed


def test_withdraw_is_all_or_nothing_above_the_lower_limit():
    tank = ImpedanceTank(x0=2.0, upper_j=32.0, lower_j=1.0)  # 2 J
    assert tank.withdraw(0.75) and tank.energy == pytest.approx(1.25) and tank.delivered == pytest.approx(0.75)
    assert not tank.withdraw(0.5) and tank.energy == pytest.approx(1.25)  # would end at 0.75 J < 1 J
    assert tank.withdraw(0.0) and not tank.withdraw(float("nan")) and tank.energy == pytest.approx(1.25)
    shadow = ImpedanceTank(x0=2.0, upper_j=32.0, lower_j=1.0, enabled=False)
    assert shadow.withdraw(1.5) and shadow.energy == pytest.approx(0.5)  # books kept below the limit


def test_the_pair_never_stores_more_than_was_dissipated(rng):
    """Eq. 39 and 57 both harvest ẋᵀDẋ; routed as VA-UFIC does (force tank first, the impedance
    tank the rest), the pair together stores at most the damping's plus the force loop's dissipation."""
    dt = 1e-3
    tf, ti = ForceTank(x0=1.2, upper_j=2.0, lower_j=0.5), ImpedanceTank(x0=1.2, upper_j=2.0, lower_j=0.5)
    dissipated = 0.0
    for _ in range(4000):
        p_damp = float(rng.uniform(0.0, 2.0))
        p_force = float(rng.normal(0.0, 1.0))  # ẋᵀf_f: dissipating when negative (λ = 1)
        tf.step(p_damp, p_force, dt)
        assert 0.0 <= tf.damping_harvested_w <= p_damp + 1e-12
        ti.step(p_damp - tf.damping_harvested_w, float(rng.normal(0.0, 1.0)), dt)
        dissipated += dt * (p_damp + max(-p_force, 0.0))
        assert tf.harvested + ti.harvested <= dissipated + 1e-9
    # both tanks actually harvested (the split did not starve one of them) and both filled to the top
    assert tf.harvested > 0.1 and ti.harvested > 0.1
    assert tf.energy > 1.9 and ti.energy > 1.9


def test_force_tank_reports_no_damping_harvest_while_its_port_delivers():
    tank = ForceTank(x0=1.6, upper_j=2.0, lower_j=1.0)
    tank.step(damping_power=3.0, force_power=0.5, dt=1e-3)  # λ = 0: the force loop injects
    assert tank.damping_harvested_w == 0.0
    tank.step(damping_power=3.0, force_power=-1.0, dt=1e-3)  # λ = 1: stores β(ẋᵀDẋ − ẋᵀf_f)
    assert tank.damping_harvested_w == pytest.approx(3.0 * tank.last.harvest_power / 4.0)


def test_a_drained_force_tanks_multiplier_is_continuous_in_the_power():
    """Eq. 38's λ steps from 1 to 0 where ẋᵀf_f changes sign: with the tank drained (σ ≈ 0) the whole force
    came and went tick to tick whenever the velocity along it changed sign (measured on franka-sim: the
    command held at the robot's torque-rate limit until it aborted). Ramped over lambda_band_w, the
    multiplier moves by at most Δp/band for a change Δp of ẋᵀf_f, and the paper's step is band 0."""
    def multiplier(band: float, power: float) -> float:
        tank = ForceTank(lambda_band_w=band)
        tank.energy = tank.lower + 1e-9  # drained: σ ≈ 0
        return tank.step(0.0, power, 1e-3)

    powers = np.linspace(-0.5, 0.5, 2001)  # 0.5 mW apart
    stepped = [multiplier(0.0, p) for p in powers]
    ramped = [multiplier(0.3, p) for p in powers]
    assert max(abs(np.diff(stepped))) > 0.99  # the paper's switch: 1 → 0 between two neighbouring powers
    assert max(abs(np.diff(ramped))) <= (powers[1] - powers[0]) / 0.3 + 1e-9
    assert multiplier(0.3, -0.3) == 1.0 and multiplier(0.3, -0.15) == pytest.approx(0.5, abs=1e-6)
    assert multiplier(0.3, 0.1) == pytest.approx(0.0, abs=1e-6)
    with pytest.raises(ConfigError, match="lambda_band_w"):
        ForceTank(lambda_band_w=-1.0)


def test_the_ramped_force_tank_stays_passive(rng):
    """Inside the ramp the force acts, reduced, while it dissipates: the tank stores only what the applied
    force and the damping dissipate, and its energy never drops below the lower limit."""
    tank = ForceTank(lambda_band_w=0.3)
    tank.energy = tank.lower + 0.05
    for _ in range(20000):
        power, damping = rng.normal(scale=0.3), abs(rng.normal(scale=0.1))
        e0 = tank.energy
        m = tank.step(damping, power, 1e-3)
        assert 0.0 <= m <= 1.0 and tank.energy >= tank.lower - 1e-12
        if power < 0.0:  # dissipating: the tank stores at most what was dissipated
            assert tank.energy - e0 <= (damping - m * power) * 1e-3 + 1e-15
        else:  # generating: the tank pays exactly what the force delivers
            assert e0 - tank.energy == pytest.approx(m * power * 1e-3, abs=1e-12)
