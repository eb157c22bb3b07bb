"""The planned first sweep over the captured dirt (issue 21): its prediction agrees with the wear model's,
it is short where a short sweep exists, it keeps to the surface and above the support, and its island."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.spatial import cKDTree

from tactex.errors import ConfigError, InputError
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.tasks.clean import SWEEP_MIN_SHARE, CleanConfig, _first_leg, sweep_plan
from tactex.tasks.clean.sweep_plan import MAX_CORNERS, dirt_island, plan_sweep
from tactex.tasks.stroke import MAX_LINE_GAP_M
from tactex.tasks.wear_model import WearModel

K_P, R, STEP, FORCE = 5e-3, 0.025, 0.003, 10.0
PER_M = K_P * FORCE / (np.pi * R**2)  # dirt level per metre slid under the pad


def _plane(target, spacing: float = 0.003, half: float = 0.12, trench: float = 0.0) -> SurfaceCloud:
    g = np.arange(-half, half + 1e-9, spacing)
    x, y = np.meshgrid(g, g)
    pts = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    if trench > 0:
        pts[:, 2] = np.where(np.abs(pts[:, 0]) < 0.03, -trench, 0.0)
    return SurfaceCloud(points=pts, normals=np.tile([0.0, 0.0, 1.0], (len(pts), 1)), target=target(pts),
                        spacing=spacing)


def _strip(p: np.ndarray) -> np.ndarray:
    """A 16 cm × 1.2 cm strip along x: one pass along it wipes it, from one end to the other."""
    return ((np.abs(p[:, 0]) <= 0.08) & (np.abs(p[:, 1]) <= 0.006)).astype(float)


def _wiped_share(cloud: SurfaceCloud, waypoints: np.ndarray) -> float:
    """The share of the cloud's dirt the wear model (margin 1) predicts off after a slide along ``waypoints``."""
    wear = WearModel(cloud, K_P, R)
    for a, b in itertools.pairwise(waypoints):
        wear.wipe(0.5 * (a + b), FORCE * float(np.linalg.norm(b - a)))
    return 1.0 - float(wear.remaining().sum()) / float(cloud.target.sum())


def test_the_sweep_of_a_strip_from_its_middle_is_one_turn_and_wipes_what_it_predicts() -> None:
    cloud = _plane(_strip)
    start = np.array([0.0, 0.0, 0.0])
    plan = plan_sweep(cloud, cKDTree(cloud.points), cloud.target, start, R, PER_M, STEP, goal=0.95, seed=1)
    assert plan is not None
    assert np.allclose(plan.waypoints[0], start, atol=cloud.spacing)
    # the wear model, fed the slide along the plan, predicts the goal reached (the planner's own prediction)
    assert _wiped_share(cloud, plan.waypoints) >= 0.95 - 0.01
    # out to one end and back along the whole strip: at most 8 + 16 cm, less where the pad's reach saves its
    # ends; a loop or a second turn would be longer
    assert plan.length_m <= 0.24
    assert plan.length_m >= 0.10  # the strip is 16 cm long; the pad reaches 2.5 cm beyond each end of a pass


def test_no_sweep_when_the_goal_is_out_of_reach() -> None:
    cloud = _plane(_strip)
    tree = cKDTree(cloud.points)
    start = np.array([0.0, 0.0, 0.0])
    assert plan_sweep(cloud, tree, cloud.target, start, R, PER_M, STEP, max_length_m=0.05) is None
    assert plan_sweep(cloud, tree, np.zeros(len(cloud)), start, R, PER_M, STEP) is None  # nothing to wipe


