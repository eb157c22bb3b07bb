"""The overlay of a compare's methods (compare.png) on synthetic run folders: one curve per method on the dirt
axis with each method's time to 95 % marked, the force with its set point band, the wipe's force and motion
error; a run without a series named in a note; the compare's index page led by the figure."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tactex.errors import InputError
from tactex.report import plot_compare, write_run_report
from tactex.tasks.clean.time_breakdown import time_to_fraction_removed

from .test_report_figures import _figure_of
from .test_run_report import PNG_MAGIC, FakeCleanConfig, fake_clean, fake_wipe


def _clean_run(baseline: str, remaining_end: float):
    res = fake_clean(baseline)
    n = len(res.series["t"])
    res.series["dirt_remaining"] = np.linspace(1.0, remaining_end, n)
    return res


def _clean_folders(tmp_path) -> list[tuple[str, object]]:
    runs = [("tactex", _clean_run("", 0.0)), ("raster", _clean_run("raster", 0.5))]
    return [(label, write_run_report(res, tmp_path / label, label=label, html_page=False).out_dir)
            for label, res in runs]


def test_clean_overlay_one_dirt_curve_per_method_with_the_time_to_95_marked(tmp_path, monkeypatch) -> None:
    seen = _figure_of(monkeypatch)
    fig_out = plot_compare("clean", _clean_folders(tmp_path), tmp_path / "compare.png")
    assert fig_out.path.read_bytes()[:8] == PNG_MAGIC and fig_out.drawn == ["tactex", "raster"] and not fig_out.notes
    dirt, force = seen[-1].axes
    curves = [ln for ln in dirt.get_lines() if ln.get_label().split(":")[0] in ("tactex", "raster")]
    assert [ln.get_label().split(":")[0] for ln in curves] == ["tactex", "raster"]
    t = fake_clean().series["t"]
    t95 = time_to_fraction_removed(t, np.linspace(1.0, 0.0, len(t)))
    assert t95 is not None and f"95 % removed at {t95:.1f} s" in curves[0].get_label()
    assert "not reached (50 % removed)" in curves[1].get_label()
    marks = [ln for ln in dirt.get_lines() if list(ln.get_xdata()) == [t95, t95]]  # the dashed line at t95
    assert marks and marks[0].get_color() == curves[0].get_color()
    assert "[%" in dirt.get_ylabel() and force.get_ylabel() == "normal force [N]" and "[s]" in force.get_xlabel()
    band = [p for p in force.patches if p.get_label() == "set point ±20 %"]
    box = band[0].get_bbox()  # y in newtons, x across the whole axis
    assert np.allclose([box.y0, box.y1], [8.0, 12.0])  # 10 N ± 20 %
    assert dirt.get_legend() is not None and force.get_legend() is not None
    assert {ln.get_label() for ln in force.get_lines()} >= {"tactex", "raster", "set point 10 N"}


def test_wipe_overlay_force_and_motion_error_per_method(tmp_path, monkeypatch) -> None:
    seen = _figure_of(monkeypatch)
    runs = []
    for label, offset in (("tactex", 0.001), ("cartesian", 0.02)):
        res = fake_wipe(label if label != "tactex" else "")
        res.series["desired"] = res.series["tcp"] + offset / np.sqrt(3.0)
        runs.append((label, write_run_report(res, tmp_path / label, label=label, html_page=False).out_dir))
    out = plot_compare("wipe", runs, tmp_path / "compare.png")
    assert out.path.is_file() and out.drawn == ["tactex", "cartesian"]
    force, motion = seen[-1].axes
    assert force.get_ylabel() == "normal force [N]" and "[mm]" in motion.get_ylabel()
    assert motion.get_yscale() == "log" and "[s]" in motion.get_xlabel()
    errors = {ln.get_label().split(" ")[0]: ln.get_ydata() for ln in motion.get_lines()}
    assert set(errors) == {"tactex", "cartesian"}
    contact = fake_wipe().series["in_contact"] > 0.5
    np.testing.assert_allclose(errors["cartesian"][contact], 20.0)  # ‖x − x_d‖ in mm, in contact only
    assert np.isnan(errors["tactex"][~contact]).all()
    assert {"tactex", "cartesian"} <= {ln.get_label() for ln in force.get_lines()}


def test_a_run_without_series_is_named_not_a_crash(tmp_path, monkeypatch) -> None:
    seen = _figure_of(monkeypatch)
    runs = _clean_folders(tmp_path)
    (tmp_path / "empty").mkdir()
    (tmp_path / "raster" / "series.npz").write_bytes(b"not a zip")
    out = plot_compare("clean", [("no_feedback", tmp_path / "empty"), *runs], tmp_path / "compare.png")
    assert out.drawn == ["tactex"] and out.path.is_file()
    assert len(out.notes) == 2 and out.notes[0].startswith("no_feedback: no series.npz")
    assert out.notes[1].startswith("raster: series.npz cannot be read") and "\n" not in "".join(out.notes)
    curve = next(ln for ln in seen[-1].axes[0].get_lines() if ln.get_label().startswith("tactex"))
    assert curve.get_color() == "C1"  # its place in the compare's colours, whoever is left out
    none = plot_compare("clean", [("no_feedback", tmp_path / "empty")], tmp_path / "none.png")
    assert none.path is None and not (tmp_path / "none.png").exists() and len(none.notes) == 1
    with pytest.raises(InputError, match="valid: clean, wipe"):
        plot_compare("sweep", runs, tmp_path / "x.png")
    with pytest.raises(InputError, match="at least one run"):
        plot_compare("clean", [], tmp_path / "x.png")


def test_compare_index_leads_with_the_overlay(tmp_path, monkeypatch) -> None:
    """run_compare's own wiring, its runs replaced by synthetic ones (a simulated compare takes minutes)."""
    import tactex.experiments.run as run_mod

    def fake_task(kind, cfg, out, *, label, **_):
        res = fake_clean(cfg.baseline)
        if cfg.baseline == "no_feedback":  # a run whose dirt is not known (as on a robot) is still drawn
            res.series["dirt_remaining"] = np.full(len(res.series["t"]), np.nan)
        rep = write_run_report(res, out, label=label)
        if cfg.baseline == "region_raster":
            (out / "series.npz").unlink()
        return rep

    monkeypatch.setattr(run_mod, "run_task", fake_task)
    reports = run_mod.run_compare("clean", dataclasses.replace(FakeCleanConfig()), tmp_path / "cmp", note=None)
    assert [r.label for r in reports] == ["tactex", "raster", "region_raster", "no_feedback"]
    page = (tmp_path / "cmp" / "index.html").read_text()
    assert (tmp_path / "cmp" / "compare.png").read_bytes()[:8] == PNG_MAGIC
    assert 0 < page.index("src='compare.png'") < page.index("<table")
    assert page.count("<p class='note'>") == 1 and "<p class='note'>region_raster: no series.npz" in page
