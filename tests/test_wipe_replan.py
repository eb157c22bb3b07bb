"""``tactex wipe --replan-from RUN_DIR``: the explored surface of an earlier wipe puts the motion reference on the
part and feeds the normal ahead to VA-UFIC (tactex.tasks.explored_surface)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tactex.errors import ConfigError, InputError
from tactex.experiments.run import run_task, task_summary
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.pointcloud.io import save_ply
from tactex.tasks.explored_surface import MIN_EXPLORED_POINTS, ExploredSurface
from tactex.tasks.wipe import WipeConfig, run_wipe
from tactex.tasks.wipe_references import REPLAN_DEPTH_M

RADIUS_M = 0.1


def _sphere_band(n: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """Contact points along an arc of a 10 cm sphere (a first pass's path, 3 mm apart) and their normals."""
    a = np.linspace(-0.9, 0.9, n)  # [rad]
    normals = np.column_stack([np.sin(a), np.zeros(n), np.cos(a)])
    return RADIUS_M * normals, normals


def test_the_local_plane_lies_on_the_explored_surface_near_the_path() -> None:
    pts, nrm = _sphere_band()
    surface = ExploredSurface(pts, nrm, np.full(len(pts), 0.05), spacing_m=0.003)
    for a, off_y in ((0.2, 0.0), (-0.5, 0.004), (0.7, 0.01)):
        on = RADIUS_M * np.array([np.sin(a), 0.0, np.cos(a)]) + np.array([0.0, off_y, 0.0])
        query = on + 0.012 * np.array([np.sin(a), 0.0, np.cos(a)])  # 12 mm above the surface
        near = surface.near(query)
        # the plane through the nearest contact points: on the sphere to its sagitta over the offset
        assert abs(np.linalg.norm(near.point_m) - RADIUS_M) < 1e-3 + off_y**2 / RADIUS_M
        assert np.degrees(np.arccos(np.clip(near.normal @ [np.sin(a), 0.0, np.cos(a)], -1, 1))) < 3.0
        assert near.gap_m == pytest.approx(off_y, abs=2e-3)
        assert near.curvature == pytest.approx(0.05)
    nan_curv = ExploredSurface(pts, nrm, np.full(len(pts), np.nan), spacing_m=0.003)
    assert np.isnan(nan_curv.near(pts[10]).curvature)


def test_bad_explored_surfaces_are_refused_in_one_line(tmp_path) -> None:
    pts, nrm = _sphere_band()
    with pytest.raises(InputError, match="usable contact points"):
        ExploredSurface(pts[: MIN_EXPLORED_POINTS - 1], nrm[: MIN_EXPLORED_POINTS - 1],
                        np.zeros(MIN_EXPLORED_POINTS - 1), 0.003)
    with pytest.raises(InputError, match=r"\(N, 3\) points"):
        ExploredSurface(pts, nrm[:, :2], np.zeros(len(pts)), 0.003)
    with pytest.raises(InputError, match="no such run folder"):
        ExploredSurface.from_run(tmp_path / "missing")
    with pytest.raises(InputError, match=r"no explored\.ply"):
        ExploredSurface.from_run(tmp_path)
    save_ply(SurfaceCloud(points=pts, spacing=0.003), tmp_path / "explored.ply")
    with pytest.raises(InputError, match="no normals"):
        ExploredSurface.from_run(tmp_path)


def test_a_replan_needs_a_wipe_of_the_same_part(tmp_path) -> None:
    with pytest.raises(ConfigError, match="no such run folder"):
        WipeConfig(replan_from=str(tmp_path / "nothing"))
    with pytest.raises(ConfigError, match=r"no explored\.ply in it"):
        WipeConfig(replan_from=str(tmp_path))
    pts, nrm = _sphere_band()
    save_ply(SurfaceCloud(points=pts, normals=nrm, spacing=0.003), tmp_path / "explored.ply")
    (tmp_path / "config.json").write_text(json.dumps({"object_name": "bowl"}))
    with pytest.raises(ConfigError, match="explored 'bowl', this wipe is on 'sine_panel'"):
        WipeConfig(replan_from=str(tmp_path))
    with pytest.raises(ConfigError, match="drop --baseline"):
        WipeConfig(object_name="bowl", replan_from=str(tmp_path), baseline="cartesian")
    with pytest.raises(ConfigError, match="replan_lead_s"):
        WipeConfig(replan_lead_s=-1.0)
    with pytest.raises(ConfigError, match=r"replan_learn_gain must lie in \[0, 1\]"):
        WipeConfig(replan_learn_gain=1.5)
    with pytest.raises(ConfigError, match="passes must be 1 or 2"):
        WipeConfig(passes=3)
    with pytest.raises(ConfigError, match="drop --replan-from"):
        WipeConfig(object_name="bowl", replan_from=str(tmp_path), passes=2)
    with pytest.raises(ConfigError, match="drop --baseline"):
        WipeConfig(passes=2, baseline="cartesian")
    assert WipeConfig(object_name="bowl", replan_from=str(tmp_path), start_y_m=-0.09).replan_from == str(tmp_path)


def _depths(surface: ExploredSurface, desired_m: np.ndarray) -> np.ndarray:
    """How far into the explored surface each 20th desired position lies, along its normal [m]."""
    return np.array([(surface.near(p).point_m - p) @ surface.near(p).normal for p in desired_m[::20]])


# long enough for ρ_align to reach 1 on the bowl in both passes
BASE = dict(object_name="bowl", policy="examples/policies/zigzag.toml", start_y_m=0.0, duration_s=12.0)


@pytest.fixture(scope="module")
def two_passes(tmp_path_factory):
    out, base = tmp_path_factory.mktemp("replan"), BASE
    first = run_task("wipe", WipeConfig(**base), out / "first", progress=False, video=False)
    second = run_task("wipe", WipeConfig(**base, replan_from=str(out / "first")), out / "second", progress=False,
                      video=False)
    return first, second


def test_the_second_pass_follows_the_explored_surface(two_passes) -> None:
    first, second = two_passes
    replan = second.metrics["replan"]
    assert replan["explored_points"] >= MIN_EXPLORED_POINTS
    assert replan["on_explored_fraction"] > 0.8  # the same policy runs where the first pass touched
    assert replan["first_pass"]["force_mae_n"] == pytest.approx(first.metrics["force_mae_n"])
    # the desired position sits REPLAN_DEPTH_M into the explored surface wherever the re-plan placed it
    surface = ExploredSurface.from_run(first.out_dir)
    s = np.load(second.out_dir / "series.npz", allow_pickle=False)
    contact = s["in_contact"] > 0.5
    assert np.median(_depths(surface, s["desired"][contact])) == pytest.approx(REPLAN_DEPTH_M, abs=2e-3)
    # the first pass's own reference, planned in the tangent plane, lies farther from it
    s1 = np.load(first.out_dir / "series.npz", allow_pickle=False)
    depth1 = _depths(surface, s1["desired"][s1["in_contact"] > 0.5])
    assert np.median(np.abs(np.asarray(depth1) - REPLAN_DEPTH_M)) > 2e-3
    for m in (first.metrics, second.metrics):
        assert m["torque_rate_clip_ticks"] == 0 and m["max_force_over_set_point"] < 2.0
    # the error without its part along the tool axis: its squared RMSEs sum to the mean squared in-plane
    # tool-frame error over the aligned contact ticks (the series holds every 10th tick), and to no more than
    # the base frame's
    for run in (first, second):
        m, s = run.metrics, np.load(run.out_dir / "series.npz", allow_pickle=False)
        assert m["aligned_at_s"] is not None  # BASE's duration lets VA-UFIC align on the bowl
        tangent, world = np.asarray(m["motion_rmse_tangent_m"]), np.asarray(m["motion_rmse_m"])
        aligned = (s["in_contact"] > 0.5) & (s["rho_align"] >= 1.0 - 1e-9)
        in_plane = float(np.mean(np.sum(s["motion_error_tool"][aligned, :2] ** 2, axis=1)))
        assert float(tangent @ tangent) == pytest.approx(in_plane, rel=0.05)
        assert float(tangent @ tangent) <= float(world @ world) + 1e-12


def test_the_terminal_shows_the_first_pass_beside_the_second(two_passes) -> None:
    _, second = two_passes
    lines = task_summary([second]).splitlines()
    assert lines[2].startswith("first pass (first)") and lines[3].startswith(second.label)
    # and what it learned from the first pass, in its own line
    learned = second.metrics["replan"]["learned"]
    said = [line for line in lines if line.startswith(f"re-plan ({second.label}): ")]
    assert len(said) == 1, lines
    assert (learned["note"] in said[0]) if learned["note"] else f"{learned['force_rms_n']:.2f} N RMS" in said[0]


def test_the_re_plan_line_says_what_was_learned_or_why_not() -> None:
    from tactex.report.run_pages import learning_summary

    learned = {"gain": 0.8, "note": "", "force_rms_n": 0.123, "force_max_abs_n": 0.9, "offset_rms_m": [0.0012, 0.0004]}
    line = learning_summary({"replan": {"learned": learned}})
    assert line == ("learned from the first pass (gain 0.8): force corrections 0.12 N RMS (largest 0.90 N), "
                    "in-plane 1.2/0.4 mm RMS (tool x/y)")
    assert learning_summary({"replan": {"learned": {**learned, "note": "it slipped"}}}) == (
        "learned nothing from the first pass: it slipped")
    assert learning_summary({"replan": {"learned": None}}) is None and learning_summary({}) is None


def test_two_passes_in_one_run_re_plan_the_second_on_the_first(two_passes) -> None:
    """``passes = 2`` (what a study varies: its runs keep no folder to re-plan from) runs the first pass and the
    second planned on it, and reports the second with the first's figures, the same as the two runs above."""
    first, second = two_passes
    both = run_wipe(WipeConfig(**BASE, passes=2), progress=False).metrics
    assert both["replan"]["from"] == "the first pass"
    assert both["replan"]["first_pass"]["force_mae_n"] == pytest.approx(first.metrics["force_mae_n"])
    assert both["force_mae_n"] == pytest.approx(second.metrics["force_mae_n"], rel=1e-6)


class _CountingPlane:
    """An explored surface that is the plane z = 0 (normal +z), counting how often it is read."""

    def __init__(self, gap_m: float = 0.0) -> None:
        self.reads, self.gap_m = 0, gap_m

    def near(self, query_m):
        from tactex.tasks.explored_surface import SurfacePoint

        self.reads += 1
        q = np.asarray(query_m, dtype=float)
        return SurfacePoint(np.array([q[0], q[1], 0.0]), np.array([0.0, 0.0, 1.0]), 0.0, self.gap_m)


def test_the_re_plan_reads_the_explored_surface_every_10_ms_and_projects_between() -> None:
    from tactex.tasks.wipe_policy import wipe_policy
    from tactex.tasks.wipe_references import REPLAN_READ_EVERY_S, WipeReferences

    cfg = WipeConfig()
    plane = _CountingPlane()
    refs = WipeReferences(cfg, None, np.array([0.0, 0.0, 0.01]), np.eye(3), wipe_policy(cfg, None), plane)
    twist = np.array([0.05, 0.0, 0.0, 0.0, 0.0, 0.0])
    dt, n = 0.001, 100
    for i in range(n):
        refs.pos_ref = np.array([0.001 * i, 0.0, 0.01 + 0.001 * (i % 3)])  # wherever the policy moved it
        surface = refs._on_explored(i * dt, twist)
        # every tick: the desired position REPLAN_DEPTH_M into the plane, read or not
        assert refs.pos_ref[2] == pytest.approx(-REPLAN_DEPTH_M) and refs.pos_ref[0] == pytest.approx(0.001 * i)
        assert surface is not None and surface.valid and np.allclose(surface.normal_world, [0.0, 0.0, 1.0])
    assert plane.reads == 2 * round(n * dt / REPLAN_READ_EVERY_S)  # here and ahead, once per read
    assert refs.on_explored == n
    # off the explored surface (farther than REPLAN_GAP_M from any contact): the camera's estimate, no shift
    far = _CountingPlane(gap_m=1.0)
    refs = WipeReferences(cfg, None, np.array([0.0, 0.0, 0.01]), np.eye(3), wipe_policy(cfg, None), far)
    assert refs._on_explored(0.0, twist) is None and refs.pos_ref[2] == pytest.approx(0.01) and far.reads == 1


class _NoCamera:
    def update(self, state):
        return None


class _State:
    def __init__(self, t: float, rotation: np.ndarray) -> None:
        self.t, self.ee_rotation = t, rotation


def test_a_learned_correction_moves_the_commands_not_what_the_run_is_measured_against() -> None:
    """The second pass commands the policy plus what the first pass's errors call for; the position and force
    the run's figures compare with (``pos_ref``, ``force_set_n``) stay the policy's own."""
    from tactex.tasks.pass_learning import PassCorrection
    from tactex.tasks.wipe_policy import wipe_policy
    from tactex.tasks.wipe_references import WipeReferences

    cfg = WipeConfig()
    t = 0.01 * np.arange(200)
    # +2 N and (1, −2) mm in the tool's x/y all along, except −20 N from 1 s on (below the contact threshold)
    force = np.where(t < 1.0, 2.0, -20.0)
    learned = PassCorrection(t, force, np.tile([0.001, -0.002], (len(t), 1)), 0.8)
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # tool x along world y
    p0 = np.array([0.1, 0.2, 0.3])
    plain = WipeReferences(cfg, _NoCamera(), p0, rot, wipe_policy(cfg, None))
    taught = WipeReferences(cfg, _NoCamera(), p0, rot, wipe_policy(cfg, None), learned=learned)
    for tau in (0.2, 0.5):
        plain.advance(_State(tau, rot), tau)
        taught.advance(_State(tau, rot), tau)
        assert taught.pos_ref == pytest.approx(plain.pos_ref) and taught.force_set_n == plain.force_set_n
        shift = taught.reference.position_world - plain.reference.position_world
        assert shift == pytest.approx(rot @ [0.001, -0.002, 0.0])
        assert taught.reference.wrench_tool[2] == pytest.approx(plain.reference.wrench_tool[2] + 2.0)
    taught.advance(_State(1.5, rot), 1.5)
    assert taught.reference.wrench_tool[2] == pytest.approx(cfg.contact_threshold_n)  # never below contact
    assert taught.force_set_n == pytest.approx(cfg.force_n)


def test_the_path_correction_waits_for_this_pass_to_align_and_fades_in() -> None:
    """The in-plane correction, learned where the first pass was aligned, is applied from where this one is
    (ρ_align = 1), faded in; the force correction, learned over all settled contact, over the whole pass."""
    from tactex.tasks.pass_learning import PassCorrection
    from tactex.tasks.wipe_policy import wipe_policy
    from tactex.tasks.wipe_references import LEARN_FADE_IN_S, WipeReferences

    cfg = WipeConfig()
    t = 0.01 * np.arange(400)
    learned = PassCorrection(t, np.full(len(t), 2.0), np.column_stack([np.full(len(t), 0.003), np.zeros(len(t))]),
                             0.8)
    is_aligned = [False]
    refs = WipeReferences(cfg, _NoCamera(), np.zeros(3), np.eye(3), wipe_policy(cfg, None), learned=learned,
                          aligned=lambda: is_aligned[0])
    for tau, aligned, share in ((0.5, False, 0.0), (1.0, False, 0.0), (1.5, True, 0.0),
                                (1.5 + LEARN_FADE_IN_S / 2, False, 0.5), (3.0, False, 1.0)):
        is_aligned[0] = aligned  # once aligned, it stays on whatever ρ_align does later
        refs.advance(_State(tau, np.eye(3)), tau)
        assert refs.reference.wrench_tool[2] == pytest.approx(refs.force_set_n + 2.0), tau
        # the tool frame is the world's here: the path's correction is along world x
        offset = refs.reference.position_world - refs.pos_ref
        assert offset == pytest.approx([share * 0.003, 0.0, 0.0], abs=1e-12), tau
