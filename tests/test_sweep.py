"""`tactex sweep` (TEC §V-B, Fig. 6–11): grid plumbing, determinism, outputs and bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tactex.cli import main
from tactex.ergodic import HedacConfig, HedacExplorer
from tactex.errors import ConfigError, InputError
from tactex.experiments.explore import ExploreConfig, load_explore_cloud
from tactex.experiments.sweep import SweepConfig, run_sweep, sweep_starts
from tactex.pointcloud import save_ply
from tactex.spectral import build_basis

SMALL = {"n_eigen": (10, 30), "alpha": (5.0,), "starts": 2, "steps": 30, "workers": 1}
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(autouse=True)
def _cache_dir(tmp_path_factory, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TACTEX_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "basis-cache"))


@pytest.fixture(scope="module")
def cup_sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep")
    # A module fixture is set up before the autouse cache fixture: it would read and fill the user's cache, whose
    # basis may come from another version of the solver (the same to its tolerance, not to the bit).
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("TACTEX_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "basis-cache"))
        return run_sweep(["cup"], out, SweepConfig(**SMALL))


def test_sweep_writes_curves_summary_and_plots(cup_sweep):
    c = cup_sweep.curves["cup"]
    assert c["ergodicity"].shape == (2, 1, 2, 30)
    assert c["first_path"].shape == (2, 1, 30, 3) and np.isfinite(c["first_path"]).all()
    assert np.all(np.diff(c["path_length_m"], axis=-1) >= -1e-12)
    # exploring lowers the ergodicity (eq. 48) in every run
    assert (c["ergodicity"][..., -1] < c["ergodicity"][..., 0]).all()
    summary = json.loads((cup_sweep.out_dir / "sweep.json").read_text())
    rows = summary["clouds"]["cup"]["results"]
    assert [(r["n_eigen"], r["alpha"]) for r in rows] == [(10, 5.0), (30, 5.0)]
    for i, r in enumerate(rows):
        assert r["final_ergodicity_mean"] == pytest.approx(c["ergodicity"][i, 0, :, -1].mean())
    best = min(rows, key=lambda r: r["final_ergodicity_mean"])
    assert summary["clouds"]["cup"]["best"]["n_eigen"] == best["n_eigen"]
    with np.load(cup_sweep.out_dir / "curves.npz", allow_pickle=False) as z:
        np.testing.assert_array_equal(z["cup.ergodicity"], c["ergodicity"])
    for name in ("vs_n_eigen", "vs_alpha", "time", "paths"):
        assert (cup_sweep.out_dir / f"cup_{name}.png").read_bytes()[:8] == PNG_MAGIC


def test_smaller_n_eigen_is_the_truncated_basis(cup_sweep):
    """A sweep setting equals a direct run with the first n_K columns of the largest basis."""
    cfg = SweepConfig(**SMALL)
    cloud, info = load_explore_cloud("cup", cfg.explore_config())
    basis = build_basis(cloud, n_eigen=30, n_neighbors=cfg.n_neighbors)
    starts, _ = sweep_starts(cloud, info, 2, 0)
    ex = HedacExplorer(cloud, basis, HedacConfig(
            alpha=5.0, n_eigen=10, agent_radius_m=0.0075, coverage_normalization=cfg.coverage_normalization))
    ex.reset(starts[1])
    erg = []
    for _ in range(30):
        ex.step()
        erg.append(ex.ergodicity())
    np.testing.assert_allclose(cup_sweep.curves["cup"]["ergodicity"][0, 0, 1], erg, rtol=0, atol=1e-12)


def test_worker_processes_give_the_same_result(cup_sweep, tmp_path):
    two = run_sweep(["cup"], tmp_path, SweepConfig(**{**SMALL, "workers": 2}))
    for name in ("ergodicity", "coverage_residual", "first_path"):
        np.testing.assert_allclose(two.curves["cup"][name], cup_sweep.curves["cup"][name], rtol=0, atol=1e-12)


def test_starts_come_from_the_authors_file_then_the_seed(tmp_path):
    cloud, _ = load_explore_cloud("cup", ExploreConfig())
    path = save_ply(cloud, tmp_path / "mycup.ply")
    given = cloud.points[[5, 50]]
    np.savez(tmp_path / "mycup_x0_arr_10.npz", x0_arr=given)
    info = {"kind": "file", "path": str(path)}
    starts, origin = sweep_starts(cloud, info, 3, seed=4)
    np.testing.assert_array_equal(starts[:2], given)
    assert "mycup_x0_arr_10.npz" in origin and "seed 4" in origin
    assert np.any(np.all(cloud.points == starts[2], axis=1))  # the third is a cloud point
    again, _ = sweep_starts(cloud, info, 3, seed=4)
    np.testing.assert_array_equal(again, starts)


@pytest.mark.parametrize("changes, match", [
    ({"n_eigen": ()}, "at least one"),
    ({"n_eigen": (10, 2.5)}, "integers"),
    ({"alpha": (5.0, -1.0)}, "positive"),
    ({"alpha": (5.0, 5.0)}, "twice"),
    ({"alpha": ("x",)}, "numbers"),
    ({"starts": 0}, "starts"),
    ({"steps": 0}, "steps"),
    ({"workers": -1}, "workers"),
    ({"voxel_size_m": 3.0}, "metres"),
    ({"coverage_normalization": "all"}, "coverage_normalization"),
])
def test_config_validation(changes, match):
    with pytest.raises(ConfigError, match=match):
        SweepConfig(**{**SMALL, **changes})


def test_bad_sources_and_outputs(tmp_path):
    with pytest.raises(ConfigError, match="one or more"):
        run_sweep([], tmp_path / "o", SweepConfig(**SMALL))
    with pytest.raises(ConfigError, match="must be smaller"):
        run_sweep(["cup"], tmp_path / "o", SweepConfig(**{**SMALL, "n_eigen": (5000,)}))
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(InputError, match="is an existing file"):
        run_sweep(["cup"], blocker, SweepConfig(**SMALL))


def test_cli_prints_the_grid(tmp_path, capsys):
    code = main(["sweep", "cup", "--out", str(tmp_path / "s"), "--n-eigen", "10", "--alpha", "5", "20",
                 "--starts", "1", "--steps", "10", "--workers", "1", "--quiet"])
    assert code == 0
    text = capsys.readouterr().out
    assert "n_K \\ α" in text and "best: n_K = 10" in text
    assert main(["sweep", "cup", "--out", str(tmp_path / "t"), "--alpha", "-1"]) == 2


def test_a_cloud_without_colours_is_swept_with_target_all(tmp_path, capsys):
    """explore's hint for an uncoloured cloud ('use --target all') holds for sweep too."""
    g = np.linspace(0.0, 0.06, 21)
    x, y = np.meshgrid(g, g)
    path = tmp_path / "plain.npz"
    np.savez(path, points=np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)]))
    argv = ["sweep", str(path), "--n-eigen", "10", "--alpha", "5", "--starts", "1", "--steps", "10",
            "--workers", "1", "--quiet"]
    assert main([*argv, "--out", str(tmp_path / "a")]) == 2
    assert "--target all" in capsys.readouterr().err
    assert main([*argv, "--target", "all", "--out", str(tmp_path / "b")]) == 0
    assert (tmp_path / "b" / "sweep.json").is_file()