def test_no_leg_across_a_hollow() -> None:
    """Dirt on both sides of a 3 cm deep trench: no straight leg may cross it in the air, so no sweep reaches
    97 % of both sides; with the trench filled, one does."""
    spots = lambda p: (np.linalg.norm(np.abs(p[:, :2]) - [0.06, 0.0], axis=1) <= 0.008).astype(float)  # noqa: E731
    start = np.array([-0.06, 0.0, 0.0])
    hollow = _plane(spots, trench=0.03)
    assert plan_sweep(hollow, cKDTree(hollow.points), hollow.target, start, R, PER_M, STEP, goal=0.97) is None
    flat = _plane(spots)
    plan = plan_sweep(flat, cKDTree(flat.points), flat.target, start, R, PER_M, STEP, goal=0.97)
    assert plan is not None and _wiped_share(flat, plan.waypoints) >= 0.97 - 0.01  # across to the other spot


def test_a_sweep_on_a_wall_runs_on_the_wall_and_keeps_the_pad_above_the_support() -> None:
    """A half cylinder (the cup's wall) with a band of dirt near its foot: the legs follow the arc (not the chord
    inside the wall) and the pad's centre stays a pad radius above the table (its disc is vertical)."""
    radius, spacing = 0.04, 0.003
    ang = np.linspace(-np.pi, 0.0, int(np.pi * radius / spacing))
    a, z = np.meshgrid(ang, np.arange(0.0, 0.1 + 1e-9, spacing))
    pts = np.column_stack([radius * np.cos(a.ravel()), radius * np.sin(a.ravel()), z.ravel()])
    normals = np.column_stack([np.cos(a.ravel()), np.sin(a.ravel()), np.zeros(a.size)])
    zz, side = z.ravel(), np.abs(a.ravel() + np.pi / 2)
    band = ((zz >= 0.012) & (zz <= 0.04) & (side <= np.radians(50))).astype(float)
    cloud = SurfaceCloud(points=pts, normals=normals, target=band, spacing=spacing)
    start = pts[np.argmin(np.linalg.norm(pts - [0.0, -radius, 0.03], axis=1))]
    plan = plan_sweep(cloud, cKDTree(pts), band, start, R, PER_M, STEP, goal=0.9, support_z_m=0.0)
    assert plan is not None
    r_xy = np.hypot(plan.waypoints[:, 0], plan.waypoints[:, 1])
    assert np.all(np.abs(r_xy - radius) <= 1e-3)  # on the arc
    assert plan.waypoints[:, 2].min() >= R - 1e-9  # the vertical pad's disc clears z = 0
    assert np.all(plan.corners[:, 2] >= R - 1e-9)


def test_the_island_is_the_dirt_joined_to_the_touch_down() -> None:
    spots = lambda p: ((np.linalg.norm(p[:, :2] - [-0.05, 0.0], axis=1) <= 0.01)  # noqa: E731
                       | (np.linalg.norm(p[:, :2] - [0.05, 0.0], axis=1) <= 0.01)).astype(float)
    cloud = _plane(spots)
    here = np.array([-0.06, 0.0, 0.0])
    near = dirt_island(cloud.points, cloud.target, here, link_m=0.05, spacing_m=cloud.spacing)
    assert near.sum() > 0 and np.all(cloud.points[near, 0] < 0) and np.all(cloud.target[near] > 0)
    both = dirt_island(cloud.points, cloud.target, here, link_m=0.09, spacing_m=cloud.spacing)
    assert np.array_equal(both, cloud.target > 0)
    assert not dirt_island(cloud.points, np.zeros(len(cloud)), here, 0.05, spacing_m=cloud.spacing).any()


