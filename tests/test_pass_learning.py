"""What a re-planned wipe learns from the first pass (tactex.tasks.pass_learning): the force and in-plane motion
errors the first pass made, low-passed without lag, fed forward at the same policy time."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.errors import InputError
from tactex.tasks.pass_learning import (
    MAX_FORCE_SHARE,
    MAX_OFFSET_M,
    SETTLE_S,
    PassCorrection,
)

DT = 0.01  # the series' spacing [s] (record_hz 100)
TOUCH_S, ALIGN_S = 0.5, 5.0


def _series(force_amp_n: float = 1.0, motion_amp_m: float = 0.002, n: int = 1600) -> dict[str, np.ndarray]:
    """A first pass: touch-down at TOUCH_S, aligned from ALIGN_S, a 15 N set point; the force errs by a 0.3 Hz
    sine of ``force_amp_n`` and the TCP lags the path by a 0.3 Hz sine of ``motion_amp_m`` along the tool's x
    and half of it along y."""
    t = DT * np.arange(n)
    wave = np.sin(2 * np.pi * 0.3 * t)
    contact = t >= TOUCH_S
    force = np.where(contact, 15.0 + force_amp_n * wave, 0.0)
    err = np.column_stack([motion_amp_m * wave, 0.5 * motion_amp_m * wave, 0.004 * np.ones(n)])
    return {"t": t, "force_z_n": force, "force_set_n": np.full(n, 15.0), "motion_error_tool": err,
            "in_contact": contact.astype(float), "rho_align": np.clip((t - 1.0) / (ALIGN_S - 1.0), 0.0, 1.0)}


def test_the_correction_undoes_a_share_of_the_first_pass_errors_where_they_were_learned() -> None:
    s = _series()
    c = PassCorrection.from_series(s, 0.8, "a test")
    assert c is not None
    t = s["t"]
    wave = np.sin(2 * np.pi * 0.3 * t)
    aligned = (t > ALIGN_S + 1.5) & (t < t[-1] - 1.5)  # away from the filter's fade in and out
    got_al = np.array([c.at(x) for x in t[aligned]])
    # force: −g times the error (the 0.3 Hz sine passes the 1 Hz low-pass nearly unchanged)
    assert got_al[:, 0] == pytest.approx(-0.8 * wave[aligned], abs=0.03)
    assert got_al[:, 1] == pytest.approx(-0.8 * 0.002 * wave[aligned], abs=5e-5)
    assert got_al[:, 2] == pytest.approx(-0.8 * 0.001 * wave[aligned], abs=5e-5)
    # its rate: the derivative of the in-plane correction [m/s]
    rate = -0.8 * 0.002 * 2 * np.pi * 0.3 * np.cos(2 * np.pi * 0.3 * t[aligned])
    assert got_al[:, 3] == pytest.approx(rate, abs=2e-4)
    # while the first pass was still compliant: its force error is learned once the touch-down has settled (with
    # VA-UFIC's tangential hold it repeats), its motion error not (the desired position followed the tool)
    compliant = (t > TOUCH_S + SETTLE_S + 0.7) & (t < ALIGN_S - 1.5)  # past the filter's fade in at the settle
    early = np.array([c.at(x) for x in t[compliant]])
    assert early[:, 0] == pytest.approx(-0.8 * wave[compliant], abs=0.05)
    assert np.abs(early[:, 1:3]).max() < 1e-5
    # not the touch-down's ring, before the settle
    ring = np.array([c.at(x) for x in t[(t > TOUCH_S) & (t < TOUCH_S + SETTLE_S - 0.5)]])
    assert np.abs(ring[:, 0]).max() < 0.15
    # nothing outside the pass's span
    assert c.at(-1.0) == (0.0, 0.0, 0.0, 0.0, 0.0) and c.at(t[-1] + 1.0) == (0.0, 0.0, 0.0, 0.0, 0.0)
    summary = c.summary()
    assert summary["gain"] == 0.8 and summary["from"] == "a test" and summary["note"] == ""
    assert summary["force_rms_n"] > 0.3 and 0.0 < summary["offset_max_abs_m"] <= MAX_OFFSET_M


def test_the_correction_is_bounded_and_a_zero_gain_learns_nothing() -> None:
    s = _series(motion_amp_m=0.05)
    s["force_z_n"] = np.where((s["t"] > 8.0) & (s["t"] < 8.7), 40.0, s["force_z_n"])  # 0.7 s pressed 25 N over
    big = PassCorrection.from_series(s, 1.0)
    assert big is not None and big.note == ""  # held within ±20 % for 95 % of the contact: it teaches
    assert np.abs(big.force_n).max() == pytest.approx(MAX_FORCE_SHARE * 15.0)
    assert np.abs(big.uv_m).max() == pytest.approx(MAX_OFFSET_M)
    assert PassCorrection.from_series(_series(), 0.0) is None
    never = _series()
    never["in_contact"] = np.zeros_like(never["t"])
    assert PassCorrection.from_series(never, 0.8) is None  # a pass that never touched has nothing to teach


def test_a_pass_that_lost_its_contact_teaches_nothing() -> None:
    """Held within ±20 % for less than 90 % of its contact (it slipped or lost the part): where it erred, the
    next pass on the explored surface will not be at that moment."""
    s = _series(force_amp_n=6.0)  # a 6 N swing on 15 N: outside ±3 N for about half the time
    c = PassCorrection.from_series(s, 0.8, "a slipping pass")
    assert c is not None and "held its force within ±20 %" in c.note and "< 90 %" in c.note
    assert not np.any(c.force_n) and not np.any(c.uv_m)
    assert c.at(8.0) == (0.0, 0.0, 0.0, 0.0, 0.0) and c.summary()["note"] == c.note


def test_a_series_that_cannot_teach_is_refused_in_one_line(tmp_path) -> None:
    s = _series()
    with pytest.raises(InputError, match=r"lacks rho_align.*--replan-learn-gain 0"):
        PassCorrection.from_series({k: v for k, v in s.items() if k != "rho_align"}, 0.8, "run A")
    with pytest.raises(InputError, match="evenly spaced"):
        PassCorrection.from_series({**s, "t": s["t"][::-1].copy()}, 0.8)
    with pytest.raises(InputError, match="evenly spaced"):
        PassCorrection.from_series({**s, "t": np.where(s["t"] > 3.0, np.nan, s["t"])}, 0.8)
    with pytest.raises(InputError, match=r"gain must lie in \[0, 1\]"):
        PassCorrection.from_series(s, 1.5)
    with pytest.raises(InputError, match=r"cannot read series\.npz"):
        PassCorrection.from_run(tmp_path, 0.8)
    assert PassCorrection.from_run(tmp_path, 0.0) is None  # gain 0 never reads it
    np.savez(tmp_path / "series.npz", **s)
    read = PassCorrection.from_run(tmp_path, 0.8)
    assert read is not None and read.source == str(tmp_path)
    assert read.force_n == pytest.approx(PassCorrection.from_series(s, 0.8).force_n)