def test_an_interrupted_sweep_keeps_its_settings_and_resumes(tmp_path, capsys, monkeypatch):
    """14 of 20 settings done and Ctrl-C wrote nothing; now each setting is saved as it ends."""
    from tactex.experiments import sweep as sweep_module

    argv = ["sweep", "cup", "--voxel-size-m", "0.006", "--n-eigen", "10", "20", "--alpha", "5", "--starts", "1",
            "--steps", "10", "--workers", "1", "--no-cache"]
    assert main([*argv, "--out", str(tmp_path / "whole")]) == 0
    whole = json.loads((tmp_path / "whole" / "sweep.json").read_text())
    real = sweep_module._run_setting
    calls = []

    def stop_at_second(*args):
        calls.append(args)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*args)

    monkeypatch.setattr(sweep_module, "_run_setting", stop_at_second)
    out = tmp_path / "cut"
    assert main([*argv, "--out", str(out)]) == 130
    assert json.loads((out / "status.json").read_text())["status"] == "interrupted"
    assert [p.name for p in (out / "settings").iterdir()] == ["cup_K10_alpha5.npz"]
    monkeypatch.setattr(sweep_module, "_run_setting", real)
    capsys.readouterr()
    assert main([*argv, "--out", str(out)]) == 0
    assert "resuming: 1 of 2 settings already done" in capsys.readouterr().err
    resumed = json.loads((out / "sweep.json").read_text())
    assert resumed["clouds"]["cup"]["results"] == whole["clouds"]["cup"]["results"]
    # other parameters do not reuse those settings
    capsys.readouterr()
    assert main([*argv[:-3], "--steps", "12", "--workers", "1", "--no-cache", "--out", str(out)]) == 0
    assert "resuming" not in capsys.readouterr().err


