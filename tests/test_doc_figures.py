"""Figures from runs in README.md and docs/ are written from the committed results: a figure edited by
hand, or a result file committed without ``make readme-status``, fails here, naming the page, the line
and the key."""

from __future__ import annotations

import json
import re
import shutil
import sys

import pytest

from tests.conftest import REPO

sys.path.insert(0, str(REPO / "tools"))

import readme_status
from doc_figures import MARKER, doc_files, figure_text, rewrite
from figure_forms import NOT_MEASURED, FigureError, render
from figure_sources import Sources


def _copy_repo(tmp_path):
    """The pages and the sources their figures read, as committed."""
    shutil.copy(REPO / "README.md", tmp_path / "README.md")
    shutil.copytree(REPO / "docs", tmp_path / "docs")
    for source in ("bench/results.json", "bench/suite_runs.json", "fuzz/results.json"):
        (tmp_path / source).parent.mkdir(exist_ok=True)
        shutil.copy(REPO / source, tmp_path / source)
    return tmp_path


def test_every_figure_in_the_committed_pages_is_what_its_source_gives(capsys) -> None:
    assert readme_status.main(["--check"]) == 0, capsys.readouterr().err


def test_the_pages_carry_figures_and_every_marker_renders() -> None:
    """The mechanism is in use (a page without markers would pass the check above vacuously), and no
    marker is broken or reads "not measured" on the committed sources."""
    sources = Sources(REPO)
    specs = [m["spec"] for page in doc_files(REPO) for m in MARKER.finditer(page.read_text())]
    assert len(specs) >= 50
    assert [s for s in specs if figure_text(s, sources) == NOT_MEASURED] == []


@pytest.mark.parametrize("page", ["README.md", "docs/large_surfaces.md"])
def test_a_figure_edited_by_hand_fails_the_check_naming_page_line_and_key(tmp_path, capsys, page) -> None:
    root = _copy_repo(tmp_path)
    text = (root / page).read_text()
    first = next(MARKER.finditer(text))
    line = text.count("\n", 0, first.start()) + 1
    (root / page).write_text(text[:first.start("text")] + "12.3" + text[first.end("text"):])
    assert readme_status.main(["--check", "--root", str(root)]) == 1
    err = capsys.readouterr().err
    assert f"{page}:{line}: {first['spec']}: reads '12.3'" in err
    # make readme-status writes it back, and the check passes again
    assert readme_status.main(["--root", str(root)]) == 0
    assert (root / page).read_text() == text
    assert readme_status.main(["--check", "--root", str(root)]) == 0


def test_a_new_result_without_make_readme_status_fails_the_check(tmp_path, capsys) -> None:
    root = _copy_repo(tmp_path)
    fuzz = json.loads((root / "fuzz/results.json").read_text())
    next(iter(fuzz["rounds"].values()))["npz"]["classes_found"] += 1
    (root / "fuzz/results.json").write_text(json.dumps(fuzz))
    assert readme_status.main(["--check", "--root", str(root)]) == 1
    assert "docs/fuzzing.md:" in capsys.readouterr().err


def test_an_unknown_key_reads_not_measured_and_a_broken_marker_is_an_error(tmp_path, capsys) -> None:
    sources = Sources(REPO)
    assert figure_text("tasks/clean/plate/no_such_run/sim_time_s | .1f", sources) == NOT_MEASURED
    assert figure_text("no_such_file.json#a/b", sources) == NOT_MEASURED
    # one key of several missing: a range or a ratio over the rest would mislead
    assert figure_text("large/arpack_60k_s large/nothing | div | .2f", sources) == NOT_MEASURED
    assert figure_text("tasks/wipe/cartesian/tank_force_energy_min_j | .1f", sources) == NOT_MEASURED  # NaN
    text, findings = rewrite("a <!-- fig large/nothing | .2f -->1.00<!-- /fig --> b", sources, "p.md")
    assert text == f"a <!-- fig large/nothing | .2f -->{NOT_MEASURED}<!-- /fig --> b"
    assert [str(f) for f in findings] == [
        f"p.md:1: large/nothing | .2f: reads '1.00', the sources give '{NOT_MEASURED}'"]
    # a typo in the steps is reported with its place, and the text is left alone
    broken = "x\n<!-- fig large/arpack_60k_s | rnage -->18.7<!-- /fig -->"
    text, findings = rewrite(broken, sources, "p.md")
    assert text == broken and findings[0].line == 2 and findings[0].expected is None
    root = _copy_repo(tmp_path)
    with (root / "docs/annotate.md").open("a") as f:
        f.write(broken)
    assert readme_status.main(["--root", str(root)]) == 1
    assert "docs/annotate.md:" in capsys.readouterr().err


