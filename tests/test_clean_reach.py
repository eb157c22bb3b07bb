"""Where the arm cannot go on in a clean (tactex.tasks.clean.reach): a tool that can no longer follow its agent
is noticed, and the program touches down again once, then moves on."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from tactex.ergodic.command import ExplorationCommand
from tactex.tasks.clean import reach

PAD_R = 0.025
SET_N = 10.0  # the set point: held back counts from 1.8 times it


def _cmd() -> ExplorationCommand:
    z = np.zeros(3)
    return ExplorationCommand(point=z.copy(), velocity=z.copy(), normal=np.array([0.0, 0.0, 1.0]),
                              tangent_u=np.array([1.0, 0.0, 0.0]), tangent_v=np.array([0.0, 1.0, 0.0]), step=0, agent=0)


def _loop(tcp, force_n, repelling=False):
    state = SimpleNamespace(ee_position=np.asarray(tcp, dtype=float),
                            wrench_tool=np.array([0.0, force_n * 0.6, force_n * 0.8, 0.0, 0.0, 0.0]))
    return SimpleNamespace(state=state, safety=SimpleNamespace(repelling=repelling))


@pytest.mark.parametrize(("tcp", "force_n", "repelling", "why"), [
    ((0.004, 0.0, 0.0), 10.0, False, None),  # keeping up at the set point
    ((0.030, 0.0, 0.0), 10.0, False, None),  # behind, but not held back: the agent waits for it
    ((0.010, 0.0, 0.0), 20.0, False, None),  # pressed hard, but near where the agent is
    ((0.030, 0.0, 0.0), 17.0, False, None),  # behind, climbing a wall: the agent waits for it
    ((0.0, 0.0, 0.040), 20.0, False, None),  # off the point along the normal only: no lag along the surface
    ((0.015, 0.0, 0.0), 20.0, False, "held the tool back"),  # over half a pad radius behind, held back
    ((0.0, 0.0, 0.0), 10.0, True, "limit"),  # a joint at its limit's margin
])
def test_cannot_follow(tcp, force_n, repelling, why):
    said = reach.cannot_follow(_loop(tcp, force_n, repelling), _cmd(), PAD_R, SET_N)
    assert (said is None) == (why is None)
    if why is not None:
        assert why in said


class _Wear:
    def __init__(self, island):
        self.island, self.asked = island, []

    def next_island(self, here_m, tried_m, clearance_m, allowed=None):
        self.asked.append((np.asarray(here_m).copy(), [t.copy() for t in tried_m], clearance_m))
        return self.island


def test_regrip_touches_down_again_once_then_moves_on():
    wear, regrips, tried = _Wear(np.array([0.2, 0.0, 0.0])), [], []
    here = np.array([0.0, 0.0, 0.0])
    # the first time: the same point, from a posture planned afresh
    assert np.array_equal(reach.regrip_at(here, regrips, wear, tried, PAD_R, None), here)
    assert wear.asked == [] and tried == []
    # elsewhere (beyond two pad radii): again the same point
    far = np.array([0.06, 0.0, 0.0])
    assert np.array_equal(reach.regrip_at(far, regrips, wear, tried, PAD_R, None), far)
    # near the first again: the next island, this point tried
    near = np.array([0.01, 0.0, 0.0])
    assert np.array_equal(reach.regrip_at(near, regrips, wear, tried, PAD_R, None), wear.island)
    assert len(tried) == 1 and np.array_equal(tried[0], near)
    assert wear.asked[0][2] == pytest.approx(2 * PAD_R)
    # no island left: None (the camera judges)
    assert reach.regrip_at(near, regrips, _Wear(None), tried, PAD_R, None) is None


def test_a_hover_out_of_reach_moves_on_with_a_warning():
    tried = []
    with pytest.warns(RuntimeWarning, match="moving on to the dirt at"):
        island = reach.past_hover(np.zeros(3), _Wear(np.array([0.1, 0.0, 0.0])), tried, PAD_R, None)
    assert island is not None and len(tried) == 1
    with pytest.warns(RuntimeWarning, match="ending the program"):
        assert reach.past_hover(np.zeros(3), _Wear(None), tried, PAD_R, None) is None


class _TickLoop:
    """Records the references a lift-off ticks (1 ms each) and retracts nothing."""

    def __init__(self):
        self.t, self.refs, self.retracted = 0.0, [], 0.0

    def tick(self, ref, after_send=None):
        self.refs.append(ref)
        self.t += 0.001

    def retract(self, distance_m, duration_s):
        self.retracted += distance_m


def test_a_lift_off_unloads_on_a_line_that_slides_smoothly_to_where_the_tool_is():
    from tactex.control.references import LineForceReference
    from tactex.tasks.clean.motion import UNLOAD_S, _lift_off

    pressing = LineForceReference(np.zeros(3), np.array([0.0, 0.0, 1.0]), 15.0)
    tool = np.array([0.015, -0.01, 0.0])
    loop = _TickLoop()
    _lift_off(loop, 0.05, pressing=pressing, release_at_m=tool)
    points = np.array([r.point_world for r in loop.refs])
    forces = np.array([r.force_n for r in loop.refs])
    assert len(loop.refs) == pytest.approx(UNLOAD_S / 0.001, abs=2)
    assert np.linalg.norm(points[0]) < 1e-6  # starts on the agent's line: no step at the hand-over
    assert np.linalg.norm(points[-1] - tool) < 1e-4  # ends where the tool is
    assert np.max(np.linalg.norm(np.diff(points, axis=0), axis=1)) < 1.6 * np.linalg.norm(tool) / len(points)
    assert np.all(np.diff(forces) < 0) and forces[0] <= 15.0
    assert loop.retracted == pytest.approx(0.05)
    # without release_at_m the line stays on the agent's point
    loop = _TickLoop()
    _lift_off(loop, 0.05, pressing=pressing)
    assert all(np.array_equal(r.point_world, pressing.point_world) for r in loop.refs)
