"""``tactex clean --baseline region_raster``: the plane-slicer raster over the captured dirt only, with the
same touch-down, controller, force and speeds as tactex, and the same re-measurement by the camera."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.errors import ConfigError
from tactex.pointcloud.markings import marked_cloud
from tactex.pointcloud.shapes import get_surface
from tactex.tasks.clean import CleanConfig, run_clean
from tactex.tasks.ideal_time import dirty_area_m2


@pytest.fixture(scope="module")
def plate_metrics() -> dict:
    return run_clean(CleanConfig(object_name="plate", baseline="region_raster"), progress=False).metrics


def test_the_region_raster_cleans_the_plate_and_re_measures(plate_metrics) -> None:
    m = plate_metrics
    assert m["aborted"] == ""
    assert m["dirt_removed_fraction"] >= 0.95
    assert m["vision_updates"] >= 1  # back to the camera after the raster, as tactex goes
    assert m["force_within_20pct_fraction"] >= 0.9
    assert m["torque_rate_clip_ticks"] == 0


def test_the_region_raster_takes_no_keep_out_zone() -> None:
    with pytest.raises(ConfigError, match="the region_raster baseline has no keep-out zones"):
        CleanConfig(baseline="region_raster", keep_out_channel="blue")


def test_a_clean_reports_its_physical_bound(plate_metrics) -> None:
    m, cfg = plate_metrics, CleanConfig()
    parts = m["ideal_time_parts_s"]
    assert m["ideal_time_s"] == pytest.approx(sum(parts.values()))
    # the captured dirt's area is the marking's (the X on the plate, from the object's own surface) to 15 %
    truth = dirty_area_m2(marked_cloud(get_surface("plate"), "X", cfg.voxel_size_m))
    assert m["dirty_area_m2"] == pytest.approx(truth, rel=0.15)
    speed_m_s = cfg.max_velocity * cfg.voxel_size_m * cfg.explorer_rate_hz
    assert parts["sliding"] == pytest.approx(m["dirty_area_m2"] / (cfg.lane_spacing_m * speed_m_s), rel=0.05)
    # the first capture as the run spent it (the time to 95 % holds it), a joint move to dirt, the fall from the hover
    assert 0.0 < parts["capture"] <= m["time_breakdown_to_95pct_s"]["vision"] + 1e-9
    assert 0.2 < parts["transit"] <= m["time_breakdown_to_95pct_s"]["transit"]
    assert parts["touch_down"] == pytest.approx(cfg.hover_height_m / cfg.approach_speed_m_s)
    # no method beats it: the raster's own time to 95 % lies above it
    assert m["ideal_time_s"] < m["time_to_95pct_s"]
    assert m["time_to_95pct_over_ideal"] == pytest.approx(m["time_to_95pct_s"] / m["ideal_time_s"])


def test_a_raster_touch_down_out_of_reach_goes_on_along_the_path(monkeypatch) -> None:
    """A raster's hover the arm cannot reach (a bowl's rim beside the robot) is passed by: the raster goes on
    along its path and touches down where the arm reaches, instead of ending the run with an IK error."""
    from tactex.errors import SimulationError
    from tactex.tasks.clean import motion

    plan = motion._hover_plan
    refused: list[np.ndarray] = []

    def hover_plan(loop, point_m, *args, **kwargs):
        if not refused and "q_hover" not in kwargs:  # the approach's first hover (not the bound's planning)
            refused.append(np.asarray(point_m, dtype=float).copy())
            raise SimulationError("IK did not reach the target")
        return plan(loop, point_m, *args, **kwargs)

    monkeypatch.setattr(motion, "_hover_plan", hover_plan)
    with pytest.warns(RuntimeWarning, match="the region raster goes on at"):
        m = run_clean(CleanConfig(object_name="plate", baseline="region_raster", budget_s=8.0), progress=False).metrics
    assert refused and m["contact_time_s"] > 2.0 and m["dirt_removed_fraction"] > 0.2
