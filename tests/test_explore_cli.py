"""`tactex explore`: end-to-end runs through tactex.cli.main, outputs, and bad-input handling."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tactex.cli import main
from tactex.experiments import ExploreConfig, load_explore_cloud, run_explore
from tactex.pointcloud import SurfaceCloud, save_npz, save_ply
from tests.conftest import tec_cloud_path

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
STEPS = 50


@pytest.fixture(autouse=True)
def _cache_dir(tmp_path_factory, monkeypatch: pytest.MonkeyPatch) -> None:
    # Never write into the user's ~/.cache from tests.
    monkeypatch.setenv("TACTEX_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "basis-cache"))


def _check_run(out, steps: int) -> dict:
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["series_file"] == "series.npz" and "ergodicity" not in metrics  # per-step series in the npz
    with np.load(out / "series.npz", allow_pickle=False) as z:
        metrics.update({k: z[k] for k in z.files})
    traj = np.load(out / "trajectory.npy", allow_pickle=False)
    assert traj.shape == (steps, 3) and np.isfinite(traj).all()
    for key in ("ergodicity", "coverage_residual", "path_length_m"):
        series = np.asarray(metrics[key], dtype=float)
        assert series.shape == (steps,) and np.isfinite(series).all(), key
    erg, res, path = (np.asarray(metrics[k], dtype=float) for k in ("ergodicity", "coverage_residual", "path_length_m"))
    assert np.all(erg >= 0) and np.all(erg <= 1.0 + 1e-9)
    assert np.all(res >= 0) and np.all(res <= 1.0 + 1e-9)
    assert np.all(np.diff(path) >= -1e-12) and path[0] >= 0
    # The path length is the sum of the steps between recorded positions (plus the first step).
    steps_len = np.linalg.norm(np.diff(traj, axis=0), axis=1).sum()
    assert path[-1] >= steps_len - 1e-9
    assert metrics["n_points"] > 0 and 0 < metrics["n_target"] <= metrics["n_points"]
    assert metrics["preprocess_time_s"] > 0 and metrics["step_time_median_s"] > 0
    for name in ("metrics.png", "cloud.png"):
        assert (out / name).read_bytes()[:8] == PNG_MAGIC
    fields = np.load(out / "fields.npz", allow_pickle=False)
    assert fields["points"].shape == (metrics["n_points"], 3)
    assert np.isfinite(fields["coverage"]).all() and np.isfinite(fields["potential"]).all()
    return metrics


def test_explore_builtin_plate_end_to_end(tmp_path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    code = main(["explore", "plate", "--steps", str(STEPS), "--n-eigen", "60", "--out", str(out), "--seed", "3"])
    assert code == 0
    metrics = _check_run(out, STEPS)
    source = metrics["source"]
    assert {k: source[k] for k in ("kind", "name", "marking")} == {
        "kind": "builtin", "name": "plate", "marking": "shapes"}
    assert source["target_where"].startswith(f"{metrics['n_target']} of {metrics['n_points']} points are target")
    assert metrics["explorer_config"]["agent_radius_m"] == pytest.approx(0.015)  # TEC: 15 mm on the plate
    assert metrics["config"]["n_eigen"] == 60 and metrics["explorer_config"]["n_eigen"] == 60
    # Exploring covers target: the residual falls from its start.
    assert metrics["coverage_residual"][-1] < metrics["coverage_residual"][0]
    html = (out / "explore.html").read_text()
    assert "<script src=" not in html and '"potential"' in html and '"path"' in html
    captured = capsys.readouterr()
    assert f"step {STEPS}/{STEPS}" in captured.err and "ergodicity" in captured.out


def test_whole_surface_target_sweeps_and_a_marked_one_does_not(tmp_path, capsys) -> None:
    base = ["explore", "plate", "--steps", "40", "--n-eigen", "60", "--no-html"]
    assert main([*base, "--marking", "full", "--out", str(tmp_path / "all")]) == 0
    err = capsys.readouterr().err
    assert "source: sweep" in err and "planned passes 1.8 r_a apart from the outer edge" in err
    whole = json.loads((tmp_path / "all" / "metrics.json").read_text())
    assert whole["source_mode"] == "sweep" and whole["n_target"] == whole["n_points"] and whole["planned_passes"]
    assert main([*base, "--marking", "full", "--sweep-pass-spacing", "0", "--out", str(tmp_path / "alone")]) == 0
    err = capsys.readouterr().err
    assert "source: sweep" in err and "planned passes" not in err
    assert not json.loads((tmp_path / "alone" / "metrics.json").read_text())["planned_passes"]
    assert main([*base, "--out", str(tmp_path / "red")]) == 0
    assert "source: sweep" not in capsys.readouterr().err
    assert json.loads((tmp_path / "red" / "metrics.json").read_text())["source_mode"] == "ergodic"
    assert main([*base, "--marking", "full", "--source-mode", "ergodic", "--out", str(tmp_path / "e")]) == 0
    assert json.loads((tmp_path / "e" / "metrics.json").read_text())["source_mode"] == "ergodic"
    # a user's own file with --target-channel all
    g = np.linspace(-0.04, 0.04, 27)
    x, y = np.meshgrid(g, g)
    path = save_ply(SurfaceCloud(points=np.column_stack([x.ravel(), y.ravel(), 0.0 * x.ravel()]),
                                 colors=np.full((x.size, 3), 0.5)), tmp_path / "sheet.ply")
    file_args = ["explore", str(path), "--target-channel", "all", "--steps", "30", "--n-eigen", "50", "--no-html"]
    assert main([*file_args, "--out", str(tmp_path / "file")]) == 0
    assert json.loads((tmp_path / "file" / "metrics.json").read_text())["source_mode"] == "sweep"


def test_explore_is_reproducible(tmp_path) -> None:
    args = ["explore", "cup", "--steps", "20", "--n-eigen", "40", "--no-html", "--quiet", "--seed", "5"]
    assert main([*args, "--out", str(tmp_path / "a")]) == 0
    assert main([*args, "--out", str(tmp_path / "b")]) == 0
    a = np.load(tmp_path / "a" / "trajectory.npy")
    b = np.load(tmp_path / "b" / "trajectory.npy")
    np.testing.assert_array_equal(a, b)
    assert not (tmp_path / "a" / "explore.html").exists()


def test_explore_file_with_red_target_and_x0(tmp_path) -> None:
    g = np.linspace(-0.05, 0.05, 34)
    x, y = np.meshgrid(g, g)
    pts = np.column_stack([x.ravel(), y.ravel(), 0.02 * x.ravel() ** 2])
    red = (np.abs(x.ravel()) < 0.015) & (np.abs(y.ravel()) < 0.03)
    colors = np.where(red[:, None], [1.0, 0.0, 0.0], [0.5, 0.5, 0.5])
    path = save_ply(SurfaceCloud(points=pts, colors=colors), tmp_path / "patch.ply")
    out = tmp_path / "run"
    base = ["explore", str(path), "--voxel-size", "0", "--steps", "30", "--n-eigen", "50", "--quiet", "--no-html"]
    code = main([*base, "--x0", "0.0", "0.0", "0.01", "--agent-radius", "0.006", "--out", str(out)])
    assert code == 0
    metrics = _check_run(out, 30)
    assert metrics["n_target"] == int(red.sum()) and metrics["n_points"] == pts.shape[0]
    assert metrics["x0_source"] == "given" and metrics["explorer_config"]["agent_radius_m"] == 0.006
    # The start is projected onto the surface (z = 0.02 x², so ≈ 0 at the origin).
    assert abs(metrics["start_on_surface"][2]) < 1e-3


def test_explore_tec_bunny_uses_authors_start(tmp_path) -> None:
    path = tec_cloud_path("bun270_X")
    out = tmp_path / "bunny"
    assert (
        main(["explore", str(path), "--steps", "30", "--n-eigen", "50", "--quiet", "--no-html", "--out", str(out)]) == 0
    )
    metrics = _check_run(out, 30)
    assert metrics["n_points"] == 2996 and metrics["n_target"] == 210  # the dataset README's counts
    assert metrics["x0_source"] == "bun270_X_x0_arr_10.npz[0]"
    assert metrics["explorer_config"]["agent_radius_m"] == pytest.approx(0.0075)


def test_run_explore_api_returns_metrics(tmp_path) -> None:
    messages: list[str] = []
    result = run_explore(
        "bowl",
        tmp_path / "bowl",
        ExploreConfig(steps=10, n_eigen=30, html=False, cache=False),
        progress=messages.append,
    )
    assert result.trajectory.shape == (10, 3) and result.metrics["source"]["marking"] == "RLI"
    assert set(result.files) >= {"metrics", "trajectory", "fields", "metrics_png", "cloud_png"}
    assert any("basis" in m for m in messages) and result.metrics["basis_from_cache"] is False


# --- bad input: one line, exit code 2, no traceback ---------------------------------------------


def _fails(argv: list[str], capsys: pytest.CaptureFixture, *fragments: str) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("tactex explore: error:")]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


def test_unknown_object(tmp_path, capsys) -> None:
    _fails(["explore", "teapot", "--out", str(tmp_path)], capsys, "'teapot'", "plate")


def test_missing_file(tmp_path, capsys) -> None:
    _fails(["explore", str(tmp_path / "nope.ply"), "--out", str(tmp_path / "o")], capsys, "does not exist")


def test_too_many_eigenpairs(tmp_path, capsys) -> None:
    _fails(
        ["explore", "cup", "--voxel-size", "0.01", "--n-eigen", "5000", "--quiet", "--out", str(tmp_path / "o")],
        capsys,
        "--n-eigen 5000 eigenpairs requested",
        "ask for fewer than",
    )


@pytest.mark.parametrize(
    ("option", "value", "fragment"),
    [
        ("--voxel-size", "-0.003", "--voxel-size -0.003"),
        ("--voxel-size-m", "-0.003", "--voxel-size-m -0.003"),
        ("--steps", "0", "--steps 0"),
        ("--alpha", "-10", "--alpha -10"),
        ("--agent-radius", "-0.0075", "--agent-radius -0.0075"),
        ("--max-velocity", "0", "--max-velocity 0"),
        ("--target-channel", "purple", "unknown target 'purple'"),
        ("--target", "purple", "unknown target 'purple'"),
        ("--marking", "Z", "unknown marking 'Z'"),
        ("--voxel-size", "3", "in metres"),
    ],
)
def test_bad_values(tmp_path, capsys, option: str, value: str, fragment: str) -> None:
    """The message names the option as typed (an old alias included), never the Python field."""
    _fails(["explore", "plate", option, value, "--out", str(tmp_path / "o")], capsys, fragment)


def test_bad_explorer_option(tmp_path, capsys) -> None:
    _fails(["explore", "plate", "--order", "3", "--quiet", "--out", str(tmp_path / "o")], capsys, "order")
    # the library's message names HedacConfig.coverage_normalization; the CLI names its option
    _fails(["explore", "plate", "--coverage-normalization", "cloud", "--out", str(tmp_path / "o")], capsys,
           "--coverage-normalization must be one of")
    _fails(["explore", "plate", "--n-eigen", "99999", "--out", str(tmp_path / "o")], capsys, "fewer than", "(e.g. 200)")
    # the user's own paths and values come back as typed, even when they read like field=value
    missing = tmp_path / "seed=3" / "alpha=10.ply"
    _fails(["explore", str(missing), "--out", str(tmp_path / "o")], capsys, f"'{missing}' does not exist")
    _fails(["explore", "plate", "--target-channel", "alpha=1", "--out", str(tmp_path / "o")], capsys, "'alpha=1'")


def test_file_without_target(tmp_path, capsys) -> None:
    rng = np.random.default_rng(0)
    path = save_npz(SurfaceCloud(points=rng.random((200, 3)) * 0.05), tmp_path / "plain.npz")
    _fails(["explore", str(path), "--voxel-size", "0", "--out", str(tmp_path / "o")], capsys, "no target", "all")
    cfg = ExploreConfig(voxel_size_m=0.0, target="all")
    cloud, info = load_explore_cloud(path, cfg)
    assert cloud.n_target == 200 and info["kind"] == "file"


def test_no_point_above_the_threshold(tmp_path, capsys) -> None:
    rng = np.random.default_rng(0)
    cloud = SurfaceCloud(points=rng.random((200, 3)) * 0.05, colors=np.full((200, 3), 0.5))
    path = save_ply(cloud, tmp_path / "grey.ply")
    _fails(["explore", str(path), "--voxel-size", "0", "--out", str(tmp_path / "o")], capsys, "red by hue",
           "--target-saturation")
    _fails(["explore", str(path), "--voxel-size", "0", "--target-threshold", "0.9", "--out", str(tmp_path / "o")],
           capsys, "red channel ≥ 0.9", "lower --target-threshold")


def test_marking_on_a_file_is_refused(tmp_path, capsys) -> None:
    path = save_npz(SurfaceCloud(points=0.1 * np.random.default_rng(1).random((50, 3))), tmp_path / "c.npz")
    _fails(["explore", str(path), "--marking", "X", "--out", str(tmp_path / "o")], capsys, "--marking")


def test_start_far_from_the_surface(tmp_path, capsys) -> None:
    _fails(
        ["explore", "cup", "--n-eigen", "30", "--x0", "1", "1", "1", "--quiet", "--out", str(tmp_path / "o")],
        capsys,
        "x0",
        "mm from the nearest cloud point",
    )


def test_output_path_is_a_file(tmp_path, capsys) -> None:
    (tmp_path / "f").write_text("x")
    _fails(["explore", "cup", "--quiet", "--out", str(tmp_path / "f")], capsys, "is an existing file")


def _two_plates(tmp_path):
    g = np.linspace(0.0, 0.06, 21)
    x, y = np.meshgrid(g, g)
    patch = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    pts = np.vstack([patch, patch + np.array([0.3, 0.0, 0.0])])  # two plates 30 cm apart
    target = np.r_[np.ones(len(patch)), np.zeros(len(patch))]
    return save_npz(SurfaceCloud(points=pts, target=target), tmp_path / "two.npz"), len(patch)


def test_separate_parts_are_handled_and_reported(tmp_path) -> None:
    path, n = _two_plates(tmp_path)
    messages: list[str] = []
    cfg = ExploreConfig(
        voxel_size_m=0.0, n_eigen=20, n_neighbors=10, steps=150, x0=(0.33, 0.03, 0.0), html=False, cache=False
    )
    result = run_explore(path, tmp_path / "run", cfg, progress=messages.append)
    assert any("2 separate parts" in m and "lifts off" in m for m in messages)
    assert any("part without target: the agent relocates" in m for m in messages)
    assert not any("warning" in m for m in messages)
    m = result.metrics
    assert m["component_sizes"] == [n, n]
    assert m["start_part_has_target"] is False
    assert m["relocations"] == 1 and m["relocation_events"][0]["reason"] == "part_done"
    assert m["final_air_path_length_m"] > 0.29
    assert m["final_total_path_length_m"] == pytest.approx(m["final_path_length_m"] + m["final_air_path_length_m"])
    assert m["final_coverage_residual"] < 0.5
    assert any("relocated 1 time(s) (part_done 1)" in msg for msg in messages)


def test_separate_parts_without_relocation_are_warned_about(tmp_path) -> None:
    from tactex.ergodic import HedacConfig

    path, _ = _two_plates(tmp_path)
    messages: list[str] = []
    cfg = ExploreConfig(
        voxel_size_m=0.0, n_eigen=20, n_neighbors=10, steps=5, x0=(0.33, 0.03, 0.0), html=False, cache=False
    )
    result = run_explore(path, tmp_path / "run", cfg, hedac=HedacConfig(relocate=False), progress=messages.append)
    assert any("2 separate parts" in m and "--n-neighbors" in m for m in messages)
    assert any("part without target and relocation is off" in m for m in messages)
    # Without heat reaching it, the agent covers none of the target.
    assert result.metrics["final_ergodicity"] == pytest.approx(1.0)


def test_stalled_from_finds_the_still_tail() -> None:
    from tactex.experiments.explore import STALL_MIN_STEPS, _stalled_from

    walk = np.column_stack([np.arange(200) * 0.003, np.zeros(200), np.zeros(200)])
    assert _stalled_from(walk, 0.003) is None
    dither = walk.copy()
    dither[100:] = walk[99] + 0.002 * np.sign(np.sin(np.arange(100)))[:, None] * np.array([1.0, 0.0, 0.0])
    # the dither around x = 0.297 ± 0.002 m is within 2 voxels (6 mm) of the end, and so are the walk's
    # last three steps into it (0.291, 0.294, 0.297 m)
    assert _stalled_from(dither, 0.003) == 97
    short = walk.copy()
    short[-(STALL_MIN_STEPS - 5):] = walk[-(STALL_MIN_STEPS - 5)]
    assert _stalled_from(short, 0.003) is None
    assert _stalled_from(np.zeros((0, 3)), 0.003) is None
    # an agent at 0.02 voxels/step needs 200 steps to cross the 4-voxel circle: 100 still steps are no stall
    assert _stalled_from(dither, 0.003, max_velocity=0.02) is None


def test_an_agent_stuck_on_contact_tracks_is_reported(tmp_path) -> None:
    """Parallel tracks 12 mm apart (a wipe's contact points, not a surface): the potential rises only
    across the gaps, which the agent may not leave the cloud to cross; the run says so."""
    s = np.arange(0.0, 0.06, 0.002)
    pts = np.vstack([np.column_stack([s, np.full(s.size, 0.012 * k), np.zeros(s.size)]) for k in range(5)])
    path = save_npz(SurfaceCloud(points=pts, target=np.ones(len(pts))), tmp_path / "tracks.npz")
    messages: list[str] = []
    cfg = ExploreConfig(voxel_size_m=0.0, n_eigen=30, steps=600, x0=(0.03, 0.024, 0.0), html=False, cache=False)
    from tactex.ergodic import HedacConfig

    result = run_explore(path, tmp_path / "run", cfg, hedac=HedacConfig(relocate=False), progress=messages.append)
    assert result.metrics["stalled_from_step"] is not None
    assert result.metrics["final_coverage_residual"] > 0.1
    stalled = result.metrics["stalled_from_step"]
    assert any(f"stayed in place from step {stalled} on," in m and "--relocate" in m for m in messages)
    # With relocation (the default) the stall sends the agent to the other tracks through the air.
    messages.clear()
    result = run_explore(path, tmp_path / "run2", cfg, progress=messages.append)
    assert result.metrics["relocations"] >= 1
    assert result.metrics["final_coverage_residual"] <= 0.05
    assert not any("warning" in m for m in messages)


def _strip_plate_file(tmp_path, blue_strip: bool = True):
    """A 150 × 60 mm plate: red target patches at both ends, a blue 12 mm strip across the middle."""
    g = np.arange(0.0, 0.1501, 0.003)
    x, y = np.meshgrid(g, np.arange(0.0, 0.0601, 0.003))
    pts = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    colors = np.full((len(pts), 3), 0.5)
    colors[(pts[:, 0] < 0.035) | (pts[:, 0] > 0.115)] = (1.0, 0.0, 0.0)
    strip = np.abs(pts[:, 0] - 0.075) <= 0.006
    if blue_strip:
        colors[strip] = (0.0, 0.0, 1.0)
    return save_ply(SurfaceCloud(points=pts, colors=colors), tmp_path / "strip.ply"), strip, pts[strip]


@pytest.mark.parametrize("how", ["channel", "mask"])
def test_explore_keeps_the_footprint_off_a_keep_out_zone(tmp_path, capsys, how: str) -> None:
    path, strip, zone = _strip_plate_file(tmp_path, blue_strip=how == "channel")
    out = tmp_path / "run"
    args = ["explore", str(path), "--voxel-size", "0", "--n-eigen", "40", "--steps", "700", "--x0", "0.01", "0.03",
            "0", "--agent-radius", "0.0075", "--no-html", "--quiet", "--out", str(out)]
    if how == "channel":
        args += ["--keep-out-channel", "blue", "--keep-out-threshold", "0.9"]
    else:
        np.save(tmp_path / "strip.npy", strip)
        args += ["--keep-out-mask", str(tmp_path / "strip.npy")]
    assert main(args) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["keep_out_points"] == int(strip.sum())
    assert m["keep_out_contacts"] == 0
    assert m["relocations"] >= 1 and m["final_air_path_length_m"] > 0
    assert m["final_coverage_residual"] <= 0.05  # both patches: the far one reached through the air
    trajectory = np.load(out / "trajectory.npy")
    # the agent (the footprint's centre) stayed more than a footprint radius from every kept-out point
    assert np.min(np.linalg.norm(trajectory[:, None, :] - zone[None], axis=2)) >= 0.0075
    assert "keep-out contacts 0 of" in capsys.readouterr().out


def test_keep_out_options_are_checked(tmp_path, capsys) -> None:
    path, strip, _ = _strip_plate_file(tmp_path, blue_strip=False)
    o = str(tmp_path / "o")
    _fails(["explore", str(path), "--keep-out-channel", "purple", "--out", o], capsys, "--keep-out-channel")
    _fails(["explore", str(path), "--keep-out-channel", "blue", "--keep-out-threshold", "2", "--out", o], capsys,
           "--keep-out-threshold")
    _fails(["explore", str(path), "--keep-out-mask", "zone.txt", "--out", o], capsys, ".npy")
    _fails(["explore", str(path), "--keep-out-mask", str(tmp_path / "none.npy"), "--out", o], capsys, "does not exist")
    np.save(tmp_path / "short.npy", strip[:-3])
    _fails(["explore", str(path), "--keep-out-mask", str(tmp_path / "short.npy"), "--out", o], capsys,
           "one boolean per point")
    np.save(tmp_path / "float.npy", strip.astype(float) * 0.5)
    _fails(["explore", str(path), "--keep-out-mask", str(tmp_path / "float.npy"), "--out", o], capsys, "boolean")
    _fails(["explore", str(path), "--keep-out-channel", "blue", "--voxel-size", "0", "--out", o], capsys,
           "selects no point")
    red = strip | (np.arange(len(strip)) >= 0)  # everything, the red target included
    np.save(tmp_path / "all.npy", red)
    _fails(["explore", str(path), "--keep-out-mask", str(tmp_path / "all.npy"), "--voxel-size", "0", "--out", o],
           capsys, "every cloud point")
    grey = save_npz(SurfaceCloud(points=np.random.default_rng(0).random((100, 3)) * 0.05, target=np.ones(100)),
                    tmp_path / "grey.npz")
    _fails(["explore", str(grey), "--keep-out-channel", "blue", "--voxel-size", "0", "--out", o], capsys,
           "no colours", "--keep-out-mask")


def test_keep_out_mask_is_carried_onto_the_voxels() -> None:
    from tactex.pointcloud.keep_out import keep_out_on_voxels
    from tactex.pointcloud.voxel import voxel_down_sample

    rng = np.random.default_rng(4)
    pts = rng.random((2000, 3)) * [0.06, 0.06, 0.001]
    mask = pts[:, 0] < 0.01
    vox = keep_out_on_voxels(pts, mask, 0.003)
    down = voxel_down_sample(SurfaceCloud(points=pts), 0.003)
    assert vox.shape == (len(down),)
    # a voxel holding any kept-out point is kept out; its mean may lie a little past the line
    assert np.all(down.points[vox, 0] < 0.01 + 0.003) and np.all(down.points[~vox, 0] >= 0.009 - 1e-12)


def test_a_keep_out_mask_indexes_the_files_rows_nan_rows_included(tmp_path, capsys) -> None:
    """The mask has one entry per row of the file; rows with NaN coordinates (dropped on reading) count too."""
    _, strip, _ = _strip_plate_file(tmp_path)
    g = np.arange(0.0, 0.1501, 0.003)
    x, y = np.meshgrid(g, np.arange(0.0, 0.0601, 0.003))
    pts = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    target = ((pts[:, 0] < 0.035) | (pts[:, 0] > 0.115)).astype(float)
    rows = np.arange(len(pts) + 5)
    nan_rows = rows[::len(rows) // 5][:5]  # five NaN rows spread through the file
    file_pts = np.full((len(rows), 3), np.nan)
    file_target = np.zeros(len(rows))
    keep = np.ones(len(rows), dtype=bool)
    keep[nan_rows] = False
    file_pts[keep], file_target[keep] = pts, target
    path = tmp_path / "holes.npz"
    np.savez(path, points=file_pts, target=file_target)
    file_mask = np.zeros(len(rows), dtype=bool)
    file_mask[keep] = strip
    file_mask[nan_rows] = True  # a NaN row's entry is read and dropped with it
    np.save(tmp_path / "file_mask.npy", file_mask)
    out = tmp_path / "run"
    assert main(["explore", str(path), "--voxel-size", "0", "--n-eigen", "40", "--steps", "20", "--x0", "0.01",
                 "0.03", "0", "--agent-radius", "0.0075", "--no-html", "--quiet", "--keep-out-mask",
                 str(tmp_path / "file_mask.npy"), "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["keep_out_points"] == int(strip.sum())
    np.save(tmp_path / "finite_mask.npy", strip)  # one per finite point: the file has more rows
    _fails(["explore", str(path), "--voxel-size", "0", "--keep-out-mask", str(tmp_path / "finite_mask.npy"),
            "--out", str(tmp_path / "o")], capsys, f"the cloud file has {len(rows)} rows", "5 of them with NaN")


def test_keep_out_mask_on_a_mesh_and_other_option_misuse_are_refused(tmp_path, capsys) -> None:
    o = str(tmp_path / "o")
    mesh = tmp_path / "square.obj"
    mesh.write_text("v 0 0 0\nv 0.06 0 0\nv 0.06 0.06 0\nv 0 0.06 0\nf 1 2 3\nf 1 3 4\n")
    np.save(tmp_path / "four.npy", np.array([True, False, False, False]))
    _fails(["explore", str(mesh), "--target", "all", "--keep-out-mask", str(tmp_path / "four.npy"), "--out", o],
           capsys, "--keep-out-mask", "cannot index a mesh")
    path, strip, _ = _strip_plate_file(tmp_path)
    _fails(["explore", str(path), "--keep-out-threshold", "0.5", "--out", o], capsys, "--keep-out-channel")
    np.save(tmp_path / "none.npy", np.zeros_like(strip))
    _fails(["explore", str(path), "--voxel-size", "0", "--keep-out-mask", str(tmp_path / "none.npy"), "--out", o],
           capsys, "marks no point")
    (tmp_path / "text.npy").write_text("1 0 1\n")
    _fails(["explore", str(path), "--keep-out-mask", str(tmp_path / "text.npy"), "--out", o], capsys,
           "np.save")


def test_a_colour_keep_out_that_takes_most_of_the_cloud_is_warned_about(tmp_path) -> None:
    from tactex.pointcloud.keep_out import raw_keep_out

    white = SurfaceCloud(points=np.random.default_rng(1).random((200, 3)) * 0.05, colors=np.full((200, 3), 0.95))
    with pytest.warns(RuntimeWarning, match="white and grey"):
        zone = raw_keep_out(white, "blue", 0.9, "")
    assert zone.all()
    coloured = white.colors.copy()
    coloured[:20] = (0.0, 0.0, 1.0)
    coloured[20:] = (0.9, 0.2, 0.2)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a sticker's share: no warning
        zone = raw_keep_out(SurfaceCloud(points=white.points, colors=coloured), "blue", 0.9, "")
    assert zone.sum() == 20


def test_the_report_draws_flights_apart_from_the_walk_and_the_keep_out_zone(tmp_path) -> None:
    """The plots draw the path from the start (before the first step), each relocation as a chord through the
    air, and the kept-out points; fields.npz holds the zone."""
    from tactex.report.path_segments import split_flights

    path, strip, _ = _strip_plate_file(tmp_path)
    out = tmp_path / "run"
    assert main(["explore", str(path), "--voxel-size", "0", "--n-eigen", "40", "--steps", "700", "--x0", "0.01",
                 "0.03", "0", "--agent-radius", "0.0075", "--quiet", "--keep-out-channel", "blue",
                 "--keep-out-threshold", "0.9", "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["relocations"] >= 1
    with np.load(out / "fields.npz", allow_pickle=False) as f:
        np.testing.assert_array_equal(f["keep_out"], strip)
    page = (out / "explore.html").read_text()
    assert '"name":"flight"' in page and '"name":"keep-out"' in page
    # the split: a flight is a chord of its own, and the walk breaks there
    walk = np.array([[0.0, 0, 0], [1, 0, 0], [5, 0, 0], [6, 0, 0]])
    surface, air = split_flights(walk, [2])
    assert np.isnan(surface[2]).all() and np.array_equal(surface[[0, 1, 3, 4]], walk)
    np.testing.assert_array_equal(air, walk[[1, 2]])
    assert split_flights(walk, [])[1] is None
    with pytest.raises(Exception, match="flights"):
        split_flights(walk, [0])
