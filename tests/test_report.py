"""Report helpers: files are produced, well formed, and carry the data (not pixels)."""

from __future__ import annotations

import base64
import json
import math
import re

import numpy as np
import pytest

from tactex.errors import ConfigError, InputError
from tactex.report import cloud_html, plot_cloud, plot_series, read_metrics, write_metrics

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def png_size(path) -> tuple[int, int]:
    """(width, height) from the IHDR chunk of a PNG file."""
    head = path.read_bytes()[:24]
    assert head[:8] == PNG_MAGIC and head[12:16] == b"IHDR"
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


@pytest.fixture
def cloud(rng: np.random.Generator) -> np.ndarray:
    return rng.random((300, 3)) * 0.1


def test_plot_series_writes_png(tmp_path, rng: np.random.Generator) -> None:
    out = plot_series(
        {"ergodicity [-]": rng.random(50), "path [m]": np.cumsum(rng.random(50)), "runs": rng.random((4, 50))},
        tmp_path / "sub" / "series.png",
        title="demo",
        logy=["ergodicity [-]"],
    )
    w, h = png_size(out)
    # Three stacked panels: the figure is taller than a single-panel one.
    single = plot_series({"a": [1.0, 2.0, 3.0]}, tmp_path / "single.png")
    assert h > png_size(single)[1] and w == png_size(single)[0]


def test_plot_series_keeps_nan_as_gap(tmp_path) -> None:
    out = plot_series({"a": [1.0, np.nan, 3.0]}, tmp_path / "nan.png", x=[0.0, 0.5, 1.0], xlabel="time [s]")
    assert png_size(out)[0] > 0


@pytest.mark.parametrize(
    ("series", "kwargs", "match"),
    [
        ({}, {}, "at least one"),
        ({"a": []}, {}, "non-empty"),
        ({"a": np.zeros((2, 2, 2))}, {}, "1-D"),
        ({"a": [1.0, 2.0, 3.0]}, {"x": [0.0, 1.0]}, "x only 2"),
    ],
)
def test_plot_series_bad_input(tmp_path, series, kwargs, match) -> None:
    with pytest.raises(InputError, match=match):
        plot_series(series, tmp_path / "bad.png", **kwargs)


def test_plot_cloud_panels_and_path(tmp_path, cloud) -> None:
    one = plot_cloud(cloud, cloud[:, 2], tmp_path / "one.png")
    three = plot_cloud(
        cloud,
        {"target": cloud[:, 0] > 0.05, "coverage": cloud[:, 1], "potential": cloud[:, 2]},
        tmp_path / "three.png",
        trajectory=cloud[:20],
        title="run",
        cmaps={"target": "Reds"},
    )
    (w1, h1), (w3, h3) = png_size(one), png_size(three)
    # one panel per field, side by side (the tight crop follows titles and colour bars)
    assert w3 > 2.5 * w1 and h1 <= h3 < 1.3 * h1
    assert png_size(plot_cloud(cloud, None, tmp_path / "plain.png"))[0] < 0.6 * w3  # one grey panel


@pytest.mark.parametrize(
    ("points", "fields", "trajectory", "match"),
    [
        (np.zeros((0, 3)), None, None, r"shape \(N, 3\)"),
        (np.full((4, 3), np.nan), None, None, "NaN"),
        (np.zeros((4, 3)), {"a": np.zeros(5)}, None, r"field 'a' must have shape \(4,\)"),
        (np.zeros((4, 3)), None, np.zeros((3, 2)), r"trajectory must have shape \(T, 3\)"),
        (np.zeros((4, 3)), None, np.array([[0.0, 0.0, np.nan]]), "trajectory holds NaN"),
    ],
)
def test_plot_cloud_bad_input(tmp_path, points, fields, trajectory, match) -> None:
    with pytest.raises(InputError, match=match):
        plot_cloud(points, fields, tmp_path / "x.png", trajectory=trajectory)
    with pytest.raises(InputError, match=match):
        cloud_html(points, fields, tmp_path / "x.html", trajectory=trajectory, include_plotlyjs=False)