def test_the_planner_and_the_option_refuse_bad_input() -> None:
    cloud = _plane(_strip, half=0.03)
    tree = cKDTree(cloud.points)
    here = np.zeros(3)
    with pytest.raises(InputError, match="shape"):
        plan_sweep(cloud, tree, np.ones(3), here, R, PER_M, STEP)
    for kwargs, match in (({"goal": 1.0}, "goal"), ({"goal": 0.0}, "goal"), ({"max_corners": 0}, "corner")):
        with pytest.raises(ConfigError, match=match):
            plan_sweep(cloud, tree, cloud.target, here, R, PER_M, STEP, **kwargs)
    with pytest.raises(ConfigError, match="pad_radius_m"):
        plan_sweep(cloud, tree, cloud.target, here, -R, PER_M, STEP)
    with pytest.raises(ConfigError, match="step_m"):
        plan_sweep(cloud, tree, cloud.target, here, R, PER_M, float("nan"))
    bare = SurfaceCloud(points=cloud.points, normals=None, target=cloud.target, spacing=cloud.spacing)
    with pytest.raises(InputError, match="normals"):
        plan_sweep(bare, tree, cloud.target, here, R, PER_M, STEP)
    for kwargs in ({"max_corners": MAX_CORNERS + 1}, {"max_corners": 2.7}, {"max_corners": True}):
        with pytest.raises(ConfigError, match="corners"):
            plan_sweep(cloud, tree, cloud.target, here, R, PER_M, STEP, **kwargs)
    for length in (0.0, -1.0, float("nan")):
        with pytest.raises(ConfigError, match="max_length_m"):
            plan_sweep(cloud, tree, cloud.target, here, R, PER_M, STEP, max_length_m=length)
    for start in (np.array([np.nan, 0.0, 0.0]), np.zeros(2)):
        with pytest.raises(InputError, match="start_m"):
            plan_sweep(cloud, tree, cloud.target, start, R, PER_M, STEP)
    with pytest.raises(InputError, match="KD-tree"):
        plan_sweep(cloud, cKDTree(cloud.points[:10]), cloud.target, here, R, PER_M, STEP)
    for bad_target in (np.full(len(cloud), np.nan), -cloud.target):
        with pytest.raises(InputError, match="finite dirt mass"):
            plan_sweep(cloud, tree, bad_target, here, R, PER_M, STEP)
    with pytest.raises(InputError, match="here_m"):
        dirt_island(cloud.points, cloud.target, np.array([np.inf, 0.0, 0.0]), 2 * R, spacing_m=cloud.spacing)
    with pytest.raises(ConfigError, match="link_m"):
        dirt_island(cloud.points, cloud.target, here, 0.0, spacing_m=cloud.spacing)
    for bad in (-1, 1.5, True, MAX_CORNERS + 1):
        with pytest.raises(ConfigError, match="--sweep-corners"):
            CleanConfig(sweep_corners=bad)
    assert CleanConfig(sweep_corners=0).sweep_corners == 0


def test_the_same_seed_plans_the_same_sweep() -> None:
    cloud = _plane(_strip)
    tree, start = cKDTree(cloud.points), np.array([0.02, 0.0, 0.0])
    a = plan_sweep(cloud, tree, cloud.target, start, R, PER_M, STEP, goal=0.95, seed=3)
    b = plan_sweep(cloud, tree, cloud.target, start, R, PER_M, STEP, goal=0.95, seed=3)
    assert a is not None and b is not None
    np.testing.assert_array_equal(a.waypoints, b.waypoints)
    assert a.length_m == b.length_m


class _CountingTree(cKDTree):
    """The planner's KD-trees, counting the work that grows with the dirt's density: (sample, dirty point) pairs
    under the pad and the island's links."""

    pairs = links = 0

    def query_ball_point(self, x, r, *args, **kwargs):
        out = super().query_ball_point(x, r, *args, **kwargs)
        _CountingTree.pairs += sum(len(u) for u in out) if isinstance(out, np.ndarray) else len(out)
        return out

    def query_pairs(self, r, *args, **kwargs):
        out = super().query_pairs(r, *args, **kwargs)
        _CountingTree.links += len(out)
        return out


