"""What a second pass of the same policy learns from the first: the errors the first pass made at each moment of
the policy, fed forward (one iteration of iterative learning control, P-type with a zero-phase low-pass filter;
Bristow, Tharayil and Alleyne, "A survey of iterative learning control", IEEE Control Systems 26(3), 2006).

A wipe repeats: the same policy on the same part from the same start meets the same friction, the same
curvature and the same controller lag at the same policy time. The first pass's series holds, per recorded
tick, the normal force's error against the policy's set point [N] and the TCP's in-plane error in the tool
frame [m]. The second pass commands, at policy time τ,

    f_cmd(τ) = f_set(τ) − g · LP[f − f_set](τ),        (u, v)_cmd(τ) = (u, v)(τ) − g · LP[e_x, e_y](τ),

with ``g`` the learning gain and LP a second-order Butterworth low-pass run forwards and backwards (no lag):
what repeats is slow (the policy's own rates), what is faster is noise the next pass will not see again.
The force is learned over the first pass's contact from :data:`SETTLE_S` after its first contact, aligned or not:
with VA-UFIC's tangential hold the tool stays where it touched down while the controller is compliant, so the
force error of that phase repeats too, and the wipe applies the force correction over the whole second pass.
The in-plane motion is learned over the aligned contact ticks only (ρ_align = 1), where the controller tracks
what it is given: while the alignment monitor keeps VA-UFIC compliant the desired position follows the tool on
purpose, and the wipe applies that correction from the moment the second pass aligns
(:class:`~tactex.tasks.wipe_references.WipeReferences`). Elsewhere the error counts as zero, so the corrections
fade in and out through the filter. A first pass that did not hold its force
(:data:`LEARN_MIN_HELD`) teaches nothing. Both corrections are bounded (:data:`MAX_FORCE_SHARE`,
:data:`MAX_OFFSET_M`). The second pass's figures stay measured against the policy's own set point and path,
not the corrected commands.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
from scipy.signal import butter, filtfilt

from tactex.errors import InputError

__all__ = ["FORCE_CUTOFF_HZ", "MAX_FORCE_SHARE", "MAX_OFFSET_M", "MOTION_CUTOFF_HZ", "SETTLE_S", "PassCorrection"]

#: The low-pass's cut-off on the force error [Hz]: above the policies' rates (a 2 rad/s sinusoid is 0.3 Hz),
#: below the contact's own ring (about 3 Hz at a touch-down), which a feed-forward at its frequency would excite.
FORCE_CUTOFF_HZ = 1.0
#: The low-pass's cut-off on the motion error [Hz]: a zigzag's turns have harmonics above its rate.
MOTION_CUTOFF_HZ = 4.0
#: The force is learned from this long after the first pass's first contact [s]: the touch-down's ring is a
#: transient the correction would excite, not a repeating error it could remove.
SETTLE_S = 1.0
#: Largest force correction, as a share of the set point at that moment [-].
MAX_FORCE_SHARE = 0.3
#: Largest in-plane correction, per axis [m].
MAX_OFFSET_M = 0.006
#: A pass teaches only if its force stayed within ±HELD_BAND of the set point for at least LEARN_MIN_HELD of its
#: contact ticks (the wipe's own ±20 % figure): one that slipped or lost the part erred where the next pass, on
#: the explored surface, will not be at that moment.
HELD_BAND = 0.2
LEARN_MIN_HELD = 0.9
#: The correction fades out over the last this long of the pass [s].
TAPER_S = 0.5
#: ρ_align from which a first-pass tick counts as aligned [-].
ALIGNED_RHO = 1.0 - 1e-6
#: The series a first pass must hold.
SERIES_KEYS = ("t", "force_z_n", "force_set_n", "motion_error_tool", "in_contact", "rho_align")


class PassCorrection:
    """Force and in-plane corrections over policy time, learned from one pass's series.

    Args:
        t_s: (N,) recorded policy times [s], increasing and evenly spaced.
        force_n: (N,) force correction [N] (added to the set point).
        uv_m: (N, 2) in-plane correction in the tool frame [m] (added to the policy's offsets).
        gain: the learning gain it was made with [-].
        source: where the pass came from (messages, metrics).
    """

    def __init__(self, t_s: np.ndarray, force_n: np.ndarray, uv_m: np.ndarray, gain: float, source: str = "",
                 note: str = "") -> None:
        self.note = note  # why nothing was learned ("" when something was)
        self.t_s = np.asarray(t_s, dtype=float)
        self.force_n = np.asarray(force_n, dtype=float)
        self.uv_m = np.asarray(uv_m, dtype=float).reshape(-1, 2)
        self.gain, self.source = float(gain), source
        self._t0 = float(self.t_s[0])
        self._dt = float(self.t_s[1] - self.t_s[0])
        # per-tick lookups in plain floats: this runs between a robot state and its command
        self._f = self.force_n.tolist()
        self._u = self.uv_m[:, 0].tolist()
        self._v = self.uv_m[:, 1].tolist()
        du = np.gradient(self.uv_m, self._dt, axis=0)
        self._du, self._dv = du[:, 0].tolist(), du[:, 1].tolist()

    @classmethod
    def from_series(cls, series: Mapping[str, np.ndarray], gain: float, source: str = "") -> PassCorrection | None:
        """The correction a pass whose recorded ``series`` (a wipe's ``series.npz``) calls for, with learning gain
        ``gain`` in [0, 1]; None when ``gain`` is 0 or the pass never touched. Raises :class:`InputError` for a
        series that lacks what it needs or holds non-finite times."""
        if not (np.isfinite(gain) and 0.0 <= gain <= 1.0):
            raise InputError(f"the learning gain must lie in [0, 1], got {gain!r}")
        where = f" of {source}" if source else ""
        missing = [k for k in SERIES_KEYS if k not in series]
        if missing:
            raise InputError(f"the series{where} lacks {', '.join(missing)}: re-run that wipe with this tactex, or "
                             "set --replan-learn-gain 0 to re-plan on its surface only")
        t = np.asarray(series["t"], dtype=float).reshape(-1)
        if gain == 0.0 or len(t) < 8:
            return None
        step = np.diff(t)
        if not (np.isfinite(t).all() and (step > 0).all() and np.ptp(step) <= 0.5 * float(np.median(step))):
            raise InputError(f"the series{where} has times that are not finite, increasing and evenly spaced")
        err_f = np.asarray(series["force_z_n"], dtype=float) - np.asarray(series["force_set_n"], dtype=float)
        err_xy = np.asarray(series["motion_error_tool"], dtype=float).reshape(len(t), 3)[:, :2]
        contact = (np.asarray(series["in_contact"], dtype=float) > 0.5) & np.isfinite(err_f)
        if not contact.any():
            return None
        f_set = np.abs(np.asarray(series["force_set_n"], dtype=float))
        dt = float(np.median(step))
        grid = t[0] + dt * np.arange(len(t))
        held = float(np.mean(np.abs(err_f[contact]) <= HELD_BAND * f_set[contact]))
        if held < LEARN_MIN_HELD:
            return cls(grid, np.zeros(len(t)), np.zeros((len(t), 2)), gain, source, note=(
                f"the pass held its force within ±{100 * HELD_BAND:.0f} % of the set point for {100 * held:.0f} % of "
                f"its contact (< {100 * LEARN_MIN_HELD:.0f} %): it slipped or lost the part, so its errors do not "
                "repeat"))
        aligned = contact & (np.asarray(series["rho_align"], dtype=float) >= ALIGNED_RHO)
        settled = contact & (t >= t[np.argmax(contact)] + SETTLE_S)
        force = -gain * _low_pass(dt, FORCE_CUTOFF_HZ)(np.where(settled, err_f, 0.0))
        tracked = aligned & np.isfinite(err_xy).all(axis=1)
        uv = -gain * _low_pass(dt, MOTION_CUTOFF_HZ)(np.where(tracked[:, None], err_xy, 0.0))
        bound = MAX_FORCE_SHARE * np.where(np.isfinite(f_set), f_set, 0.0)
        force = np.clip(np.nan_to_num(force), -bound, bound)
        uv = np.clip(np.nan_to_num(uv), -MAX_OFFSET_M, MAX_OFFSET_M)
        # faded out over the pass's last TAPER_S: the run ends with the policy and lifts the tool off, and a
        # correction cut there would step the commands
        taper = np.clip((t[-1] - t) / TAPER_S, 0.0, 1.0)
        return cls(grid, force * taper, uv * taper[:, None], gain, source)

    @classmethod
    def from_run(cls, run_dir: Path, gain: float) -> PassCorrection | None:
        """The correction the wipe whose run folder is ``run_dir`` calls for (its ``series.npz``); None when
        ``gain`` is 0. Raises :class:`InputError` when the folder holds no readable series."""
        if gain == 0.0:
            return None
        path = Path(run_dir) / "series.npz"
        try:
            with np.load(path, allow_pickle=False) as data:
                series = {k: data[k] for k in SERIES_KEYS if k in data.files}
        except (OSError, ValueError) as exc:
            raise InputError(f"--replan-from {run_dir}: cannot read series.npz ({exc}); the re-plan learns from "
                             "the first pass's series: give a wipe's whole run folder, or --replan-learn-gain 0"
                             ) from None
        return cls.from_series(series, gain, str(run_dir))

    def at(self, tau_s: float) -> tuple[float, float, float, float, float]:
        """(force [N], u [m], v [m], du/dt [m/s], dv/dt [m/s]) at policy time ``tau_s``, linearly interpolated;
        zero outside the learned span."""
        x = (tau_s - self._t0) / self._dt
        i = int(x)
        if x < 0.0 or i >= len(self._f) - 1:
            return 0.0, 0.0, 0.0, 0.0, 0.0
        w = x - i
        f, u, v, du, dv = self._f, self._u, self._v, self._du, self._dv
        return (f[i] + w * (f[i + 1] - f[i]), u[i] + w * (u[i + 1] - u[i]), v[i] + w * (v[i + 1] - v[i]),
                du[i] + w * (du[i + 1] - du[i]), dv[i] + w * (dv[i + 1] - dv[i]))

    def summary(self) -> dict:
        """The correction's size, for the run's metrics."""
        return {"gain": self.gain, "note": self.note, "from": self.source,
                "cutoff_hz": {"force": FORCE_CUTOFF_HZ, "motion": MOTION_CUTOFF_HZ},
                "force_rms_n": float(np.sqrt(np.mean(self.force_n**2))),
                "force_max_abs_n": float(np.max(np.abs(self.force_n))),
                "offset_rms_m": [float(x) for x in np.sqrt(np.mean(self.uv_m**2, axis=0))],
                "offset_max_abs_m": float(np.max(np.abs(self.uv_m)))}


def _low_pass(dt_s: float, cutoff_hz: float):
    """A zero-phase low-pass at ``cutoff_hz`` (capped below the series' Nyquist rate) for series of spacing
    ``dt_s`` [s], along axis 0."""
    nyquist = 0.5 / dt_s
    b, a = butter(2, min(cutoff_hz, 0.8 * nyquist) / nyquist)

    def smooth(x: np.ndarray) -> np.ndarray:
        pad = min(3 * max(len(a), len(b)), len(x) - 1)
        return filtfilt(b, a, x, axis=0, padlen=pad)

    return smooth