@pytest.mark.parametrize(("values", "steps", "text"), [
    ([0.30674], [".2f"], "0.31"),
    ([0.98931], ["%", ".1f"], "98.9"),
    ([2.17e-05], ["*1e6", ".0f"], "22"),
    ([1500.0], ["/1e3", ".1f"], "1.5"),
    ([0.9815, 0.9866, 0.9834], ["%", "range", ".0f"], "98–99"),
    ([0.031, 0.18], ["range", ".2f"], "0.03–0.18"),
    ([0.9815, 0.9849], ["%", "range", ".0f"], "98"),  # both ends read the same: one figure
    ([0, 7, 0], ["list"], "0, 7, 0"),
    ([3, 1, 2], ["min"], "1"), ([3, 1, 2], ["max"], "3"), ([3, 1, 2], ["sum"], "6"),
    ([1.0, 2.0, 4.0], ["mean", ".2f"], "2.33"), ([1.0, 2.0, 4.0], ["median", ".1f"], "2.0"),
    ([1.0, 2.0, 4.0], ["count"], "3"),
    ([18.66, 3.02], ["div", ".2f"], "6.18"),
    ([18.66, 0.0], ["div", ".2f"], NOT_MEASURED),
    (["a", "b"], ["count"], "2"),
    ([190976], [",d"], "190,976"),
    ([190976.0], [",d"], "190,976"),
    ([0.1256], [], "0.126"), ([22], [], "22"), (["2026-11-27"], [], "2026-11-27"),
])
def test_the_forms_render_as_documented(values, steps, text) -> None:
    assert render(values, steps) == text


@pytest.mark.parametrize("steps", [[], [".2f"], ["range", "%"], [".2f", "range"], ["div"], ["rnage"],
                                   ["range", "list"]])
def test_steps_that_cannot_write_the_values_are_refused(steps) -> None:
    with pytest.raises(FigureError):
        render([1.0, 2.0, 3.0], steps)


def test_keys_reach_nested_json_globs_other_files_and_study_csv_cells(tmp_path) -> None:
    (tmp_path / "bench").mkdir()
    (tmp_path / "bench/results.json").write_text(json.dumps(
        {"clean": {"plate": {"t": 13.1, "per_seed": [1, 2]}, "bowl": {"t": 11.5}, "cup": {"u": 1}}}))
    (tmp_path / "other.json").write_text(json.dumps({"rounds": {"long: 600 s, 01:15 UTC": {"ply": 190976}}}))
    (tmp_path / "summary.csv").write_text("object,baseline,removed\nplate,,0.75\nplate,raster,0.51\ncup,,\n")
    sources = Sources(tmp_path)
    assert sources.values("clean/plate/t") == [13.1]
    assert sources.values("clean/*/t") == [13.1, 11.5]  # the cup has no t: dropped, not an error
    assert sources.values("clean/plate/per_seed") == [1, 2]
    assert sources.values("other.json#rounds/long*/ply") == [190976]
    assert sources.values("summary.csv#object=plate,baseline=/removed") == [0.75]
    assert sources.values("summary.csv#object=plate/removed") == [0.75, 0.51]
    assert sources.values("summary.csv#object=cup/removed") is None  # an empty cell
    assert sources.values("summary.csv#object=p*,baseline=r*/removed") == [0.51]
    assert sources.values("summary.csv#0/baseline") is None
    assert sources.values("summary.csv#-1/object") == ["cup"]
    # --results of readme_status: the default source read from another file
    (tmp_path / "b.json").write_text(json.dumps({"clean": {"plate": {"t": 9.9}}}))
    assert Sources(tmp_path, {"bench/results.json": tmp_path / "b.json"}).values("clean/plate/t") == [9.9]


def test_the_readme_says_how_figures_are_marked() -> None:
    readme = (REPO / "README.md").read_text()
    assert re.search(r"`<!-- fig [^`]*-->[^`]*<!-- /fig -->`", readme)
    assert "make readme-status" in readme


def test_a_marker_inside_a_fenced_code_block_is_refused_as_it_would_show_its_comments() -> None:
    sources = Sources(REPO)
    spec = "tasks/clean_time/plate/X/ratio | .2f"
    good = figure_text(spec, sources)
    prose = f"ratio <!-- fig {spec} -->{good}<!-- /fig -->\n"
    block = f"```bash\ntactex clean   # <!-- fig {spec} -->{good}<!-- /fig -->\n```\n"
    findings = rewrite(prose + block + prose, sources, "page.md")[1]
    assert len(findings) == 1 and findings[0].line == 3 and "fenced code block" in findings[0].error
    assert rewrite(prose, sources, "page.md")[1] == []
