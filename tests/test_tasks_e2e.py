"""End-to-end: shortened cleaning and wiping runs in the simulator give finite, in-range metrics.

The full-length numbers (≥ 95 % dirt, force bands, MAE/RMSE) come from `make bench`
(bench/bench_tasks.py); these runs are short so that the suite stays fast.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from tactex.errors import ConfigError, InputError
from tactex.tasks.clean import PHASES, CleanConfig, run_clean
from tactex.tasks.clean.motion import UNLOAD_S
from tactex.tasks.wipe import WipeConfig, run_wipe

pytestmark = pytest.mark.slow


def _finite_series(series: dict) -> None:
    for key, values in series.items():
        if key in ("agent",):  # NaN before the first exploration step, by design
            continue
        assert np.isfinite(values).all(), f"series '{key}' holds NaN/inf"


def test_short_clean_removes_dirt_with_bounded_force() -> None:
    # 17 s: a ~4.5 s trip back to the camera fits (transits are one smooth motion since issue 17)
    cfg = CleanConfig(object_name="plate", budget_s=17.0, n_eigen=60, vision_max_steps=80)
    r = run_clean(cfg, progress=False)
    m = r.metrics
    # issue 21: every tick of the run is in one bucket of the time breakdown; each bucket this program has
    # (camera, transit, touch-down, contact) is used
    bd = m["time_breakdown_s"]
    assert sum(bd.values()) == pytest.approx(m["sim_time_s"], abs=0.002)
    assert min(bd["vision"], bd["transit"], bd["touch_down"], bd["contact_dirt"]) > 0.0
    assert bd["contact_dirt"] + bd["contact_clean"] == pytest.approx(m["contact_time_s"], abs=0.05)
    t95 = m["time_to_95pct_s"]
    assert (t95 is None) == (m["dirt_removed_fraction"] < 0.95 and np.nanmin(r.series["dirt_remaining"]) > 0.05)
    # the breakdown up to the 95 % mark adds up to the time to 95 % (the ticks up to that reading)
    to95 = m["time_breakdown_to_95pct_s"]
    assert (to95 is None) == (t95 is None)
    if to95 is not None:
        assert sum(to95.values()) == pytest.approx(t95, abs=0.002)
        assert all(to95[k] <= bd[k] + 1e-9 for k in to95)
    assert 0.05 < m["dirt_removed_fraction"] <= 1.0  # it cleaned something in a few seconds of contact
    assert 0.0 <= m["force_within_20pct_fraction"] <= 1.0
    assert 0.0 < m["max_contact_force_n"] <= 2.0 * cfg.force_n
    assert m["sim_time_s"] <= cfg.budget_s + UNLOAD_S + 0.45  # only the final unload and 0.4 s lift-off come on top
    assert m["vision_updates"] >= 1
    assert all(t <= cfg.budget_s for t in m["vision_update_times_s"])  # no re-measurement past the budget
    # the agent's path over every exploration phase (it counted the last one only); the steps are
    # ≤ 3 mm, longer ones are the restarts after a re-measurement
    steps = np.linalg.norm(np.diff(r.agent_path, axis=0), axis=1)
    assert m["agent_path_length_m"] == pytest.approx(steps[steps < 0.004].sum(), rel=0.05)
    assert m["contact_time_s"] > 1.0
    assert 0.0 < m["start_plan_time_s"] < m["wall_time_s"]  # the first touch-down is planned (wall clock)
    # ticks the torque-rate limiter cut (thousands per run when the GA damping chattered at 500 Hz)
    assert m["torque_rate_clip_ticks"] <= 5
    _finite_series(r.series)
    assert set(np.unique(r.series["phase"])) <= set(PHASES.values())
    for name in ("target", "coverage", "potential"):
        assert r.fields[name].shape == (len(r.cloud),) and np.isfinite(r.fields[name]).all()
    assert r.agent_path.shape[1] == 3 and np.isfinite(r.agent_path).all()


def test_short_raster_baseline_runs() -> None:
    r = run_clean(CleanConfig(object_name="plate", budget_s=10.0, baseline="raster"), progress=False)
    assert r.metrics["baseline"] == "raster"
    assert 0.0 <= r.metrics["dirt_removed_fraction"] <= 1.0
    assert r.metrics["max_contact_force_n"] <= 20.0


def test_short_wipe_makes_contact_and_keeps_tanks_in_limits() -> None:
    r = run_wipe(WipeConfig(duration_s=4.0), progress=False)
    m = r.metrics
    assert m["contact_fraction"] > 0.5
    assert np.isfinite(m["force_mae_n"]) and np.isfinite(m["force_rmse_n"])
    assert m["force_rmse_n"] >= m["force_mae_n"] >= 0.0
    lo, hi = m["tank_impedance_limits_j"]
    assert lo <= m["tank_impedance_energy_j"]["min"] <= m["tank_impedance_energy_j"]["max"] <= hi
    lo, hi = m["tank_force_limits_j"]
    assert lo <= m["tank_force_energy_j"]["min"] <= m["tank_force_energy_j"]["max"] <= hi
    assert m["vision_valid_fraction"] > 0.9
    _finite_series({k: v for k, v in r.series.items() if k not in ("rho_align", "rho_frc", "theta_rad")})
    assert r.explored is not None and len(r.explored) == r.explored_curvature.shape[0]
    # the explored normals come from the wrist camera and agree with the true surface
    assert m["explored_normal_error_deg_median"] < 5.0
    assert 0.0 <= m["explored_depth_below_surface_m_median"] < 0.015  # TCP = pad tip, pressed into the sponge


def test_short_wipe_baseline_runs() -> None:
    r = run_wipe(WipeConfig(duration_s=3.0, baseline="cartesian"), progress=False)
    assert r.metrics["controller"] == "cartesian_impedance"
    assert np.isfinite(r.metrics["force_mae_n"])


def test_bowl_with_the_rli_marking_stays_within_the_force_band() -> None:
    """The README's bowl example. Before: the agent's fit turned its normal over on the ragged rim of
    the capture (45.7 N peaks, 79.9 % within ±20 %), and once the joint move back to the camera
    dipped the tool into the bowl (720 N, a force trip, a capture that saw nothing and a crash)."""
    cfg = CleanConfig(object_name="bowl", marking="RLI")
    m = run_clean(cfg, progress=False).metrics
    assert m["vision_updates"] >= 1 and m["dirt_removed_fraction"] > 0.95
    assert m["max_contact_force_n"] < 2.5 * cfg.force_n
    assert m["force_within_20pct_fraction"] > 0.85
    kinds = [p for _, p in m["phase_changes"]]
    assert kinds.count(PHASES["capture"]) == m["vision_updates"] + 1  # the first capture and each update


def test_a_far_joint_move_after_a_lift_off_goes_up_to_the_capture_posture_first(monkeypatch,
                                                                                 descent_sweep_search) -> None:
    """The bowl's RLI, seed 1, with the planned sweep run to its last corner: after the lift-off low in the bowl the
    hover over the next dirt is an IK posture 1.4 rad away in the wrist, and the straight joint move there swung the
    tool down the bowl's far wall (24.5 N against a 10 N set point, during a move). Such a move now goes up to the
    capture posture first."""
    from tactex.tasks.clean import sweep_plan

    # the scenario: the sweep to its last corner, planned (descent_sweep_search) and followed as when it was found
    monkeypatch.setattr(sweep_plan, "END_BEYOND_RADII", np.inf)
    cfg = CleanConfig(object_name="bowl", marking="RLI", seed=1, line_lead_s=0.2)
    m = run_clean(cfg, progress=False).metrics
    assert m["moves_via_capture"] >= 1, "no far move from low over the bowl: the scenario does not test the rule"
    assert m["max_contact_force_n"] <= 2.0 * cfg.force_n
    assert m["dirt_removed_fraction"] > 0.95


def test_the_way_up_to_the_capture_posture_leaves_the_bowl_straight_up_first(descent_sweep_search) -> None:
    """The bowl's RLI, seed 2: after the planned sweep the lift-off ends low in the bowl and the next dirt's hover
    is a far wrist turn away, so the move goes up to the capture posture first; a straight joint move there from
    inside the bowl swung the tool through its wall (104-146 N, 229 clipped ticks). Now straight up first, then
    along the line of IK waypoints, as the trip to the camera does."""
    cfg = CleanConfig(object_name="bowl", marking="RLI", seed=2)  # the sweep planned as when it was found
    m = run_clean(cfg, progress=False).metrics
    assert m["moves_via_capture"] >= 1, "no move up to the capture posture: the scenario does not test the rule"
    assert m["max_contact_force_n"] <= 2.0 * cfg.force_n
    assert m["torque_rate_clip_ticks"] == 0


def test_the_cup_is_cleaned_from_a_reachable_side_view() -> None:
    """`clean --object-name cup` failed at once: the side capture pose 0.45 m out was out of reach."""
    # TEC's loop: with the default objective the trip to the camera starts where the wear model calls the
    # cup clean, near the rim, and the lift-off there drags the pad over the lip (30.5 N): a known limit of
    # the retract on the cup (issue 21's report), not of the side view this test is about
    # (30 s: 200 exploration steps from the first contact at 6.7 s, some put off while the wall drags the pad
    # over 15 N, and the 3.8 s trip to the camera, which ends at 20.9 s)
    m = run_clean(CleanConfig(object_name="cup", budget_s=30.0, objective="ergodic"), progress=False).metrics
    assert m["vision_updates"] >= 1 and m["dirt_removed_fraction"] > 0.9
    assert m["max_contact_force_n"] < 3.0 * 10.0


def test_the_cup_view_from_above_sees_the_marking_with_a_shorter_swing_from_home() -> None:
    """The side capture 45° above the horizontal: the camera still looks at the wall's mid-height, sees as
    much of the marking as the level view (within a few voxels) and none of the cup's top, and the joint
    move from home is shorter (the shoulder swings less)."""
    from tactex.robots.mujoco_backend import FRANKA_HOME_Q, MujocoBackend
    from tactex.tasks.clean import _acquisition, _capture_pose
    from tactex.tasks.vision import capture_target_cloud

    seen = {}
    for el in (0.0, 45.0):
        cfg = CleanConfig(object_name="cup", marking="X", side_capture_elevation_deg=el)
        scene = cfg.scene()
        pos, rot = _capture_pose(scene, cfg)
        mid = scene.object_pose()[0] + np.array([0.0, -0.04, 0.05])  # the marked wall's middle, at mid-height
        view = (pos - mid) / np.linalg.norm(pos - mid)
        assert np.degrees(np.arcsin(view[2])) == pytest.approx(el, abs=1.0)
        assert rot[:, 2] @ view == pytest.approx(-1.0, abs=1e-9)  # the tool (and camera) axis looks at the wall
        with MujocoBackend(scene) as be:
            q = be.solve_ik(pos, rot)
            be.reset(q0=q)
            cloud = capture_target_cloud(be.render_depth(), replace(_acquisition(scene), voxel_size_m=cfg.voxel_size_m))
        assert cloud.points[:, 2].max() < 0.1  # the wall, not the cup's top at z = 0.1 m
        seen[el] = (cloud.n_target, float(np.max(np.abs(q - FRANKA_HOME_Q))))
    assert seen[45.0][0] >= 0.95 * seen[0.0][0]
    assert seen[45.0][1] < 0.6 * seen[0.0][1]


def _plate_with_keep_out(tmp_path, dirt_of, keep_out_of):
    """The plate's surface (3 mm voxels) in the robot base frame as a ``--cloud`` file, dirty where
    ``dirt_of(x, y)`` and kept out where ``keep_out_of(x, y)`` (a ``--keep-out-mask`` file), both of the
    plate's own x, y [m]. Returns (cloud, cloud file, mask file, plate-frame x (N,), plate position (3,))."""
    from tactex.pointcloud import save_npz
    from tactex.pointcloud.markings import marked_cloud

    scene = CleanConfig(object_name="plate").scene()
    pos, rot = scene.object_pose()
    local = marked_cloud(scene.sim_object.surface, "full", 0.003)
    x, y = local.points[:, 0], local.points[:, 1]
    cloud = local.with_target(dirt_of(x, y).astype(float)).transformed(rot, pos)
    path = save_npz(cloud, tmp_path / "plate.npz")
    mask = tmp_path / "keep_out.npy"
    np.save(mask, keep_out_of(x, y))
    return cloud, path, mask, x, pos


