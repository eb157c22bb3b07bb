"""Relocation (lift-and-move) and keep-out zones of the HEDAC explorer (issue 18)."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.ergodic import HedacConfig, HedacExplorer
from tactex.ergodic.relocation import ProgressMonitor, RelocationCommand, air_length, choose_touch_down
from tactex.errors import ConfigError, ExplorationError, InputError
from tactex.pointcloud import SurfaceCloud
from tactex.spectral import build_basis

from .conftest import gap_strips

H = 0.003


def _grid(nx: int, ny: int, offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    u, v = np.meshgrid(np.arange(nx) * H, np.arange(ny) * H)
    return np.c_[u.ravel(), v.ravel(), np.zeros(u.size)] + np.asarray(offset)


def _run(ex: HedacExplorer, steps: int) -> list:
    return [ex.step() for _ in range(steps)]


@pytest.fixture(scope="module")
def two_plates():
    """Two 60 × 60 mm plates 30 cm apart (two Laplacian parts), the target on the first only."""
    a, b = _grid(21, 21), _grid(21, 21, (0.3, 0.0, 0.0))
    pts = np.vstack([a, b])
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    cloud = SurfaceCloud(pts, normals=normals, target=np.r_[np.ones(len(a)), np.zeros(len(b))], spacing=H)
    return cloud, build_basis(cloud, n_eigen=20, n_neighbors=10, cache=False)


def test_a_start_on_a_part_without_target_relocates_to_the_target(two_plates):
    cloud, basis = two_plates
    assert basis.n_components == 2
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=20))
    ex.reset(np.array([0.33, 0.03, 0.0]))
    first = ex.step()
    assert isinstance(first, RelocationCommand) and first.reason == "part_done"
    assert cloud.target[int(np.argmin(np.linalg.norm(cloud.points - first.point, axis=1)))] > 0
    _run(ex, 300)
    assert ex.coverage_residual() < 0.05
    assert len(ex.relocations) == 1 and ex.air_path_length == pytest.approx(first.air_length_m)


def test_without_relocation_the_agent_stays_on_its_part(two_plates):
    cloud, basis = two_plates
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=20, relocate=False))
    ex.reset(np.array([0.33, 0.03, 0.0]))
    cmds = _run(ex, 50)
    assert not any(isinstance(c, RelocationCommand) for c in cmds)
    assert ex.coverage_residual() == pytest.approx(1.0)


def test_a_finished_part_sends_the_agent_to_the_other_part():
    a, b = _grid(11, 11), _grid(11, 11, (0.3, 0.0, 0.0))
    pts = np.vstack([a, b])
    cloud = SurfaceCloud(pts, target=np.ones(len(pts)), spacing=H)
    basis = build_basis(cloud, n_eigen=20, n_neighbors=10, cache=False)
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=20))
    ex.reset(a[60])
    _run(ex, 200)
    assert [r.reason for r in ex.relocations][:1] == ["part_done"]
    assert ex.coverage_residual() == 0.0


def test_a_stall_at_a_hole_the_agent_may_not_cross_relocates():
    """A 9.5 mm scan hole the Laplacian links but the agent may neither walk (max_off_cloud_voxels 1 voxel) nor
    hop (max_bridge_voxels 0): the agent stalls at the rim, then relocates beyond the hole. (At 9 mm the band
    farther than one voxel from both sides is 3 mm, which one straight 3 mm step can jump: round-off
    decides whether it does.)"""
    cloud = gap_strips(0.0095, 0.01, seed=2)
    basis = build_basis(cloud, n_eigen=60, n_neighbors=40, cache=False)
    assert basis.n_components == 1
    start = np.array([0.02, 0.045, 0.0])
    stuck = HedacExplorer(cloud, basis, HedacConfig(n_eigen=60, max_bridge_voxels=0.0, relocate=False))
    stuck.reset(start)
    assert max(c.point[0] for c in _run(stuck, 250)) < 14 * H + 0.0095
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=60, max_bridge_voxels=0.0))
    ex.reset(start)
    cmds = _run(ex, 250)
    relocs = [c for c in cmds if isinstance(c, RelocationCommand)]
    assert relocs and relocs[0].reason == "stall"
    assert relocs[0].point[0] > 14 * H + 0.0095
    assert ex.coverage_residual() < 0.05


def test_a_scripted_stall_relocates_after_stall_steps():
    """The stall rule itself: an agent held in place (its measured position fed back, as a robot
    that does not move) relocates after stall_steps steps."""
    pts = _grid(30, 20)
    cloud = SurfaceCloud(pts, target=(pts[:, 0] > 0.06).astype(float), spacing=H)
    basis = build_basis(cloud, n_eigen=30, n_neighbors=10, cache=False)
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=30, stall_steps=15))
    held = np.array([0.01, 0.03, 0.0])
    ex.reset(held)
    cmds = [ex.step(held) for _ in range(16)]
    assert not any(isinstance(c, RelocationCommand) for c in cmds[:15])
    cmd = cmds[15]
    assert isinstance(cmd, RelocationCommand) and cmd.reason == "stall"
    assert cmd.point[0] > 0.06


def test_relocation_commands_are_well_formed(two_plates):
    cloud, basis = two_plates
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=20, relocation_clearance_m=0.03))
    start = np.array([0.33, 0.03, 0.0])
    ex.reset(start)
    cmd = ex.step()
    assert isinstance(cmd, RelocationCommand)
    # the touch-down is a cloud point, the lift-off where the agent was (on the cloud)
    assert np.min(np.linalg.norm(cloud.points - cmd.point, axis=1)) == 0.0
    assert np.min(np.linalg.norm(cloud.points - cmd.lift_off, axis=1)) <= H
    for n in (cmd.normal, cmd.lift_off_normal, cmd.tangent_u, cmd.tangent_v):
        assert np.linalg.norm(n) == pytest.approx(1.0, abs=1e-12)
    assert cmd.normal @ np.array([0.0, 0.0, 1.0]) > 0.99  # outward, as the cloud's normals
    assert abs(cmd.tangent_u @ cmd.normal) < 1e-12 and abs(cmd.tangent_v @ cmd.normal) < 1e-12
    assert np.all(cmd.velocity == 0.0)
    w = cmd.waypoints()
    assert w.shape == (4, 3)
    np.testing.assert_allclose(w[1] - w[0], 0.03 * cmd.lift_off_normal, atol=1e-15)
    np.testing.assert_allclose(w[2] - w[3], 0.03 * cmd.normal, atol=1e-15)
    assert cmd.air_length_m == pytest.approx(float(np.sum(np.linalg.norm(np.diff(w, axis=0), axis=1))))
    assert np.isfinite(np.concatenate([cmd.point, cmd.normal, cmd.lift_off, cmd.lift_off_normal])).all()
    assert ex.positions[0] == pytest.approx(cmd.point)


def test_touch_down_prefers_near_mass_over_a_far_clump_and_a_clump_over_a_speck():
    pts = np.array([[0.0, 0, 0], [0.01, 0, 0], [0.5, 0, 0], [0.501, 0, 0], [0.502, 0, 0],
                    [0.02, 0, 0], [0.0205, 0, 0], [0.021, 0, 0]])
    mass = np.ones(len(pts))
    # from the origin: the clump at 2 cm (3 points) beats the speck at 1 cm and the clump at 50 cm
    j = choose_touch_down(pts, np.arange(1, len(pts)), mass[1:], np.zeros(3), 0.002)
    assert j in (5, 6, 7)
    assert choose_touch_down(pts, np.zeros(0, dtype=np.intp), np.zeros(0), np.zeros(3), 0.002) is None


def test_progress_monitor_rules():
    mon = ProgressMonitor(np.zeros(3), 0, 0.006, stall_steps=5, progress_steps=10)
    for k in range(1, 5):
        mon.moved_to(np.array([0.004, 0.0, 0.0]), k)
        assert not mon.stalled(k)
    assert mon.stalled(5)
    mon.moved_to(np.array([0.02, 0.0, 0.0]), 6)  # left the circle: a new anchor
    assert not mon.stalled(10) and mon.stalled(11)
    assert not mon.no_progress(100, 0) and not mon.no_progress(99, 5)
    assert not mon.no_progress(99, 14) and mon.no_progress(99, 15)
    assert air_length(np.zeros(3), np.array([0, 0, 1.0]), np.array([1.0, 0, 0]), np.array([0, 0, 1.0]), 0.1) == \
        pytest.approx(1.2)


@pytest.fixture(scope="module")
def strip_plate():
    """A 150 × 60 mm plate: target patches at both ends, a 12 mm keep-out strip across the middle."""
    pts = _grid(51, 21)
    x = pts[:, 0]
    target = ((x < 0.035) | (x > 0.115)).astype(float)
    keep_out = np.abs(x - 0.075) <= 0.006
    cloud = SurfaceCloud(pts, normals=np.tile([0.0, 0.0, 1.0], (len(pts), 1)), target=target, spacing=H)
    return cloud, keep_out, build_basis(cloud, n_eigen=40, n_neighbors=20, cache=False)


def test_a_keep_out_strip_between_two_targets_is_never_crossed_by_the_footprint(strip_plate):
    cloud, keep_out, basis = strip_plate
    cfg = HedacConfig(n_eigen=40)
    ex = HedacExplorer(cloud, basis, cfg, keep_out=keep_out)
    ex.reset(np.array([0.01, 0.03, 0.0]))
    ko = cloud.points[keep_out]
    closest = np.inf
    walked = []
    for _ in range(1500):
        cmd = ex.step()
        walked.append(isinstance(cmd, RelocationCommand))
        closest = min(closest, float(np.min(np.linalg.norm(ko - cmd.point, axis=1))))
        if not walked[-1]:
            assert ex.keep_out_contacts == 0
    assert ex.keep_out_contacts == 0
    assert np.all(ex.coverage[keep_out] == 0.0)
    assert closest >= cfg.agent_radius_m  # the agent point, so its footprint, never reached the zone
    assert ex.coverage_residual() < 0.05  # both sides cleaned: the far one through the air
    assert any(walked)
    assert np.all(ex.target[keep_out] == 0.0)


def test_a_start_in_a_keep_out_zone_relocates_or_is_refused(strip_plate):
    cloud, keep_out, basis = strip_plate
    inside = np.array([0.075, 0.03, 0.0])
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=40), keep_out=keep_out)
    ex.reset(inside)
    cmd = ex.step()
    assert isinstance(cmd, RelocationCommand) and cmd.reason == "keep_out"
    assert ex.keep_out_contacts == 0
    off = HedacExplorer(cloud, basis, HedacConfig(n_eigen=40, relocate=False), keep_out=keep_out)
    with pytest.raises(ExplorationError, match="keep-out"):
        off.reset(inside)


def test_keep_out_input_is_checked(strip_plate):
    cloud, keep_out, basis = strip_plate
    with pytest.raises(InputError, match="boolean mask"):
        HedacExplorer(cloud, basis, HedacConfig(n_eigen=40), keep_out=keep_out.astype(float))
    with pytest.raises(InputError, match="boolean mask"):
        HedacExplorer(cloud, basis, HedacConfig(n_eigen=40), keep_out=keep_out[:-1])
    with pytest.raises(ExplorationError, match="every target point is kept out"):
        HedacExplorer(cloud, basis, HedacConfig(n_eigen=40), keep_out=cloud.target > 0)


@pytest.mark.parametrize(
    ("field", "value"),
    [("stall_steps", 1), ("progress_steps", -1), ("stall_radius_voxels", 0.0), ("relocation_clearance_m", -0.01),
     ("relocate", 1)],
)
def test_relocation_parameters_are_validated(field, value):
    with pytest.raises(ConfigError, match=field):
        HedacConfig(**{field: value})


def test_with_several_agents_one_relocates_while_the_other_walks(two_plates):
    cloud, basis = two_plates
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=20))
    ex.reset(np.array([[0.03, 0.03, 0.0], [0.33, 0.03, 0.0]]))
    cmds = ex.step_all()
    assert not isinstance(cmds[0], RelocationCommand) and isinstance(cmds[1], RelocationCommand)
    assert [c.agent for c in cmds] == [0, 1]
    for _ in range(150):
        cmds = ex.step_all()
        assert len(cmds) == 2 and all(np.isfinite(c.point).all() for c in cmds)
    assert ex.coverage_residual() <= 0.05
    assert ex.air_path_lengths[0] == 0.0 and ex.air_path_lengths[1] > 0.29


def test_with_config_keeps_the_keep_out_zone(strip_plate):
    cloud, keep_out, basis = strip_plate
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=40), keep_out=keep_out).with_config(stall_steps=30)
    assert ex.config.stall_steps == 30 and np.array_equal(ex.keep_out, keep_out)
    assert not ex.clear_points[keep_out].any()


def test_target_the_agent_may_not_stand_by_is_left_out_and_the_rest_is_covered():
    """A whole plate target with a keep-out strip: the target within the clearance (footprint radius + ½ voxel)
    of the strip is no goal, so it is left out of the target and of the residual, which the explorer then takes
    to 0 instead of sitting at the strip's edge drawn by target it may not reach."""
    pts = _grid(41, 21)
    x = pts[:, 0]
    keep_out = np.abs(x - 0.06) <= 0.006
    cloud = SurfaceCloud(pts, normals=np.tile([0.0, 0.0, 1.0], (len(pts), 1)), target=np.ones(len(pts)), spacing=H)
    basis = build_basis(cloud, n_eigen=40, n_neighbors=20, cache=False)
    cfg = HedacConfig(n_eigen=40)
    ex = HedacExplorer(cloud, basis, cfg, keep_out=keep_out)
    clear_m = cfg.agent_radius_m + 0.5 * H
    assert ex.keep_out_clearance_m == pytest.approx(clear_m)
    d = np.min(np.abs(x[:, None] - x[keep_out][None]), axis=1)
    band = ~keep_out & (d < clear_m - 1e-9)
    assert ex.target_near_keep_out == int(band.sum()) > 0
    assert np.all(ex.target[band | keep_out] == 0.0) and np.all(ex.target[~band & ~keep_out] > 0.0)
    assert ex.source_mode == "sweep"  # still a whole-surface target outside the zone and its band
    ex.reset(np.array([0.01, 0.03, 0.0]))
    for _ in range(3000):
        ex.step()
        if ex.coverage_residual() <= 0.0:
            break
    assert ex.keep_out_contacts == 0
    assert ex.coverage_residual() <= 0.05


def test_target_entirely_beside_a_keep_out_zone_is_refused(strip_plate):
    cloud, keep_out, basis = strip_plate
    x = cloud.points[:, 0]
    beside = (np.abs(x - 0.075) > 0.006) & (np.abs(x - 0.075) <= 0.009)  # within r_a + ½ voxel of the strip
    near_only = cloud.with_target(beside.astype(float))
    with pytest.raises(ExplorationError, match=r"within 9\.0 mm of it"):
        HedacExplorer(near_only, basis, HedacConfig(n_eigen=40), keep_out=keep_out)
