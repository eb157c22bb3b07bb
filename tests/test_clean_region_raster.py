"""``tactex clean --baseline region_raster``: the plane-slicer raster over the captured dirt only, with the
same touch-down, controller, force and speeds as tactex, and the same re-measurement by the camera."""

from __future__ import annotations

import pytest

from tactex.errors import ConfigError
from tactex.tasks.clean import CleanConfig, run_clean


def test_the_region_raster_cleans_the_plate_and_re_measures() -> None:
    m = run_clean(CleanConfig(object_name="plate", baseline="region_raster"), progress=False).metrics
    assert m["aborted"] == ""
    assert m["dirt_removed_fraction"] >= 0.95
    assert m["vision_updates"] >= 1  # back to the camera after the raster, as tactex goes
    assert m["force_within_20pct_fraction"] >= 0.9
    assert m["torque_rate_clip_ticks"] == 0


def test_the_region_raster_takes_no_keep_out_zone() -> None:
    with pytest.raises(ConfigError, match="the region_raster baseline has no keep-out zones"):
        CleanConfig(baseline="region_raster", keep_out_channel="blue")
