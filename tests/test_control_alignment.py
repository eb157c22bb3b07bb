"""Contact-alignment monitor and shaping functions (VA-UFIC eq. 17–21, 30), case by case."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactex.control import AlignmentShaper, alignment_coefficient, contact_alignment, force_shaping, rho_align_rate

RHO_MIN = 0.001
F_D = np.array([0, 0, 15.0, 0, 0, 0])


def test_contact_alignment_sum_of_terms():
    f = np.array([1.0, 0, 15.0, 0, 0, 0])
    x = np.array([0.0, 0, -0.01, 0, 0, 0])
    c = contact_alignment(f, x, 0.3, 0.02, alpha=1.0, xi=0.08, gamma=10.0)
    assert c == pytest.approx(0.15 + 0.08 * 0.3 + 10 * 0.02)
    assert alignment_coefficient(c, 0.9) == pytest.approx(1.0 - c / 0.9)


@pytest.mark.parametrize(
    ("rho_align", "h", "expected"),
    [
        (1.0, 0.5, 0.0),  # at 1 and ρ > 0: min{ρ, 0} = 0, stays
        (1.0, -0.5, -0.5 + RHO_MIN),  # at 1 and ρ < 0: decreases
        (0.4, 0.5, 0.2 + RHO_MIN),  # inside: ρ = hρ_align + ρ_min
        (0.4, -2.0, -0.8 + RHO_MIN),
        (0.0, -3.0, RHO_MIN),  # at 0: max{ρ, 0} with ρ = ρ_min > 0: starts growing (ρ_min's purpose)
        (0.0, 0.5, RHO_MIN),
    ],
)
def test_rho_align_rate_cases(rho_align, h, expected):
    assert rho_align_rate(rho_align, h, RHO_MIN) == pytest.approx(expected)


def test_rho_align_at_zero_never_negative():
    assert rho_align_rate(0.0, -1.0, 0.0) == 0.0


def test_shaper_stays_in_unit_interval_and_follows_h():
    s = AlignmentShaper(RHO_MIN)
    assert s.rho == 0.0
    for _ in range(20000):
        s.step(0.8, 1e-3)
        assert 0.0 <= s.rho <= 1.0
    assert s.rho == 1.0  # aligned: reaches full stiffness
    for _ in range(20000):
        s.step(-1.5, 1e-3)
        assert 0.0 <= s.rho <= 1.0
    # misaligned: eq. 20–21 settle at ρ_align = −ρ_min/h > 0, not at 0 (hence VA-UFIC's compliance threshold)
    assert s.rho == pytest.approx(RHO_MIN / 1.5, rel=1e-6)
    s.reset()
    assert s.rho == 0.0


def test_shaper_matches_explicit_euler():
    s = AlignmentShaper(RHO_MIN, rho0=0.3)
    rho = 0.3
    for k in range(100):
        h = math.sin(0.1 * k)
        rho = rho + 1e-3 * (h * rho + RHO_MIN)
        assert s.step(h, 1e-3) == pytest.approx(rho, abs=1e-15)


@pytest.mark.parametrize(
    ("x_err", "expected"),
    [
        (np.array([0, 0, -0.01, 0, 0, 0]), 1.0),  # f_dᵀx̃ < 0: tool stopped before x_d (in contact)
        (np.zeros(6), 1.0),  # f_dᵀx̃ = 0
        (np.array([0, 0, 0.02, 0, 0, 0]), 0.5 * (1 + math.cos(math.pi * 0.02 / 0.04))),  # inside δ_c
        (np.array([0, 0, 0.04, 0, 0, 0]), 0.0),  # at δ_c exactly: cos(π) → 0
        (np.array([0, 0, 0.05, 0, 0, 0]), 0.0),  # beyond δ_c: impedance only
    ],
)
def test_force_shaping_cases(x_err, expected):
    assert force_shaping(F_D, x_err, 0.04) == pytest.approx(expected, abs=1e-15)


def test_force_shaping_otherwise_branch():
    """f_dᵀx̃ > 0 through another component while x̃_z ≤ 0 falls in the 'otherwise' case: 0."""
    f_d = np.array([5.0, 0, 15.0, 0, 0, 0])
    assert force_shaping(f_d, np.array([0.01, 0, -0.001, 0, 0, 0]), 0.04) == 0.0