def _planned_work(cloud: SurfaceCloud, monkeypatch: pytest.MonkeyPatch) -> tuple:
    """The sweep planned on ``cloud`` (the agent's step: one spacing) and the work its island and search took."""
    monkeypatch.setattr(sweep_plan, "cKDTree", _CountingTree)
    _CountingTree.pairs = _CountingTree.links = 0
    start = np.array([0.0, 0.0, 0.0])
    island = dirt_island(cloud.points, cloud.target, start, 2 * R, spacing_m=cloud.spacing)
    plan = plan_sweep(cloud, cKDTree(cloud.points), cloud.target * island, start, R, PER_M, cloud.spacing,
                      goal=0.95, seed=1)
    return plan, island, _CountingTree.pairs, _CountingTree.links


def test_the_planner_s_work_does_not_grow_with_the_cloud_s_density(monkeypatch: pytest.MonkeyPatch) -> None:
    """The strip at 1 mm (``--voxel-size-m 0.001``) costs the planner about what it does at the default 3 mm
    (without the grid: 26x the pairs, 82x the links) and its sweep still wipes the goal."""
    plan3, island3, pairs3, links3 = _planned_work(_plane(_strip), monkeypatch)
    dense = _plane(_strip, spacing=0.001)
    plan1, island1, pairs1, links1 = _planned_work(dense, monkeypatch)
    assert plan3 is not None and plan1 is not None
    assert np.array_equal(island1, dense.target > 0) and np.array_equal(island3, _plane(_strip).target > 0)
    assert pairs3 > 0 and links3 > 0
    assert pairs1 <= 2.0 * pairs3
    # the strip's 13 rows of 1 mm points fall in 6 rows of 3 mm cells (the coarse strip has 5 rows of points)
    assert links1 <= 3.0 * links3
    assert _wiped_share(dense, plan1.waypoints) >= 0.95  # measured on every point, not on the cells
    assert plan1.length_m <= 0.24  # as short as on the default grid (one turn along the strip)


def test_the_sweep_uses_only_the_corners_its_goal_needs() -> None:
    """Five corners are allowed; the strip needs fewer: the corners after the one on whose leg the goal is reached
    are not driven, and that leg ends half a pad radius past the point where the goal is reached (or at its
    corner), not beyond over what is already clean."""
    cloud = _plane(_strip)
    plan = plan_sweep(cloud, cKDTree(cloud.points), cloud.target, np.zeros(3), R, PER_M, STEP, goal=0.95,
                      max_corners=5, seed=1)
    assert plan is not None
    assert 2 <= len(plan.corners) < 1 + 5  # the start and some of the five corners
    # the goal is reached on the last leg: the slide to the corner before it is shorter than the plan's
    slide = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(plan.waypoints, axis=0), axis=1))])
    before_last = int(np.argmin(np.linalg.norm(plan.waypoints - plan.corners[-2], axis=1)))
    assert slide[before_last] < plan.length_m <= slide[-1] + 1e-9
    end = plan.length_m + sweep_plan.END_BEYOND_RADII * R
    at_corner = np.allclose(plan.waypoints[-1], plan.corners[-1], atol=1e-9)
    assert at_corner or end <= slide[-1] <= end + 2 * STEP
    assert slide[-1] <= end + 2 * STEP


def test_no_leg_beside_the_surface_across_a_hole() -> None:
    """A slot cut out of the plane between two spots (a hole in the capture, in the surface's own plane: no
    leg runs above or under the surface there, only beside it): the sweep goes round the slot, never across."""
    spots = lambda p: (np.linalg.norm(np.abs(p[:, :2]) - [0.05, 0.0], axis=1) <= 0.008).astype(float)  # noqa: E731
    whole = _plane(spots)
    keep = ~((np.abs(whole.points[:, 0]) < 0.03) & (np.abs(whole.points[:, 1]) < 0.015))
    cloud = SurfaceCloud(points=whole.points[keep], normals=whole.normals[keep], target=whole.target[keep],
                         spacing=whole.spacing)
    tree = cKDTree(cloud.points)
    plan = plan_sweep(cloud, tree, cloud.target, np.array([-0.05, 0.0, 0.0]), R, PER_M, STEP, goal=0.9, seed=0)
    assert plan is not None and _wiped_share(cloud, plan.waypoints) >= 0.9 - 0.01  # both spots
    # every step of the slide stays on the captured surface (the slot is 6 x 3 cm, its middle 15 mm from it)
    step = np.diff(plan.waypoints, axis=0)[:, None]
    along = plan.waypoints[:-1, None] + np.linspace(0.0, 1.0, 5)[None, :, None] * step
    assert tree.query(along.reshape(-1, 3))[0].max() <= MAX_LINE_GAP_M