def test_clean_relocates_over_a_keep_out_strip_within_the_force_limits(tmp_path, monkeypatch) -> None:
    """Dirt on both sides of a keep-out strip across the plate (a --cloud in the base frame with a
    --keep-out-mask): the agent cleans one side, stalls at the strip, and the robot lifts off, flies
    and touches down on the other side (issue 18), never pressing on the strip; every touch-down (the first, the
    task's island moves, the explorer's relocations) is a footprint radius clear of the strip."""
    from tactex.ergodic.explorer import HedacExplorer

    touch_downs = []  # (explorer, where it was reset: the task's touch-downs)
    reset = HedacExplorer.reset

    def record(self, x0):
        touch_downs.append((self, np.array(x0, dtype=float)))
        return reset(self, x0)

    monkeypatch.setattr(HedacExplorer, "reset", record)

    cloud, path, mask, x, pos = _plate_with_keep_out(
        tmp_path, lambda x, y: (np.hypot(x + 0.06, y) <= 0.025) | (np.hypot(x - 0.06, y) <= 0.025),
        lambda x, y: np.abs(x) <= 0.01)
    # The exact basis: this checks the explorer's own stall relocation, and whether that or the task's wear-model
    # island move fires first depends on the trajectory, which the hierarchical basis (auto) changes slightly.
    cfg = CleanConfig(object_name="plate", budget_s=30.0, n_eigen=60, cloud=str(path),
                      keep_out_mask=str(mask), eigensolver="arpack")
    r = run_clean(cfg, progress=False)
    m = r.metrics
    assert m["relocations"] >= 1 and m["air_path_length_m"] > 0.0
    # a given cloud is never re-measured: nothing the camera saw is reported (it said 1.0)
    assert m["vision_updates"] == 0 and math.isnan(m["vision_remaining_fraction"])
    assert m["keep_out_points"] >= int((np.abs(x) <= 0.01).sum()) // 2  # on the 3 mm voxels of the file
    assert m["keep_out_contacts"] == 0
    # touched down on both sides: the agent's path holds points left and right of the strip
    side = r.agent_path[:, 0] - pos[0]
    assert (side < -0.03).any() and (side > 0.03).any()
    # within the force limits over the whole run, lift-off and touch-down included
    assert 0.0 < m["max_contact_force_n"] <= 2.0 * cfg.force_n
    assert m["force_over_2x_ticks"] == 0
    # the sponge's centre never pressed within an agent radius of the strip (a few mm of tracking error allowed):
    # the simulator's pad contact, not the F/T, which reads the tool's inertia (~1 N) while it lifts off
    pressing = r.series["pad_force_n"] >= cfg.contact_threshold_n
    assert pressing.any()
    assert np.min(np.abs(r.series["tcp"][pressing, 0] - pos[0])) >= 0.01 + cfg.agent_radius_m - 0.005
    phases = [p for _, p in m["phase_changes"]]
    first_explore = phases.index(PHASES["explore"])
    assert PHASES["retract"] in phases[first_explore:] and phases[first_explore:].count(PHASES["explore"]) >= 2
    ex = touch_downs[-1][0]
    strip = cloud.points[np.abs(x) <= 0.01]
    at = [p for e, p in touch_downs if e is ex] + [c.point for c in ex.relocations]
    assert len(at) >= 2
    for p in at:
        assert np.min(np.linalg.norm(strip - p, axis=1)) >= cfg.agent_radius_m, p


