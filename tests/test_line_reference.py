"""The commanded line of the contact phase (issue 21): led ahead of the agent along its step, its normal
leaning towards the captured surface under the tool."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.errors import ConfigError, InputError
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.pointcloud.shapes import CylinderWallSurface
from tactex.tasks.clean import CleanConfig, run_clean
from tactex.tasks.clean.line_reference import LineLead, ToolNormal, blend_normals


def _cup_cloud() -> SurfaceCloud:
    return CylinderWallSurface("cup", radius_m=0.04, height_m=0.10, arc_deg=180.0).sample(0.003)


def _radial(az_deg: float) -> np.ndarray:
    a = np.radians(az_deg)
    return np.array([np.cos(a), np.sin(a), 0.0])


def test_line_lead_is_the_agent_velocity_times_the_lead_and_never_jumps() -> None:
    step_s, dt = 0.05, 1e-3
    lead = LineLead(0.2, step_s, smoothing_s=0.05)
    a, b = np.zeros(3), np.array([0.003, 0.0, 0.0])  # 6 cm/s along x
    offsets = [lead.offset(a, b, dt) for _ in range(1000)]
    # settles at 0.2 s × 6 cm/s = 1.2 cm ahead, along the step
    assert np.allclose(offsets[-1], [0.012, 0.0, 0.0], atol=1e-6)
    # a held agent (a step of no length): the lead fades out, without a jump from one tick to the next
    held = [lead.offset(b, b, dt) for _ in range(1000)]
    steps = np.linalg.norm(np.diff(np.vstack([offsets[-1], *held]), axis=0), axis=1)
    assert steps.max() < 0.012 * dt / 0.05 * 1.01 and np.linalg.norm(held[-1]) < 1e-6
    # a new leg starts from no lead, the first tick moving it by the low-pass's share only
    lead.reset()
    assert np.allclose(lead.offset(a, b, dt), 0.012 * (1 - np.exp(-dt / 0.05)) * np.array([1.0, 0.0, 0.0]))
    assert np.allclose(LineLead(0.0, step_s).offset(a, b, dt), 0.0)
    with pytest.raises(InputError, match="lead_s"):
        LineLead(-0.1, step_s)
    with pytest.raises(InputError, match="smoothing_s"):
        LineLead(0.2, step_s, smoothing_s=0.0)


def test_tool_normal_is_the_surface_normal_where_the_tool_is() -> None:
    cloud = _cup_cloud()
    normal = ToolNormal(cloud)
    for az in (-150.0, -90.0, -37.0):
        # the pad centre a few millimetres inside the wall (the pad pressed in) at mid-height
        tcp = 0.036 * _radial(az) + np.array([0.0, 0.0, 0.05])
        n = normal.at(tcp)
        assert np.isclose(np.linalg.norm(n), 1.0)
        assert np.degrees(np.arccos(np.clip(n @ _radial(az), -1.0, 1.0))) < 2.0
    g = np.arange(-0.03, 0.031, 0.003)
    x, y = np.meshgrid(g, g)
    plane = SurfaceCloud(points=np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)]),
                         normals=np.tile([0.0, 0.0, 1.0], (x.size, 1)))
    assert np.allclose(ToolNormal(plane).at([0.01, -0.02, -0.004]), [0.0, 0.0, 1.0])
    with pytest.raises(InputError, match="normals"):
        ToolNormal(SurfaceCloud(points=plane.points))


def test_blend_normals_leans_from_the_agent_towards_the_tool() -> None:
    agent, tool = _radial(-60.0), _radial(-100.0)
    assert np.allclose(blend_normals(agent, tool, 0.0), agent)
    assert np.allclose(blend_normals(agent, tool, 1.0), tool)
    half = blend_normals(agent, tool, 0.5)
    assert np.isclose(np.linalg.norm(half), 1.0) and np.allclose(half, _radial(-80.0))
    # on a plane the feedback changes nothing
    z = np.array([0.0, 0.0, 1.0])
    assert np.allclose(blend_normals(z, z, 0.5), z)
    # the far side of a thin wall: opposed normals keep the agent's
    assert np.allclose(blend_normals(agent, -agent, 0.5), agent)


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"line_lead_s": -0.1}, "--line-lead-s"),
    ({"line_lead_s": float("nan")}, "--line-lead-s"),
    ({"line_lead_s": 2.0}, "--line-lead-s"),
    ({"line_normal_feedback": 1.5}, "--line-normal-feedback"),
    ({"line_normal_feedback": -0.5}, "--line-normal-feedback"),
])
def test_line_options_are_checked(kwargs, match) -> None:
    with pytest.raises(ConfigError, match=match):
        CleanConfig(**kwargs)


def _lateral_lag_and_peak(cfg: CleanConfig) -> tuple[float, float]:
    """Median distance [m] along the cup's wall between the tool and the agent while exploring in
    contact, and the run's peak contact force [N]."""
    res = run_clean(cfg, progress=False)
    s = res.series
    m = (s["phase"] == 3) & np.isfinite(s["agent"][:, 0]) & (s["force_z_n"] >= 0.5)
    centre = np.array([0.5, 0.0])  # the cup's axis (default object position)
    az = lambda p: np.arctan2(p[:, 1] - centre[1], p[:, 0] - centre[0])  # noqa: E731
    d_az = np.angle(np.exp(1j * (az(s["tcp"][m]) - az(s["agent"][m]))))
    arc = np.hypot(0.04 * d_az, s["tcp"][m][:, 2] - s["agent"][m][:, 2])
    return float(np.median(arc)), res.metrics["max_contact_force_n"]


@pytest.mark.slow
def test_the_led_line_keeps_the_tool_closer_to_the_agent_round_the_cup() -> None:
    """Without the lead and the normal feedback the tool trails the agent round the cup's wall by about 2 cm
    (median over the first 5 s of contact); with them by about 1.2 cm, within twice the set point. The explorer
    leads from the touch-down (no planned sweep): the lead is measured on its continuous path; a sweep's
    reversals, where a lead along the last step points the wrong way, are another matter. The joint moves run
    at 0.8 rad/s: their durations rank the touch-down's candidates, so the joint speed picks where the path
    starts, and these figures are for the path from that touch-down."""
    base = {"object_name": "cup", "marking": "X", "budget_s": 14.0, "sweep_corners": 0, "joint_speed_rad_s": 0.8}
    lag_off, _ = _lateral_lag_and_peak(CleanConfig(**base, line_lead_s=0.0, line_normal_feedback=0.0))
    lag_on, peak_on = _lateral_lag_and_peak(CleanConfig(**base))
    assert lag_on < 0.7 * lag_off
    assert peak_on <= 2.0 * CleanConfig().force_n