def test_sweep_keeps_off_the_painted_keep_out_merged_with_the_options(tmp_path, capsys):
    """A PLY's painted keep-out is honoured as explore honours it, merged with --keep-out-mask, and said."""
    import json

    from tactex.pointcloud.annotation import Annotation
    from tactex.pointcloud.ply_marks import write_marked_ply

    from .test_annotate import centre_index, plane

    a = Annotation(plane(31))
    a.paint(centre_index(a.cloud), 0.010, "target")
    a.paint(int(np.argmax(a.cloud.points[:, 0])), 0.006, "keep_out")
    marked = write_marked_ply(a.cloud, a.target, a.keep_out, tmp_path / "marked.ply")
    mask = np.zeros(len(a.cloud), dtype=bool)
    mask[int(np.argmin(a.cloud.points[:, 0]))] = True  # one more point, on the other side
    np.save(tmp_path / "mask.npy", mask)
    argv = ["sweep", str(marked), "--n-eigen", "10", "--alpha", "5", "--starts", "2", "--steps", "150",
            "--workers", "1", "--voxel-size-m", "0"]
    assert main([*argv, "--out", str(tmp_path / "a")]) == 0
    out = capsys.readouterr()
    n_file = a.counts().n_keep_out
    assert f"{n_file} kept out (the file's keep_out property;" in out.out
    summary = json.loads((tmp_path / "a" / "sweep.json").read_text())["clouds"]["marked"]
    assert summary["keep_out_points"] == n_file and summary["n_target"] == a.counts().n_target
    assert all(r["keep_out_contacts_max"] == 0 for r in summary["results"])
    with np.load(tmp_path / "a" / "curves.npz") as z:
        assert np.array_equal(z["marked.keep_out"], a.keep_out)
        starts = z["marked.starts"]
    assert not np.isin(starts, a.cloud.points[a.keep_out]).all(axis=1).any()  # no start drawn in the zone

    assert main([*argv, "--keep-out-mask", str(tmp_path / "mask.npy"), "--out", str(tmp_path / "b")]) == 0
    out = capsys.readouterr()
    assert f"{n_file + 1} kept out (the file's keep_out property merged with --keep-out-mask" in out.out
    assert "merged with --keep-out-mask" in out.err  # the loader's warning, with the total
    summary = json.loads((tmp_path / "b" / "sweep.json").read_text())["clouds"]["marked"]
    assert summary["keep_out_points"] == n_file + 1
    assert all(r["keep_out_contacts_max"] == 0 for r in summary["results"])
