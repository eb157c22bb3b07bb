"""F/T sensor model: tool gravity compensation, moment transfer to the TCP, bias, noise, low-pass."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.errors import ConfigError, MissingDependencyError
from tactex.robots import MujocoBackend
from tactex.sim import FTSensorModel, SceneConfig
from tactex.sim.objects import rotation_from_rpy_deg

G = np.array([0.0, 0.0, -9.81])


def _raw_for(model: FTSensorModel, rot: np.ndarray, f_env: np.ndarray, point_sensor: np.ndarray):
    """Raw reading (parent on child, sensor frame) for a tool at rest pushing f_env (sensor frame)
    on the environment at point_sensor: flange force = f_env − m g, flange moment balances both."""
    w = model.mass * (rot.T @ G)
    force = f_env - w
    moment = np.cross(point_sensor, f_env) - np.cross(model.com, w)
    return force, moment


@pytest.mark.parametrize("rpy", [(0, 0, 0), (180, 0, 0), (30, -40, 75)])
def test_gravity_is_compensated_and_the_wrench_moved_to_the_tcp(rpy):
    model = FTSensorModel(0.42, [0.001, -0.002, 0.07], 0.16)
    rot = rotation_from_rpy_deg(rpy)
    f_env = np.array([1.0, -2.0, 15.0])
    point = np.array([0.01, 0.02, 0.16])  # 1–2 cm off the TCP
    wrench = model.measure(*_raw_for(model, rot, f_env, point), rot)
    np.testing.assert_allclose(wrench[:3], f_env, atol=1e-12)
    np.testing.assert_allclose(wrench[3:], np.cross(point - [0, 0, 0.16], f_env), atol=1e-12)


def test_bias_noise_and_low_pass():
    rot = np.eye(3)
    bias = np.array([0.5, -0.2, 1.0, 0.01, 0.02, -0.03])
    biased = FTSensorModel(0.0, np.zeros(3), 0.0, bias=bias)
    np.testing.assert_allclose(biased.measure(np.zeros(3), np.zeros(3), rot), bias)
    noisy = FTSensorModel(0.0, np.zeros(3), 0.0, noise_n=0.3, noise_nm=0.01)
    rng = np.random.default_rng(0)
    samples = np.array([noisy.measure(np.zeros(3), np.zeros(3), rot, rng) for _ in range(4000)])
    np.testing.assert_allclose(samples.std(axis=0), [0.3] * 3 + [0.01] * 3, rtol=0.06)
    cutoff, dt = 10.0, 0.001
    filt = FTSensorModel(0.0, np.zeros(3), 0.0, cutoff_hz=cutoff, dt_s=dt)
    filt.measure(np.zeros(3), np.zeros(3), rot)
    tau = 1.0 / (2 * np.pi * cutoff)
    n = round(tau / dt)
    out = [filt.measure(np.array([0.0, 0.0, 10.0]), np.zeros(3), rot)[2] for _ in range(n)]
    assert out[-1] == pytest.approx(10.0 * (1 - np.exp(-1)), rel=0.02)  # one time constant: 63 %


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"cutoff_hz": float("nan")}, "cutoff_hz"), ({"cutoff_hz": -1.0}, "cutoff_hz"), ({"dt_s": 0.0}, "dt_s"),
    ({"tool_mass_kg": float("inf")}, "tool_mass_kg"), ({"tool_mass_kg": -0.1}, "tool_mass_kg"),
    ({"noise_n": -0.1}, "noise_n"), ({"tool_com_m": [0.0, 0.0]}, "tool_com_m"), ({"bias": [np.nan] * 6}, "bias"),
])
def test_ft_sensor_model_rejects_bad_parameters(kwargs, match):
    """A NaN cut-off made every reading after the first NaN; dt = 0 froze the filter."""
    args = {"tool_mass_kg": 0.2, "tool_com_m": np.zeros(3), "tcp_offset_m": 0.1, **kwargs}
    with pytest.raises(ConfigError, match=match):
        FTSensorModel(args.pop("tool_mass_kg"), args.pop("tool_com_m"), args.pop("tcp_offset_m"), **args)


def test_configured_bias_reaches_the_state():
    backend = MujocoBackend(SceneConfig(object_name="plane", ft_bias=(0.0, 0.0, 2.0, 0.0, 0.0, 0.0)))
    s = backend.step()
    assert s.wrench_tool[2] == pytest.approx(2.0, abs=1e-3)


def test_gl_and_viewer_are_guarded(monkeypatch):
    backend = MujocoBackend(SceneConfig(object_name="plane", camera_width=8, camera_height=8))
    monkeypatch.setenv("MUJOCO_GL", "disable")
    with pytest.raises(MissingDependencyError, match="OpenGL"):
        backend.render_rgb(32, 24)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(MissingDependencyError, match="display"):
        backend.launch_viewer()


def test_render_without_gl_backend_or_display_refuses_cleanly_every_time(monkeypatch):
    """No MUJOCO_GL and no display: MuJoCo would fall back to GLFW, whose failed start aborts the
    process on the next attempt; the backend must refuse before touching it, every time."""
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    backend = MujocoBackend(SceneConfig(object_name="plane"))
    for _ in range(2):
        with pytest.raises(MissingDependencyError, match="MUJOCO_GL=egl"):
            backend.render_rgb(32, 24)