def _two_islands(spot_half_m: float) -> SurfaceCloud:
    """The strip and, 8 cm beside it (farther than two pad radii), a square spot of half-width ``spot_half_m``."""
    return _plane(lambda p: np.maximum(_strip(p), ((np.abs(p[:, 0]) <= spot_half_m + 1e-9)
                                                   & (np.abs(p[:, 1] - 0.09) <= spot_half_m + 1e-9)).astype(float)))


@pytest.mark.parametrize(("spot_half_m", "planned"), [(0.003, True), (0.009, False)])
def test_the_first_sweep_needs_the_touch_down_s_island_to_hold_nearly_all_the_dirt(spot_half_m: float,
                                                                                  planned: bool) -> None:
    """``tactex clean`` plans its sweep only when the touch-down's island holds SWEEP_MIN_SHARE (95 %) of the view's
    dirt: beside the strip (265 points) a spot of 9 points (3 %) leaves it the sweep, one of 49 (16 %) does not."""
    cloud = _two_islands(spot_half_m)
    cfg = CleanConfig()
    wear = WearModel(cloud, cfg.preston_coefficient, cfg.pad_radius_m)
    view = wear.remaining()
    here = np.zeros(3)
    island = dirt_island(cloud.points, view, here, 2 * cfg.pad_radius_m, spacing_m=cloud.spacing)
    share = view[island].sum() / view.sum()
    assert (share >= SWEEP_MIN_SHARE) == planned  # the scenario straddles the gate
    stroke, plan, choice = _first_leg(cloud, wear, here, np.array([0.0, -0.3, 0.3]), cfg, STEP, None)
    assert (plan is not None) == planned and (stroke is not None) == planned  # the strip is no small island
    assert choice.startswith("a planned sweep over strokes" if planned else "the explorer (the island there holds")
    if plan is not None:  # over the touch-down's island only, driven as planned
        np.testing.assert_array_equal(stroke.path.waypoints, plan.waypoints)
        assert np.all(np.abs(plan.corners[:, 1]) <= 0.006 + R)


def _bowl(target, sphere_m: float, rim_m: float, spacing: float = 0.003) -> SurfaceCloud:
    """The inside of a spherical bowl of radius ``sphere_m`` [m] cut at ``rim_m`` [m] from its axis, lowest point
    at the origin, normals up into the bowl."""
    g = np.arange(-rim_m, rim_m + 1e-9, spacing)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    keep = x**2 + y**2 <= rim_m**2
    x, y = x[keep], y[keep]
    z = sphere_m - np.sqrt(sphere_m**2 - x**2 - y**2)
    pts = np.column_stack([x, y, z])
    normals = (np.array([0.0, 0.0, sphere_m]) - pts) / sphere_m
    return SurfaceCloud(points=pts, normals=normals, target=target(pts), spacing=spacing)


def _x(p: np.ndarray) -> np.ndarray:
    """An X of two 14 cm strokes, 14 mm wide, crossing at the origin on the diagonals."""
    u, v = (p[:, 0] + p[:, 1]) / np.sqrt(2), (p[:, 0] - p[:, 1]) / np.sqrt(2)
    arm = lambda a, b: (np.abs(a) <= 0.07) & (np.abs(b) <= 0.007)  # noqa: E731
    return (arm(u, v) | arm(v, u)).astype(float)


