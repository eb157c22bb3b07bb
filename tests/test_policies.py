"""The force-motion policy family: each kind's path, rate and force, segments joined in sequence,
and the §III sinusoid reproducing the wipe's reference exactly."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactex.errors import ConfigError, InputError
from tactex.tasks.policies import (
    CirclePolicy,
    Figure8Policy,
    ForceRamp,
    LinePolicy,
    PolicySequence,
    SamplesPolicy,
    SinusoidPolicy,
    SpiralPolicy,
    ZigzagPolicy,
    read_samples,
    sample_policy,
)
from tactex.tasks.wipe import wiping_policy

#: A finite-difference rate matches the analytic one to this [m/s] (1 ms central differences).
RATE_TOL_M_S = 1e-5
F10 = ForceRamp(10.0, 10.0)


def _today_reference(t: float, a: float = 0.04, w: float = 2.0, d: float = 0.005) -> tuple[float, ...]:
    """The wipe's §III reference as written before policies existed (its tick code, copied)."""
    s, c = math.sin(w * t), math.cos(w * t)
    return (a * s, a * (c - 1.0) - d * t, a * w * c, -a * w * s - d)


def test_sinusoid_reproduces_todays_reference_exactly() -> None:
    pol = SinusoidPolicy(math.inf, ForceRamp(15.0, 15.0))
    for t in np.arange(0.0, 20.0, 0.0137):
        p = pol.at(float(t))
        assert (p.u_m, p.v_m, p.du_m_s, p.dv_m_s) == _today_reference(float(t))  # bit for bit
        assert p.force_n == 15.0
        x, v = wiping_policy(float(t))
        assert (x[0], x[1], v[0], v[1]) == (p.u_m, p.v_m, p.du_m_s, p.dv_m_s)
    assert PolicySequence([pol]).at(3.3) == pol.at(3.3)
    assert pol.constant_force_n == 15.0


KINDS = [
    LinePolicy(4.0, F10, length_m=0.1, direction_deg=30.0),
    ZigzagPolicy(8.0, F10, width_m=0.06, length_m=0.04, lanes=3),
    SpiralPolicy(6.0, F10, radius_m=0.035, turns=2.5),
    CirclePolicy(5.0, F10, radius_m=0.03, turns=1.0),
    Figure8Policy(8.0, F10, width_m=0.08, height_m=0.04),
    SinusoidPolicy(6.0, F10, amplitude_m=0.02),
]


@pytest.mark.parametrize("pol", KINDS, ids=lambda p: p.kind)
def test_each_kind_starts_at_the_contact_and_its_rate_is_its_derivative(pol) -> None:
    p0 = pol.at(0.0)
    assert (p0.u_m, p0.v_m) == (0.0, 0.0)
    h = 1e-3
    for t in np.linspace(0.01, pol.duration_s - 0.01, 97):
        a, b, mid = pol.at(t - h), pol.at(t + h), pol.at(t)
        assert abs((b.u_m - a.u_m) / (2 * h) - mid.du_m_s) < RATE_TOL_M_S
        assert abs((b.v_m - a.v_m) / (2 * h) - mid.dv_m_s) < RATE_TOL_M_S


@pytest.mark.parametrize("pol", KINDS[:5], ids=lambda p: p.kind)
def test_timed_kinds_start_and_end_at_rest(pol) -> None:
    for t in (0.0, pol.duration_s):
        p = pol.at(t)
        assert math.hypot(p.du_m_s, p.dv_m_s) < 1e-12


def test_shapes_end_where_they_should() -> None:
    line = KINDS[0].at(4.0)
    assert math.isclose(line.u_m, 0.1 * math.cos(math.radians(30)), abs_tol=1e-12)
    assert math.isclose(line.v_m, 0.1 * math.sin(math.radians(30)), abs_tol=1e-12)
    zig = KINDS[1]
    assert zig.corners == [(0.0, 0.0), (0.06, 0.0), (0.06, -0.02), (0.0, -0.02), (0.0, -0.04), (0.06, -0.04)]
    assert np.allclose(zig.at(8.0)[:2], (0.06, -0.04), atol=1e-12)
    spiral = KINDS[2].at(6.0)
    assert math.isclose(math.hypot(spiral.u_m, spiral.v_m), 0.035, rel_tol=1e-9)
    s = sample_policy(KINDS[2], 6.0)
    assert np.hypot(s["u"], s["v"]).max() <= 0.035 + 1e-12
    circle = sample_policy(KINDS[3], 5.0)  # a circle through the start, centred 3 cm along −v
    assert np.allclose(np.hypot(circle["u"], circle["v"] + 0.03), 0.03, atol=1e-12)
    assert np.allclose(KINDS[3].at(5.0)[:2], (0.0, 0.0), atol=1e-12)
    f8 = sample_policy(KINDS[4], 8.0)
    assert np.isclose(f8["u"].max(), 0.04) and np.isclose(f8["v"].max(), 0.02, atol=1e-5)
    assert np.allclose(KINDS[4].at(8.0)[:2], (0.0, 0.0), atol=1e-12)


