"""The figures and pages a person reads: labelled colour bars and sparse ticks in cloud.png, a constant target in
the top colour of a 0..1 scale, colour bars without SI prefixes on dimensionless quantities, and the index's
metrics as a table rather than a JSON dump."""

from __future__ import annotations

import re

import numpy as np
import pytest

from tactex.report import cloud_html, plot_cloud, write_index_html
from tactex.report.html import tick_format
from tactex.report.run_common import RunReport


def _plate(n: int = 20) -> np.ndarray:
    g = np.linspace(0.0, 0.2, n)
    x, y = np.meshgrid(g, g)
    return np.column_stack([x.ravel(), y.ravel(), 0.01 * np.sin(10 * x.ravel())])


def _figure_of(monkeypatch) -> list:
    from matplotlib.figure import Figure

    seen: list = []
    save = Figure.savefig

    def keep(self, *args, **kw):
        seen.append(self)
        return save(self, *args, **kw)

    monkeypatch.setattr(Figure, "savefig", keep)
    return seen


def test_cloud_png_colour_bars_are_labelled_and_ticks_sparse(tmp_path, monkeypatch) -> None:
    seen = _figure_of(monkeypatch)
    pts = _plate()
    fields = {"target": np.ones(len(pts)), "coverage": np.linspace(0, 3, len(pts))}
    plot_cloud(pts, fields, tmp_path / "c.png", trajectory=pts[:30], labels={"target": "target p [-]"})
    fig = seen[0]
    bars = [a for a in fig.axes if a.name != "3d"]
    assert [b.get_xlabel() for b in bars] == ["target p [-]", "coverage"]  # given label, else the field's name
    for ax in (a for a in fig.axes if a.name == "3d"):
        assert ax.get_xlabel() == "x [m]" and ax.get_zlabel() == "z [m]"
        assert len(ax.xaxis.get_major_locator().tick_values(0.0, 0.2)) <= 5
    target_bar = bars[0]
    assert target_bar.get_xlim() == (0.0, 1.0)  # a whole-surface target: 0..1, drawn in the top colour
    for bar, ax in zip(bars, (a for a in fig.axes if a.name == "3d"), strict=True):  # the bar above its panel
        assert bar.get_position().y0 >= ax.get_position().y1 - 1e-6


def test_html_constant_target_on_a_zero_one_scale_and_no_si_prefixes(tmp_path) -> None:
    pts = _plate()
    page = cloud_html(pts, {"target": np.ones(len(pts)), "curvature l_s [-]": np.linspace(5e-6, 2e-5, len(pts))},
                      tmp_path / "p.html", include_plotlyjs="cdn").read_text()
    markers = re.findall(r'"cmax":([-0-9.e]+),"cmin":([-0-9.e]+),"color"', page)
    assert ("1.0", "0.0") in markers, markers
    # the menu's second colouring: 5e-6..2e-5 reads "5e-6", not "5μ"
    assert '"marker.colorbar.tickformat":[".2~e"]' in page


@pytest.mark.parametrize(("lo", "hi", "fmt"), [(5e-6, 2e-5, ".2~e"), (0.0, 1.0, ".3~g"), (0.0, 25.0, ".3~g"),
                                                (0.0, 3e4, ".2~e"), (-0.004, 0.002, ".2~e"), (0.0, 0.0, ".3~g")])
def test_tick_format(lo, hi, fmt) -> None:
    assert tick_format(lo, hi) == fmt


def test_index_metrics_as_a_table_not_a_json_dump(tmp_path) -> None:
    run = tmp_path / "clean"
    run.mkdir()
    (run / "metrics.json").write_text("{}")
    rep = RunReport(run, "clean", "tactex", {"time_to_95_s": 19.856000000001284, "dirt_removed_fraction": 0.98,
                                              "aborted": None, "series": [1.0, 2.0], "passive": True})
    page = write_index_html(tmp_path / "index.html", [rep]).read_text()
    assert "<pre>" not in page and "19.856000000001284" not in page
    assert "<td>time_to_95_s</td><td>19.86</td>" in page and "<td>aborted</td><td>–</td>" in page
    assert "<td>passive</td><td>yes</td>" in page and "<td>series</td>" not in page  # lists stay in metrics.json
    assert "href='clean/metrics.json'" in page


def _positions(page: str, *marks: str) -> list[int]:
    found = [page.find(m) for m in marks]
    assert all(i >= 0 for i in found), dict(zip(marks, found, strict=True))
    return found


@pytest.mark.parametrize("kind", ["clean", "wipe"])
def test_report_page_leads_with_the_summary_then_plots_then_the_3d_view(tmp_path, kind) -> None:
    from tactex.report import write_run_report

    from .test_run_report import fake_clean, fake_wipe

    rep = write_run_report(fake_clean() if kind == "clean" else fake_wipe(), tmp_path / kind)
    page = rep.html.read_text()
    first_column = "dirt removed" if kind == "clean" else "force MAE [N]"
    marks = ("<h1>", f"<th>{first_column}</th>", "<b>All metrics</b>", "src='data:image/png;base64,",
             "<h2>3-D view</h2>", 'class="plotly-graph-div"', "<p>Files: ")
    found = _positions(page, *marks)
    assert found == sorted(found), dict(zip(marks, found, strict=True))
    assert f"<title>tactex {kind} — tactex" in page and page.count("<body") == 1


def test_report_page_without_a_3d_view_keeps_the_same_order(tmp_path) -> None:
    from tactex.report import write_run_report

    from .test_run_report import fake_clean

    res = fake_clean()
    res.cloud, res.fields, res.agent_path = None, {}, np.zeros((0, 3))
    page = write_run_report(res, tmp_path / "clean").html.read_text()
    marks = ("<h1>tactex clean — tactex", "<th>dirt removed</th>", "before its first capture",
             "src='data:image/png;base64,", "<p>Files: ", "</body>")
    found = _positions(page, *marks)
    assert found == sorted(found) and "3-D view" not in page