def test_a_sweep_over_an_x_in_a_bowl_follows_the_bowl_s_floor() -> None:
    """The X on the bowl (15 cm sphere): each arm's chord runs up to 17 mm above the floor it crosses, and the
    planner used to refuse every leg more than 4 mm above the surface, so no sweep: now a leg whose path brought
    onto the surface is smooth and at most MAX_SURFACE_DETOUR longer than its chord slides along the floor, and the
    arms' tips seed the search (random corners seldom land on all four)."""
    cloud = _bowl(_x, sphere_m=0.15, rim_m=0.09)
    tree = cKDTree(cloud.points)
    tip = cloud.points[np.argmin(np.linalg.norm(cloud.points[:, :2] - [0.045, 0.045], axis=1))]
    plan = plan_sweep(cloud, tree, cloud.target, tip, R, PER_M, STEP, goal=0.97, seed=0)
    assert plan is not None
    assert _wiped_share(cloud, plan.waypoints) >= 0.97 - 0.01
    # along both arms once (2 × 14 cm, a little beyond their tips) and across between them: no loop
    assert plan.length_m <= 0.55
    # the path lies on the bowl, not on the chords above it
    assert tree.query(plan.waypoints)[0].max() <= cloud.spacing


def test_a_leg_slides_over_a_smooth_hollow_and_not_round_a_deep_one_or_across_a_jump() -> None:
    """The rule for a chord above the surface: its path on the surface must have no step over MAX_STEP_OVER_CHORD_STEP
    of the chord's (a jump, or a deep hollow) and be at most MAX_SURFACE_DETOUR times the chord."""
    chord, n = 0.1, 40
    smooth = np.full(n, 1.1 * chord / n)
    assert sweep_plan._follows_surface(smooth, chord)
    assert not sweep_plan._follows_surface(np.full(n, (sweep_plan.MAX_SURFACE_DETOUR + 0.1) * chord / n), chord)
    jump = smooth.copy()
    jump[n // 2] = (sweep_plan.MAX_STEP_OVER_CHORD_STEP + 0.2) * chord / n
    assert not sweep_plan._follows_surface(jump, chord)


def test_a_leg_across_a_bowl_follows_its_floor_and_one_round_a_deep_hemisphere_is_refused() -> None:
    """A leg from rim to rim of a 15 cm sphere cut 8.5 cm from its axis: its chord runs 26 mm above the floor (the
    old rule refused any leg more than 4 mm above the surface), its path along the floor 1.06 times the chord: the
    leg slides on the floor. Round a hemisphere of 5 cm from rim to rim the path is 1.4 times the chord: refused (its
    steps near the floor are several chord steps long)."""
    for sphere_m, rim_m, slides in ((0.15, 0.0865, True), (0.05, 0.0499, False)):
        cloud = _bowl(lambda p: np.ones(len(p)), sphere_m=sphere_m, rim_m=rim_m, spacing=0.002)
        tree = cKDTree(cloud.points)
        ends = [int(np.argmin(np.linalg.norm(cloud.points[:, :2] - [x, 0.0], axis=1))) for x in (-rim_m, rim_m)]
        a, b = cloud.points[ends]
        half = np.arcsin(0.5 * np.linalg.norm(a - b) / sphere_m)
        arc_over_chord = half / np.sin(half)
        assert (arc_over_chord <= sweep_plan.MAX_SURFACE_DETOUR) == slides, arc_over_chord  # the case's premise
        pred = sweep_plan._Predictor(cloud, tree, cloud.target, R, PER_M, STEP, None)
        leg = pred.leg(*ends)
        assert (leg is not None) == slides, sphere_m
        if leg is not None:
            assert tree.query(leg[0])[0].max() <= cloud.spacing  # on the floor, not on the chord
            assert leg[1].sum() == pytest.approx(arc_over_chord * np.linalg.norm(a - b), rel=0.05)


def test_a_stroke_along_the_cloud_s_edge_is_still_a_stroke() -> None:
    """A strip 2 cm wide along the capture's edge: its points have no clean point beyond the edge, which counts as
    clean surface; a 6 cm square at the edge is a blob."""
    cloud = _plane(lambda p: np.zeros(len(p)))
    edge_x = cloud.points[:, 0].max()
    strip = (cloud.points[:, 0] >= edge_x - 0.02) & (np.abs(cloud.points[:, 1]) <= 0.08)
    assert sweep_plan.stroke_like(cloud.points, cKDTree(cloud.points), strip, R, cloud.spacing)
    square = (cloud.points[:, 0] >= edge_x - 0.06) & (np.abs(cloud.points[:, 1]) <= 0.03)
    assert not sweep_plan.stroke_like(cloud.points, cKDTree(cloud.points), square, R, cloud.spacing)


@pytest.mark.parametrize(("marking", "strokes"), [(_x, True), (_strip, True),
                                                  (lambda p: (np.linalg.norm(p[:, :2], axis=1) <= 0.03).astype(float),
                                                   False)])
def test_strokes_get_a_planned_sweep_and_a_blob_the_explorer(marking, strokes: bool) -> None:
    """An island of strokes narrower than a pad radius (an X, a strip) starts with a planned sweep; a blob of 3 cm
    radius, wider than the pad, with the explorer, and the choice is said in one line."""
    cloud = _plane(marking)
    cfg = CleanConfig()
    tree = cKDTree(cloud.points)
    assert sweep_plan.stroke_like(cloud.points, tree, cloud.target > 0, cfg.pad_radius_m, cloud.spacing) == strokes
    wear = WearModel(cloud, cfg.preston_coefficient, cfg.pad_radius_m)
    here = cloud.points[np.flatnonzero(cloud.target > 0)[0]]
    stroke, plan, choice = _first_leg(cloud, wear, here, np.array([0.0, -0.3, 0.3]), cfg, STEP, None)
    assert (plan is not None) == strokes and (stroke is not None) == strokes
    assert choice.startswith("a planned sweep over strokes" if strokes else "the explorer (the dirt is a blob")


def test_with_no_dirt_the_first_leg_is_the_explorer_and_says_why() -> None:
    cloud = _plane(lambda p: np.zeros(len(p)))
    cfg = CleanConfig()
    wear = WearModel(cloud, cfg.preston_coefficient, cfg.pad_radius_m)
    assert _first_leg(cloud, wear, np.zeros(3), np.array([0.0, -0.3, 0.3]), cfg, STEP, None) == (
        None, None, "the explorer (the wear model sees no dirt left)")


def test_no_leg_shorter_than_the_corner_the_tool_rounds() -> None:
    """The tool trails the agent and rounds each corner: an out-and-back jiggle of a centimetre to an X's tip was
    planned as wiping it and left the tip dirty. No corner turns back next to a leg shorter than MIN_LEG_RADII pad
    radii, whatever the search's draws."""
    cloud = _bowl(_x, sphere_m=0.15, rim_m=0.09)
    tree = cKDTree(cloud.points)
    tip = cloud.points[np.argmin(np.linalg.norm(cloud.points[:, :2] - [0.03, 0.035], axis=1))]
    for seed in range(4):
        plan = plan_sweep(cloud, tree, cloud.target, tip, R, PER_M, STEP, goal=0.97, seed=seed)
        assert plan is not None
        legs = np.diff(plan.corners, axis=0)
        short = np.linalg.norm(legs, axis=1) < sweep_plan.MIN_LEG_RADII * R
        back = np.einsum("ij,ij->i", legs[:-1], legs[1:]) < 0.0
        assert not np.any(back & (short[:-1] | short[1:])), f"seed {seed}: corners {np.round(plan.corners, 3)} m"


@pytest.mark.parametrize("five_reach", [True, False])
def test_the_fewest_corners_are_searched_first(monkeypatch: pytest.MonkeyPatch, five_reach: bool) -> None:
    """A sweep of FEW_CORNERS legs when one reaches the goal; one of up to sweep_corners only when none does."""
    import tactex.tasks.clean.legs as legs_module

    calls: list[int] = []
    plan_real = legs_module.plan_sweep

    def recording(*args, **kwargs):
        calls.append(kwargs["max_corners"])
        if kwargs["max_corners"] == legs_module.FEW_CORNERS and not five_reach:
            return None
        return plan_real(*args, **kwargs)

    monkeypatch.setattr(legs_module, "plan_sweep", recording)
    cloud = _plane(_strip)
    cfg = CleanConfig(sweep_corners=8)
    wear = WearModel(cloud, cfg.preston_coefficient, cfg.pad_radius_m)
    _, plan, choice = _first_leg(cloud, wear, np.array([0.0, 0.0, 0.0]), np.array([0.0, -0.3, 0.3]), cfg, STEP, None)
    assert plan is not None and choice.startswith("a planned sweep over strokes")
    assert calls == ([legs_module.FEW_CORNERS] if five_reach else [legs_module.FEW_CORNERS, 8])


def test_the_annealing_takes_a_longer_trial_as_often_as_its_temperature_says() -> None:
    rng = np.random.default_rng(0)
    taken = np.mean([sweep_plan._uphill_taken(0.005, 0.005, rng) for _ in range(20000)])
    assert abs(taken - np.exp(-1.0)) < 0.015
    assert not sweep_plan._uphill_taken(np.inf, 0.005, rng)  # a trial that never reaches the goal: never
    assert not any(sweep_plan._uphill_taken(1e-9, 0.0, rng) for _ in range(100))  # cooled: a pure descent


def _letters(p: np.ndarray) -> np.ndarray:
    """Three letters side by side (8 cm tall, 1 cm wide strokes): an R, an L and an I, joined within two pad
    radii into one island of strokes whose shortest sweep has many local minima."""
    x, y, w = p[:, 0], p[:, 1], 0.005
    r = ((np.abs(x + 0.06) <= w) & (np.abs(y) <= 0.04)) | ((np.abs(y - 0.04) <= w) & (x >= -0.06) & (x <= -0.03)) \
        | ((np.abs(x + 0.03) <= w) & (y >= 0.0) & (y <= 0.04)) | ((np.abs(y) <= w) & (x >= -0.06) & (x <= -0.03)) \
        | ((np.abs(x + 0.045 + 0.375 * y) <= w) & (y <= 0.0) & (y >= -0.04))
    ell = ((np.abs(x) <= w) & (np.abs(y) <= 0.04)) | ((np.abs(y + 0.04) <= w) & (x >= 0.0) & (x <= 0.03))
    i = (np.abs(x - 0.06) <= w) & (np.abs(y) <= 0.04)
    return (r | ell | i).astype(float)


def test_the_annealed_search_plans_shorter_sweeps_than_a_descent_moving_one_corner(request) -> None:
    cloud = _plane(_letters, half=0.1)
    tree, start = cKDTree(cloud.points), np.zeros(3)

    def mean_length() -> float:
        plans = [plan_sweep(cloud, tree, cloud.target, start, R, PER_M, STEP, goal=0.97, max_corners=8, seed=s)
                 for s in range(4)]
        assert all(p is not None for p in plans)
        return float(np.mean([p.length_m for p in plans]))

    annealed = mean_length()
    request.getfixturevalue("descent_sweep_search")
    descent = mean_length()
    # the same trials' budget: the descent keeps its polylines' order and legs and stops in the first local minimum
    # it meets
    assert annealed < descent - 0.01
