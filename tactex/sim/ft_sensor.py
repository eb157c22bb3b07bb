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
    """

    def __init__(self, tool_mass_kg: float, tool_com_m, tcp_offset_m: float, *, bias=None,
                 noise_n: float = 0.0, noise_nm: float = 0.0, cutoff_hz: float = 0.0, dt_s: float = 0.001,
                 gravity=None) -> None:
        self.mass = float(tool_mass_kg)
        self.com = np.asarray(tool_com_m, dtype=float).reshape(3)
        self.tcp = np.array([0.0, 0.0, float(tcp_offset_m)])
        self.bias = np.zeros(6) if bias is None else np.asarray(bias, dtype=float).reshape(6)
        self.noise = np.array([noise_n] * 3 + [noise_nm] * 3, dtype=float)
        self.alpha = 1.0 if cutoff_hz <= 0 else float(1.0 - np.exp(-2.0 * np.pi * cutoff_hz * dt_s))
        self.gravity = _GRAVITY_WORLD if gravity is None else np.asarray(gravity, dtype=float).reshape(3)
        self._filtered: np.ndarray | None = None
        # The model is affine in the raw reading and in the tool's weight in the sensor frame, w = m·Rᵀg:
        # wrench = T·(raw + bias + [w; c × w]) with T moving the moment to the TCP at (0, 0, L):
        # m_tcp = m + (−L·ẑ) × f. One 6×9 product per tick instead of a dozen scalar operations.
        length = float(self.tcp[2])
        moment_to_tcp = np.eye(6)
        moment_to_tcp[3, 1], moment_to_tcp[4, 0] = length, -length
        cx, cy, cz = self.com
        com_cross = np.array([[0.0, -cz, cy], [cz, 0.0, -cx], [-cy, cx, 0.0]])
        self._raw_to_tcp = moment_to_tcp
        self._weight_to_tcp = moment_to_tcp @ np.vstack([np.eye(3), com_cross])
        self._map = np.hstack([moment_to_tcp, self._weight_to_tcp])  # (6, 9) on [f_raw, m_raw, w]
        self._offset = moment_to_tcp @ self.bias if self.bias.any() else None
        self._mg = self.mass * self.gravity
        self._noisy = bool(self.noise.any())

    def reset(self) -> None:
        self._filtered = None

    def measure(self, raw_force: np.ndarray, raw_torque: np.ndarray, world_R_sensor: np.ndarray,
                rng: np.random.Generator | None = None) -> np.ndarray:
        """Contact wrench (6,) at the TCP, tool frame, [f (N), m (N·m)]; f_z > 0 when pressing."""
        weight = self._mg @ world_R_sensor  # m·Rᵀg: the tool's weight in the sensor frame
        wrench = self._map @ np.concatenate((raw_force, raw_torque, weight))
        if self._offset is not None:
            wrench += self._offset
        if rng is not None and self._noisy:
            wrench += self._raw_to_tcp @ (rng.normal(0.0, 1.0, 6) * self.noise)
        if self.alpha >= 1.0:
            return wrench  # a fresh array
        if self._filtered is None:
            self._filtered = wrench
        else:
            self._filtered = self._filtered + self.alpha * (wrench - self._filtered)
        return self._filtered.copy()