def test_an_island_move_touches_down_clear_of_a_keep_out_strip(tmp_path, monkeypatch) -> None:
    """Dirt right up to both sides of a keep-out strip: when the robot goes to the other side (the wear model's
    island move or the explorer's relocation, whichever comes first), the touch-down is a footprint radius clear of
    the strip (the dirty point nearest to the robot lies at the strip's edge, where the sponge would press on it).
    The dirt within the clearance is no goal (the explorer leaves it out of its target), so the explorer
    usually relocates first; test_wear_model checks the island move's own rule."""
    from tactex.ergodic.explorer import HedacExplorer
    from tactex.tasks.wear_model import WearModel

    islands = []  # where the task's island moves would touch down
    next_island = WearModel.next_island

    def record(self, here_m, tried_m, clearance_m, allowed=None):
        out = next_island(self, here_m, tried_m, clearance_m, allowed)
        islands.append(out)
        return out

    explorers = []
    init = HedacExplorer.__init__

    def keep(self, *args, **kwargs):
        init(self, *args, **kwargs)
        explorers.append(self)

    monkeypatch.setattr(WearModel, "next_island", record)
    monkeypatch.setattr(HedacExplorer, "__init__", keep)
    cloud, path, mask, x, pos = _plate_with_keep_out(
        tmp_path, lambda x, y: (np.abs(x) <= 0.04) & (np.abs(y) <= 0.02) & (np.abs(x) > 0.01),
        lambda x, y: np.abs(x) <= 0.01)
    strip = np.abs(x) <= 0.01
    cfg = CleanConfig(object_name="plate", budget_s=20.0, n_eigen=60, cloud=str(path),
                      keep_out_mask=str(mask), eigensolver="arpack")
    r = run_clean(cfg, progress=False)
    m = r.metrics
    assert m["target_near_keep_out"] > 0  # the dirt at the strip's edge: no goal
    moves = [p for p in islands if p is not None] + [c.point for e in explorers for c in e.relocations]
    assert moves, "no move to the other side: the scenario does not test the touch-down"
    assert ((r.agent_path[:, 0] - pos[0] < -0.02).any() and (r.agent_path[:, 0] - pos[0] > 0.02).any())
    for p in moves:
        assert np.min(np.linalg.norm(cloud.points[strip] - p, axis=1)) >= cfg.agent_radius_m, p
    assert m["keep_out_contacts"] == 0