def test_cloud_html_offline_with_data_and_menu(tmp_path, cloud) -> None:
    fields = {"target": (cloud[:, 0] > 0.05).astype(float), "coverage": cloud[:, 1] * 7.0}
    out = cloud_html(cloud, fields, tmp_path / "view.html", trajectory=cloud[:10], title="explore demo")
    html = out.read_text()
    assert html.lstrip().lower().startswith(("<html", "<!doctype html>")) and html.rstrip().endswith("</html>")
    # Inline plotly: no network needed to open it.
    assert "<script src=" not in html and len(html) > 1_000_000
    assert "explore demo" in html and '"target"' in html and '"coverage"' in html and '"path"' in html
    # The coordinates and each colouring are in the page, as base64 float32 (a display needs no more).
    arrays = [np.frombuffer(base64.b64decode(b), dtype="<f4")
              for b in re.findall(r'"dtype":"f4","bdata":"([^"]+)"', html)]
    assert "\\u002f" not in "".join(re.findall(r'"bdata":"([^"]+)"', html))  # "/" written as one character
    for expected in (cloud[:, 0], cloud[:, 2], fields["target"], fields["coverage"]):
        assert any(a.shape == expected.shape and np.array_equal(a, expected.astype(np.float32)) for a in arrays)
    # the path, lifted off the surface to both sides (the cloud has no normals): two copies beside it
    lift = 0.005 * np.linalg.norm(np.ptp(cloud, axis=0))
    drawn = np.stack([a for a in arrays if a.shape == (21,)][:3], axis=1)  # the path's x, y, z
    assert np.isnan(drawn[10]).all()
    for copy in (drawn[:10], drawn[11:]):
        np.testing.assert_allclose(np.linalg.norm(copy - cloud[:10], axis=1), lift, rtol=1e-4)
    assert html.count('"method":"restyle"') == 2 or html.count('"method": "restyle"') == 2
    assert not re.search(r"showing [0-9 ]+ of", html)  # a small cloud is drawn whole


def test_cloud_html_cdn_is_small(tmp_path, cloud) -> None:
    out = cloud_html(cloud, cloud[:, 0], tmp_path / "cdn.html", include_plotlyjs="cdn")
    html = out.read_text()
    assert re.search(r'<script[^>]+src="https://cdn\.plot\.ly/', html) and len(html) < 200_000


def test_cloud_html_bad_mode(tmp_path, cloud) -> None:
    with pytest.raises(ConfigError, match="include_plotlyjs"):
        cloud_html(cloud, None, tmp_path / "x.html", include_plotlyjs="offline")


def test_metrics_round_trip_with_numpy_and_nan(tmp_path) -> None:
    metrics = {"n_points": np.int64(12), "ergodicity": np.array([0.5, 0.25]), "bad": math.nan, "cfg": {"a": 1.5}}
    path = write_metrics(metrics, tmp_path / "m" / "metrics.json")
    back = read_metrics(path)
    assert back == {"n_points": 12, "ergodicity": [0.5, 0.25], "bad": None, "cfg": {"a": 1.5}}
    json.loads(path.read_text())  # strict JSON (no NaN literal)
    assert "NaN" not in path.read_text()


def test_metrics_bad_input(tmp_path) -> None:
    with pytest.raises(InputError, match="mapping"):
        write_metrics([1, 2], tmp_path / "x.json")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="does not exist"):
        read_metrics(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        read_metrics(tmp_path / "bad.json")
    (tmp_path / "list.json").write_text("[1, 2]")
    with pytest.raises(InputError, match="JSON object"):
        read_metrics(tmp_path / "list.json")


def test_plot_fixes_of_issue_22(tmp_path) -> None:
    """A whole-surface target has a colour scale, the ergodicity breaks at vision updates, start and
    end are separate legend entries, curvature is blue-low/red-high in the PNG and the page alike."""
    import matplotlib

    from tactex.report.clean_report import _ergodicity
    from tactex.report.cloud import color_limits
    from tactex.report.html import cloud_html
    from tactex.report.wipe_report import CURVATURE_COLORSCALE

    assert color_limits(np.ones(5)) == (0.0, 1.0) and color_limits(np.array([0.2, 0.7])) == (0.2, 0.7)
    assert color_limits(np.zeros(3)) == (0.0, 1.0) and color_limits(np.full(3, -2.0)) == (-2.0, 0.0)
    erg = _ergodicity({"ergodicity": [[1.0, 0.9], [2.0, 0.8], [3.0, 0.95], [4.0, 0.9]],
                       "vision_update_times_s": [2.5, 9.0]})
    assert erg.shape == (5, 2) and erg[2, 0] == 2.5 and np.isnan(erg[2, 1])
    assert np.isfinite(np.delete(erg, 2, axis=0)).all()
    pts = np.random.default_rng(0).random((50, 3)) * 0.1
    page = cloud_html(pts, {"a": pts[:, 0], "b": pts[:, 1]}, tmp_path / "p.html", trajectory=pts[:10],
                      include_plotlyjs=False).read_text()
    assert '"name":"start"' in page and '"name":"end"' in page and "start / end" not in page
    cool = matplotlib.colormaps["coolwarm"]
    for pos, colour in CURVATURE_COLORSCALE[::2]:
        rgb = [int(v) for v in colour[4:-1].split(",")]
        np.testing.assert_allclose(rgb, np.array(cool(pos)[:3]) * 255, atol=3)
