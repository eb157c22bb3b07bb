"""The controllers on an arm that is not the one they assume (issue 40): the tool's mass mis-set by
±50 % in the robot's load (its gravity compensation keeps the nominal tool; the F/T is calibrated with
the tool as it is), twice the joint friction (viscous, plus 0.2 N·m dry per joint), one extra cycle of
command delay. Each nominal wipe and clean in simulation keeps its force within ±20 % of the set point
for ≥ 90 % of its contact. The wipe never meets the torque-rate limit; the clean meets it for a few
ticks on its worst cases (6 ticks in 12 s with the tool at half its declared mass, 2 with twice the
friction, measured), each a force step of a touch-down or a stick–slip in the GA force loop (a 1.5 N
step in one tick), clipped 1 % below the robot's limit (tests/test_control_safety.py).
"""

from __future__ import annotations

import pytest

from tactex.tasks.clean import CleanConfig, run_clean
from tactex.tasks.wipe import WipeConfig, run_wipe

pytestmark = pytest.mark.slow

#: One injected mismatch per case: the config fields a task takes.
MISMATCHES = {
    "tool_mass_x0.5": {"tool_mass_scale": 0.5},
    "tool_mass_x1.5": {"tool_mass_scale": 1.5},
    "joint_friction_x2": {"joint_friction_scale": 2.0},
    "command_delay_+1": {"command_delay_ticks": 1},
}


@pytest.mark.parametrize("case", sorted(MISMATCHES))
def test_wipe_under_model_mismatch(case: str) -> None:
    m = run_wipe(WipeConfig(duration_s=8.0, **MISMATCHES[case]), progress=False).metrics
    assert m["aborted"] == ""
    assert m["torque_rate_clip_ticks"] == 0
    assert m["force_within_20pct_fraction"] >= 0.9, m["force_within_20pct_fraction"]


#: Not met yet (issue 40), measured: with the tool 1.5× its declared mass the clean keeps its 10 N within
#: ±20 % for 86 % of its contact. The unmodelled 0.21 kg weighs 2.1 N, as large as the band itself; the GA
#: force loop's integral removes it only some time after each touch-down, and the clean touches down often.
#: (The wipe's 15 N set point tolerates it: 97 %.)
CLEAN_NOT_MET = {"tool_mass_x1.5": "a 2.1 N load error is the whole ±20 % band of the clean's 10 N: 86 % within"}


@pytest.mark.parametrize("case", [pytest.param(c, marks=pytest.mark.xfail(strict=True, reason=CLEAN_NOT_MET[c]))
                                  if c in CLEAN_NOT_MET else c for c in sorted(MISMATCHES)])
def test_clean_under_model_mismatch(case: str) -> None:
    m = run_clean(CleanConfig(object_name="plate", budget_s=12.0, **MISMATCHES[case]), progress=False).metrics
    assert m["aborted"] == ""
    assert m["torque_rate_clip_ticks"] <= 10  # 0 nominal; see the module docstring
    assert m["force_within_20pct_fraction"] >= 0.9, m["force_within_20pct_fraction"]