def test_force_ramp_is_linear_and_held_outside() -> None:
    pol = LinePolicy(4.0, ForceRamp(5.0, 20.0), length_m=0.1)
    assert [pol.at(t).force_n for t in (-1.0, 0.0, 1.0, 2.0, 4.0, 5.0)] == [5.0, 5.0, 8.75, 12.5, 20.0, 20.0]
    assert pol.constant_force_n is None


def test_sequence_continues_each_segment_from_the_previous_end() -> None:
    a = LinePolicy(2.0, F10, length_m=0.05)
    b = LinePolicy(2.0, ForceRamp(10.0, 20.0), length_m=0.05, direction_deg=90.0)
    seq = PolicySequence([a, b])
    assert seq.duration_s == 4.0 and seq.segment_starts_s == (0.0, 2.0)
    assert np.allclose(seq.at(4.0)[:2], (0.05, 0.05), atol=1e-12)
    assert seq.segment_index(1.999) == 0 and seq.segment_index(2.0) == 1
    assert seq.constant_force_n is None


def test_blend_removes_a_velocity_jump_and_keeps_the_path_continuous() -> None:
    # a line ends at rest, a sinusoid starts at 8 cm/s: unblended the rate jumps at the join
    segs = [LinePolicy(2.0, F10, length_m=0.05), SinusoidPolicy(4.0, ForceRamp(15.0, 15.0))]
    hard = sample_policy(PolicySequence(segs), 6.0, dt_s=0.001)
    soft = sample_policy(PolicySequence(segs, blend_s=0.6), 6.0, dt_s=0.001)
    jump = lambda s: np.max(np.hypot(np.diff(s["du"]), np.diff(s["dv"])))  # noqa: E731
    assert jump(hard) > 0.07
    assert jump(soft) < 0.002  # per millisecond: an acceleration below 2 m/s²
    for s in (hard, soft):
        assert np.max(np.hypot(np.diff(s["u"]), np.diff(s["v"]))) < 1e-3 * 0.1  # no position jump
    # the blended rate is the derivative of the blended path
    h, seq = 1e-4, PolicySequence(segs, blend_s=0.6)
    for t in (1.75, 1.9, 2.0, 2.1, 2.25):
        assert abs((seq.at(t + h).u_m - seq.at(t - h).u_m) / (2 * h) - seq.at(t).du_m_s) < RATE_TOL_M_S
    assert math.isclose(seq.at(2.0).force_n, 12.5)  # forces mix too
    with pytest.raises(ConfigError, match=r"segment 2 .*blend_s"):
        PolicySequence(segs, blend_s=3.0)


def _csv(tmp_path, text: str):
    p = tmp_path / "drawn.csv"
    p.write_text(text)
    return p


def test_samples_interpolate_through_the_drawn_points(tmp_path) -> None:
    t = np.linspace(0.0, 4.0, 9)
    rows = "\n".join(f"{x},{0.02 * np.sin(x) + 0.1},{0.01 * x},{10 + x}" for x in t)
    data = read_samples(_csv(tmp_path, "t_s,u_m,v_m,force_n\n" + rows + "\n"))
    pol = SamplesPolicy(data)
    assert pol.duration_s == 4.0
    for x in t:  # through every sample, shifted to start at (0, 0)
        p = pol.at(float(x))
        assert math.isclose(p.u_m, 0.02 * np.sin(x), abs_tol=1e-12)
        assert math.isclose(p.v_m, 0.01 * x, abs_tol=1e-12)
        assert math.isclose(p.force_n, 10 + x)
    assert pol.at(0.0).du_m_s == 0.0 and pol.at(4.0).dv_m_s == 0.0  # clamped ends: from rest, to rest


@pytest.mark.parametrize(("text", "needle"), [
    ("t_s,u_m,v_m,force_n\n0,0,0,10\n1,nan,0,10\n", "line 3: u_m = nan is not a finite number"),
    ("t_s,u_m,v_m,force_n\n0,0,0,10\n1,0.01,0,10\n1,0.02,0,10\n", "line 4: t_s = 1 does not increase"),
    ("t_s,u_m,v_m,force_n\n0,0,0,10\n2,0.01,0,10\n1,0.02,0,10\n", "line 4: t_s = 1 does not increase"),
    ("t,u,v,f\n0,0,0,10\n1,0,0,10\n", "header t_s,u_m,v_m,force_n"),
    ("t_s,u_m,v_m,force_n\n0,0,0,10\n", "at least 2 samples"),
    ("t_s,u_m,v_m,force_n\n0,0,0,10\n1,0,x,10\n", "v_m = 'x' is not a number"),
    ("t_s,u_m,v_m,force_n\n0,0,0,10\n1,0,10\n", "3 columns"),
])
def test_bad_samples_are_refused_naming_the_line(tmp_path, text, needle) -> None:
    with pytest.raises(InputError, match=needle):
        read_samples(_csv(tmp_path, text))


def test_a_segment_needs_a_positive_duration() -> None:
    with pytest.raises(ConfigError, match="duration_s must be a positive"):
        LinePolicy(-1.0, F10, length_m=0.1)
    with pytest.raises(ConfigError, match="lanes"):
        ZigzagPolicy(4.0, F10, width_m=0.1, length_m=0.1, lanes=0)
