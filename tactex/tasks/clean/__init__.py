"""Tactile ergodic cleaning (TEC §V-A, Fig. 3, Fig. 12) in simulation or on a Franka.

The state machine of TEC §V-A3, a method each of :class:`~tactex.tasks.clean.program.CleanProgram`:

1. **capture** — joint move to a capture pose, take an RGB-D frame, pre-process it (crop, voxel
   grid, outlier removal) and segment the dirt by colour: the target distribution;
2. **plan** — while the robot holds still, the Laplacian eigenbasis and the path the agent follows; the
   first touch-down is on the dirt the arm reaches soonest from the capture pose (the raster's: its
   waypoint nearest the dirt nearest the camera);
3. **approach** — hover over the agent and move along its normal line until the tool touches;
   **explore** — each tick the GA line-and-force controller tracks the normal line of the HEDAC agent
   and presses with the set force; the agent steps at ``explorer_rate_hz``;
4. **remeasure** — the robot returns to the capture pose, re-measures the remaining dirt and updates the
   target on the same points (no new basis), then goes back to contact. The run stops when vision sees
   less than ``stop_remaining`` of the initial dirt, or when the time budget ends (**finish**: a lift-off
   and the result).

When to return to the camera, and what the agent follows until then, is ``objective``:
``ergodic`` is TEC's loop (the captured dirt as the coverage target of eq. 2, a trip every
``vision_every_steps``, about 200 in TEC §VI-B); ``clean`` (the default) makes the target the
captured dirt minus what the robot's own Preston wear model says it has removed
(:class:`~tactex.tasks.wear_model.WearModel`), so clean points stop attracting, and returns when
that model says the dirt is gone or stops falling. An island of dirt smaller than the pad gets a
straight stroke instead of the agent, and the robot slides in contact to the next island when that is
quicker than a lift-off (:mod:`tactex.tasks.stroke`). Each tick is accounted in a time breakdown
(:mod:`tactex.tasks.clean.time_breakdown`).

Baselines (same controller, force and robot): ``raster`` — a boustrophedon path over the whole
surface; ``no_feedback`` — HEDAC on the first capture only, never re-measuring.

Modules: :mod:`.config` (the parameters), :mod:`.program` (the phases), :mod:`.records` (the recorded
series and the result), :mod:`.motion` (poses and moves out of contact), :mod:`.legs` (what the agent
follows from a touch-down), :mod:`.target` (a user's cloud as the target).
"""

from __future__ import annotations

from tactex.tasks.clean.config import CLEAN_BASELINES, CLEAN_EXPLORER, CLEAN_OBJECTIVES, SWEEP_GOAL, CleanConfig
from tactex.tasks.clean.legs import SWEEP_MIN_SHARE, _first_leg, _Legs
from tactex.tasks.clean.motion import (
    APPROACH_GAIN_PER_S,
    START_CANDIDATES,
    START_SPACING_M,
    _acquisition,
    _approach_speed,
    _capture_pose,
    _hover_plan,
    _pad_over_support,
    _quickest_touch_down,
)
from tactex.tasks.clean.program import CleanProgram, run_clean
from tactex.tasks.clean.records import PHASES, CleanResult
from tactex.tasks.clean.target import load_target_cloud, load_target_cloud_keep_out

__all__ = [
    "APPROACH_GAIN_PER_S",
    "CLEAN_BASELINES",
    "CLEAN_EXPLORER",
    "CLEAN_OBJECTIVES",
    "PHASES",
    "START_CANDIDATES",
    "START_SPACING_M",
    "SWEEP_GOAL",
    "SWEEP_MIN_SHARE",
    "CleanConfig",
    "CleanProgram",
    "CleanResult",
    "_Legs",
    "_acquisition",
    "_approach_speed",
    "_capture_pose",
    "_first_leg",
    "_hover_plan",
    "_pad_over_support",
    "_quickest_touch_down",
    "load_target_cloud",
    "load_target_cloud_keep_out",
    "run_clean",
]
