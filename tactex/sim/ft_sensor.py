"""The wrist force/torque sensor as a real one reads: calibrated for the tool, optionally biased,
noisy and low-pass filtered.

MuJoCo's ``force``/``torque`` sensors at the sensor site give the wrench the flange exerts on the
tool subtree, in the site frame, about the site. The contact wrench the tool exerts on the
environment follows from the tool's static balance: f_env = f_raw + m·g, m_env = m_raw + c × m·g,
with the calibrated tool mass m and centre of mass c (what the TEC authors' calibration removes);
it is then moved to the TCP, which lies on the sensor's z axis.
"""

from __future__ import annotations

import numpy as np

from tactex.errors import ConfigError

__all__ = ["FTSensorModel"]

_GRAVITY_WORLD = np.array([0.0, 0.0, -9.81])


class FTSensorModel:
    """Raw MuJoCo F/T readings → calibrated contact wrench at the TCP in the tool frame.

    Args:
        tool_mass_kg: calibrated tool mass below the sensor [kg].
        tool_com_m: (3,) its centre of mass in the sensor frame [m].
        tcp_offset_m: TCP position on the sensor z axis [m].
        bias: (6,) constant offset added to the raw reading [N, N·m].
        noise_n, noise_nm: white noise standard deviations [N], [N·m].
        cutoff_hz: first-order low-pass cut-off [Hz] (0 disables); dt_s: sample period [s].
        gravity: (3,) gravity in the world [m/s²].

    The parameters are read once, at construction.
    """

    def __init__(self, tool_mass_kg: float, tool_com_m, tcp_offset_m: float, *, bias=None,
                 noise_n: float = 0.0, noise_nm: float = 0.0, cutoff_hz: float = 0.0, dt_s: float = 0.001,
                 gravity=None) -> None:
        for name, v, lo in (("tool_mass_kg", tool_mass_kg, 0.0), ("tcp_offset_m", tcp_offset_m, None),
                            ("noise_n", noise_n, 0.0), ("noise_nm", noise_nm, 0.0), ("cutoff_hz", cutoff_hz, 0.0)):
            if not np.isfinite(v) or (lo is not None and v < lo):
                raise ConfigError(f"FTSensorModel: {name} must be finite" + (" and ≥ 0" if lo is not None else "")
                                  + f", got {v!r}")
        if not (np.isfinite(dt_s) and dt_s > 0):
            raise ConfigError(f"FTSensorModel: dt_s must be finite and > 0 [s], got {dt_s!r}")
        for name, v, n in (("tool_com_m", tool_com_m, 3), ("bias", bias, 6), ("gravity", gravity, 3)):
            if v is not None and (np.shape(v) != (n,) or not np.isfinite(np.asarray(v, dtype=float)).all()):
                raise ConfigError(f"FTSensorModel: {name} must be {n} finite numbers, got {v!r}")
        self.mass = float(tool_mass_kg)
        self.com = np.asarray(tool_com_m, dtype=float).reshape(3)
        self.tcp = np.array([0.0, 0.0, float(tcp_offset_m)])
        self.bias = np.zeros(6) if bias is None else np.asarray(bias, dtype=float).reshape(6)
        self.noise = np.array([noise_n] * 3 + [noise_nm] * 3, dtype=float)
        self.alpha = 1.0 if cutoff_hz <= 0 else float(1.0 - np.exp(-2.0 * np.pi * cutoff_hz * dt_s))
        self.gravity = _GRAVITY_WORLD if gravity is None else np.asarray(gravity, dtype=float).reshape(3)
        self._filtered: np.ndarray | None = None
        # plain floats for the 1 kHz path: a handful of scalar operations beat numpy's per-call overhead
        self._mg = (self.mass * self.gravity).tolist()
        self._com = self.com.tolist()
        self._length = float(self.tcp[2])
        self._bias = self.bias.tolist() if self.bias.any() else None
        self._noisy = bool(self.noise.any())

    def reset(self) -> None:
        self._filtered = None

    def measure(self, raw_force: np.ndarray, raw_torque: np.ndarray, world_R_sensor: np.ndarray,
                rng: np.random.Generator | None = None) -> np.ndarray:
        """Contact wrench (6,) at the TCP, tool frame, [f (N), m (N·m)]; f_z > 0 when pressing."""
        fx, fy, fz = np.asarray(raw_force, dtype=float).tolist()
        mx, my, mz = np.asarray(raw_torque, dtype=float).tolist()
        if self._bias is not None:
            bfx, bfy, bfz, bmx, bmy, bmz = self._bias
            fx, fy, fz, mx, my, mz = fx + bfx, fy + bfy, fz + bfz, mx + bmx, my + bmy, mz + bmz
        if rng is not None and self._noisy:
            nfx, nfy, nfz, nmx, nmy, nmz = (rng.normal(0.0, 1.0, 6) * self.noise).tolist()
            fx, fy, fz, mx, my, mz = fx + nfx, fy + nfy, fz + nfz, mx + nmx, my + nmy, mz + nmz
        # the tool's weight in the sensor frame, w = m·Rᵀg
        r = np.asarray(world_R_sensor).tolist()
        g0, g1, g2 = self._mg
        w0 = r[0][0] * g0 + r[1][0] * g1 + r[2][0] * g2
        w1 = r[0][1] * g0 + r[1][1] * g1 + r[2][1] * g2
        w2 = r[0][2] * g0 + r[1][2] * g1 + r[2][2] * g2
        fx, fy, fz = fx + w0, fy + w1, fz + w2
        cx, cy, cz = self._com
        mx += cy * w2 - cz * w1
        my += cz * w0 - cx * w2
        mz += cx * w1 - cy * w0
        # move the moment from the sensor origin to the TCP at (0, 0, L): m_tcp = m + (−L·ẑ) × f
        length = self._length
        wrench = np.array((fx, fy, fz, mx + length * fy, my - length * fx, mz))
        if self.alpha >= 1.0:
            return wrench  # a fresh array
        if self._filtered is None:
            self._filtered = wrench
        else:
            self._filtered = self._filtered + self.alpha * (wrench - self._filtered)
        return self._filtered.copy()