def test_the_cup_starts_with_a_planned_sweep_of_its_marking(monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 21: on the cup's wall the first stretch in contact is a planned sweep of a few long passes over
    the blobs (the wear model's shortest slide to 97 % of them), then the explorer, which starts from what the
    wear model says the sweep left; the marking is 95 % off within the first contact, with the force in its
    band."""
    from tactex.ergodic.explorer import HedacExplorer
    from tactex.tasks import clean
    from tactex.tasks.clean.step_ahead import StepAhead

    events: list[tuple] = []  # the explorer's restarts, its target updates (the target's mass) and its steps
    restart, update, step = clean._Legs.restart, StepAhead.update_target_later, HedacExplorer.step
    monkeypatch.setattr(clean._Legs, "restart", lambda self, x0: events.append(("restart",)) or restart(self, x0))
    monkeypatch.setattr(StepAhead, "update_target_later",
                        lambda self, target: events.append(("update", float(target.sum()))) or update(self, target))
    monkeypatch.setattr(HedacExplorer, "step", lambda self, *a, **k: events.append(("step",)) or step(self, *a, **k))
    swept: list[float] = []  # the dirt mass the sweep was planned for
    plan_sweep = clean.legs.plan_sweep
    monkeypatch.setattr(clean.legs, "plan_sweep", lambda cloud, tree, target, *a, **k:
                        swept.append(float(np.sum(target))) or plan_sweep(cloud, tree, target, *a, **k))
    strokes: list = []  # the straight strokes planned through small islands (the sweep is none of them)
    plan_stroke = clean.legs.plan_stroke
    monkeypatch.setattr(clean.legs, "plan_stroke", lambda *a, **k: strokes.append(plan_stroke(*a, **k)) or strokes[-1])
    cfg = CleanConfig(object_name="cup", marking="blobs", budget_s=9.0)
    m = run_clean(cfg, progress=False).metrics
    # the handover: the explorer restarts where the sweep ended and the model's target is queued at once, for the
    # step after its first (StepAhead applies a target after the tick's send; before, it waited for the first model
    # update, up to model_update_steps later)
    assert events.count(("restart",)) == 1, events[:5]
    handover = events.index(("restart",))
    assert events[handover + 1][0] == "update", events[handover:handover + 5]
    # what the sweep left by the model (which calls a point clean at --wear-margin 1.5 times its dirt wiped: a
    # third of the view's mass where the plan, at margin 1, wiped 97 %), not the view's whole marking
    assert events[handover + 1][1] < 0.5 * swept[0], (events[handover + 1], swept)
    assert m["first_leg"].startswith("a planned sweep over strokes"), m["first_leg"]
    planned = m["first_sweep_planned_m"]
    assert 0.05 < planned < 0.25  # planned, and shorter than the explorer's 0.23 m to the 95 % mark
    # slid: to its last corner, a little beyond the goal's mark
    assert planned <= m["first_sweep_m"] <= planned + 0.05, (m["first_sweep_m"], planned)
    # the sweep is not counted as a stroke through a small island (the explorer, seeing the sweep's wiping, slides
    # to a leftover spot with one)
    assert m["island_strokes"] == sum(st is not None and not st.transfer_only for st in strokes)
    t95 = m["time_to_95pct_s"]
    assert t95 is not None and not m["vision_update_times_s"]
    to95 = m["time_breakdown_to_95pct_s"]
    assert to95["contact_clean"] < 0.1  # the sweep stays on the blobs
    assert to95["contact_dirt"] < 2.9  # the explorer alone took 3.3 s of contact (and 0.6 s on clean wall)
    assert m["force_within_20pct_fraction"] >= 0.9 and m["max_contact_force_n"] <= 2.0 * cfg.force_n


def test_a_sweep_whose_touch_down_is_out_of_reach_is_not_reported_as_slid(monkeypatch: pytest.MonkeyPatch) -> None:
    """The planned sweep starts with a hover over its first point; when that is out of the arm's reach the sweep
    is dropped (the robot moves on to other dirt), and the metrics say so: planned, not slid."""
    from tactex.errors import SimulationError
    from tactex.tasks import clean

    planned: list = []
    refused: list = []
    plan_sweep, hover_plan = clean.legs.plan_sweep, clean.motion._hover_plan

    def record_plan(*args, **kwargs):
        plan = plan_sweep(*args, **kwargs)
        planned.append(plan)
        return plan

    def unreachable_sweep_start(loop, point_m, *args, **kwargs):
        if planned and planned[0] is not None and not refused and np.allclose(point_m, planned[0].waypoints[0]):
            refused.append(point_m)
            raise SimulationError("test: the sweep's first hover is out of reach")
        return hover_plan(loop, point_m, *args, **kwargs)

    monkeypatch.setattr(clean.legs, "plan_sweep", record_plan)
    monkeypatch.setattr(clean.motion, "_hover_plan", unreachable_sweep_start)
    with pytest.warns(RuntimeWarning, match="no hover pose"):
        m = run_clean(CleanConfig(object_name="cup", marking="blobs", budget_s=4.0), progress=False).metrics
    assert refused, "the sweep's hover was never asked for: the scenario does not test the drop"
    assert m["first_sweep_planned_m"] == pytest.approx(planned[0].length_m) and m["first_sweep_planned_m"] > 0
    assert m["first_sweep_m"] == 0.0
    assert m["contact_time_s"] > 0  # the robot went on elsewhere


def test_the_first_stroke_is_planned_once(tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A single 1 cm spot (all the view's dirt, smaller than the pad): the stroke through it that the set-up plans
    while the arm holds at the capture pose (to rule out a planned sweep) is the one the first leg drives, not
    planned again."""
    from tactex.tasks import clean

    calls: list[tuple] = []  # each plan_stroke's island point, start and result
    plan_stroke = clean.legs.plan_stroke

    def record(cloud, tree, wear, island_point_m, from_m, *args, **kwargs):
        out = plan_stroke(cloud, tree, wear, island_point_m, from_m, *args, **kwargs)
        calls.append((tuple(np.round(island_point_m, 6)), tuple(np.round(from_m, 6)), out))
        return out

    monkeypatch.setattr(clean.legs, "plan_stroke", record)
    _, path, _, _, _ = _plate_with_keep_out(tmp_path, lambda x, y: np.hypot(x - 0.05, y) <= 0.005,
                                            lambda x, y: np.zeros_like(x, dtype=bool))
    cfg = CleanConfig(object_name="plate", budget_s=8.0, n_eigen=60, cloud=str(path), eigensolver="arpack")
    m = run_clean(cfg, progress=False).metrics
    assert calls and calls[0][2] is not None  # the spot's stroke, planned at the set-up
    assert m["island_strokes"] >= 1 and m["first_sweep_planned_m"] == 0.0 and m["contact_time_s"] > 0
    starts = [c[:2] for c in calls]
    assert len(set(starts)) == len(starts), starts  # no stroke planned twice from the same point


def test_a_stroke_ends_where_the_wear_model_calls_its_island_wiped(tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A spot 2.2 cm across (just under the pad's radius): one pass of its stroke leaves the spot's ends short of
    the wear margin, so a pass back follows; the stroke ends where the model first calls every spot point wiped,
    not at the far end of that pass."""
    from tactex.tasks import clean

    ended: list[tuple] = []  # (passes, path slid [m], one pass's length [m], island wiped by the model)
    after_stroke = clean.program._after_stroke

    def record(stroke, cmd, wear, *args, **kwargs):
        if not stroke.transfer_only:
            ended.append((stroke.passes, stroke.path.path_length, float(np.linalg.norm(stroke.b - stroke.a)),
                          stroke.clean(wear)))
        return after_stroke(stroke, cmd, wear, *args, **kwargs)

    monkeypatch.setattr(clean.program, "_after_stroke", record)
    _, path, _, _, _ = _plate_with_keep_out(tmp_path, lambda x, y: np.hypot(x - 0.05, y) <= 0.011,
                                            lambda x, y: np.zeros_like(x, dtype=bool))
    cfg = CleanConfig(object_name="plate", budget_s=8.0, n_eigen=60, cloud=str(path), eigensolver="arpack")
    m = run_clean(cfg, progress=False).metrics
    assert ended, "no stroke ended: the scenario does not test the stroke's end"
    passes, slid_m, pass_m, wiped = ended[0]
    assert passes == 2 and wiped
    # two whole passes slide twice the pass; the model calls the spot wiped before the second one ends
    assert slid_m < 1.95 * pass_m, (slid_m, pass_m)
    assert slid_m > 1.2 * pass_m  # the pass back was needed: the first pass alone leaves the margin unmet
    assert m["dirt_removed_fraction"] > 0.95


def test_sparse_spots_are_cleaned_island_by_island() -> None:
    """Issue 21: three 1 cm spots far apart on the plate. Each spot is smaller than the pad: the robot wipes
    it with a straight stroke (back and forth until the wear model calls it clean) and moves on to the
    nearest spot left — sliding in contact when that is quicker than a lift-off — without a trip to the
    camera before the dirt is off."""
    cfg = CleanConfig(object_name="plate", marking="spots", budget_s=22.0)
    m = run_clean(cfg, progress=False).metrics
    assert m["island_strokes"] >= 3  # one stroke per spot at least, no ergodic dwell
    assert m["first_sweep_planned_m"] == m["first_sweep_m"] == 0.0  # the first spot is smaller than the pad: its
    # stroke, not a planned sweep
    assert m["contact_transfers"] + m["island_relocations"] >= 2  # from spot to spot
    assert m["dirt_removed_fraction"] > 0.95
    t95 = m["time_to_95pct_s"]
    assert t95 is not None and all(t > t95 for t in m["vision_update_times_s"])
    assert m["max_contact_force_n"] <= 2.0 * cfg.force_n
    bd = m["time_breakdown_s"]
    assert bd["contact_dirt"] + bd["contact_clean"] > 3 * 1.0  # three strokes of a few passes in contact
    # up to the 95 % mark: the time to 95 % split; the trips to the camera after it are not in it
    to95 = m["time_breakdown_to_95pct_s"]
    assert sum(to95.values()) == pytest.approx(t95, abs=0.002)
    assert to95["contact_dirt"] > 0 and to95["touch_down"] > 0
    assert to95["vision"] < bd["vision"] or not m["vision_update_times_s"]


def test_a_fully_marked_surface_is_cleaned_with_the_dirt_source_not_the_sweep(monkeypatch) -> None:
    """The wear model keeps replacing the explorer's target: on a uniformly marked surface (``--marking
    full``, which ``explore`` would sweep) the clean still follows the dirt with eq. 1–2 from the start, so no
    target update switches the step (and compiles it) while torque control runs."""
    from tactex.ergodic.explorer import HedacExplorer

    configs = []
    orig = HedacExplorer.__init__

    def init(self, cloud, basis, config=None, *a, **k):
        configs.append(config)
        orig(self, cloud, basis, config, *a, **k)

    monkeypatch.setattr(HedacExplorer, "__init__", init)
    m = run_clean(CleanConfig(object_name="plate", marking="full", budget_s=9.0, n_eigen=40), progress=False).metrics
    assert configs and all(c.source_mode == "ergodic" for c in configs)
    assert m["dirt_removed_fraction"] > 0.0


def test_with_a_cloud_the_simulated_dirt_is_the_clouds_target(tmp_path) -> None:
    """In simulation, --cloud's target is the dirt (not the scene's --marking), so that what the run reports as
    removed is what the user marked; a cloud off the simulated object is refused."""
    from tactex.pointcloud import SurfaceCloud, save_npz

    cloud, path, _, _, _ = _plate_with_keep_out(  # its keep-out mask file is not given to the run
        tmp_path, lambda x, y: (np.abs(x - 0.03) <= 0.02) & (np.abs(y) <= 0.02), lambda x, y: np.abs(x) <= 0.001)
    cfg = CleanConfig(object_name="plate", budget_s=12.0, n_eigen=60, cloud=str(path), eigensolver="arpack")
    m = run_clean(cfg, progress=False).metrics
    assert m["marking"] == "cloud"
    assert m["dirt_removed_fraction"] >= 0.95  # the patch; the X marking it replaced lies mostly elsewhere
    lifted = save_npz(cloud.transformed(np.eye(3), np.array([0.0, 0.0, 0.05])), tmp_path / "lifted.npz")
    with pytest.raises(ConfigError, match="base frame"):
        run_clean(replace(cfg, cloud=str(lifted)), progress=False)
    half = cloud.points.copy()
    half[half[:, 0] > np.median(half[cloud.target > 0, 0]), 2] += 0.05  # half the patch off the plate
    partly = save_npz(SurfaceCloud(half, normals=cloud.normals, target=cloud.target, spacing=cloud.spacing),
                      tmp_path / "partly.npz")
    with pytest.warns(RuntimeWarning, match="not simulated as dirt"):
        run_clean(replace(cfg, cloud=str(partly), budget_s=1.0), progress=False)


def test_painting_the_dirt_field_from_points() -> None:
    """A voxelised cloud's target (a 3 mm grid over a 20 mm square) paints every 2 mm cell inside the square at
    clean's radius (0.71 voxel: the farthest an inside cell lies from the grid) and none a voxel beyond it."""
    from tactex.sim.dirt import DirtField
    from tactex.sim.objects import get_object

    surface = get_object("plate").surface
    field = DirtField(surface, "X", 0.002)
    g = np.arange(-0.0105, 0.0106, 0.003)
    gx, gy = np.meshgrid(g, g)
    grid = np.column_stack([gx.ravel(), gy.ravel(), surface.height(gx.ravel(), gy.ravel())])  # on the plate
    n = field.paint(grid, 0.003 * np.sqrt(0.5))
    x, y = field.points[:, 0], field.points[:, 1]
    inside = (np.abs(x) <= 0.0105) & (np.abs(y) <= 0.0105) & field.valid
    assert inside.sum() >= 100  # the square's 2 mm cells (about 11 × 11)
    assert n == int(field.initial.sum()) and field.initial[inside].all()
    assert not field.initial[(np.abs(x) > 0.0105 + 0.003) | (np.abs(y) > 0.0105 + 0.003)].any()
    assert field.remaining_fraction() == 1.0
    with pytest.raises(InputError):
        field.paint(np.zeros((0, 3)), 0.006)
    with pytest.raises(ConfigError):
        field.paint(grid, 0.0)


def test_a_move_past_the_cups_wall_backs_off_along_the_tool_axis_instead_of_the_capture_posture() -> None:
    """The region raster on the cup's blobs: the move from one blob's lift-off to the next blob's hover passes
    within 1.5 cm of the cup's wall, and going straight up runs along the wall. Backing off along the tool axis
    clears it, without the trip to the capture posture and back."""
    cfg = CleanConfig(object_name="cup", marking="blobs", baseline="region_raster")
    m = run_clean(cfg, progress=False).metrics
    assert m["moves_backed_off"] >= 1, "no move backed off the cup's wall: the scenario does not test the rule"
    assert m["moves_via_capture"] == 0
    assert m["max_contact_force_n"] <= 2.0 * cfg.force_n
    assert m["torque_rate_clip_ticks"] == 0
    assert m["dirt_removed_fraction"] > 0.95
