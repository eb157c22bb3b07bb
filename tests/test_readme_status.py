"""The README's Status table is bench/results.json, rendered: a figure edited by hand, or a bench
run not followed by ``make readme-status``, fails here."""

from __future__ import annotations

import copy
import importlib.util
import json

from tests.conftest import REPO

_spec = importlib.util.spec_from_file_location("readme_status", REPO / "tools" / "readme_status.py")
readme_status = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(readme_status)


def _results() -> dict:
    return json.loads((REPO / "bench" / "results.json").read_text())


def test_readme_status_matches_the_bench_results() -> None:
    readme = (REPO / "README.md").read_text()
    assert readme_status.updated_readme(readme, _results()) == readme, (
        "README.md's Status table differs from bench/results.json: run `make readme-status`")


def test_a_changed_figure_is_caught(tmp_path) -> None:
    data = _results()
    changed = copy.deepcopy(data)
    changed["tasks"]["clean"]["bowl"]["tactex"]["max_contact_force_n"] = 19.1
    readme = readme_status.updated_readme((REPO / "README.md").read_text(), data)
    assert "19.1 N" in readme_status.updated_readme(readme, changed)
    (tmp_path / "r.md").write_text(readme)
    (tmp_path / "b.json").write_text(json.dumps(changed))
    argv = ["--check", "--readme", str(tmp_path / "r.md"), "--results", str(tmp_path / "b.json")]
    assert readme_status.main(argv) == 1
    (tmp_path / "b.json").write_text(json.dumps(data))
    assert readme_status.main(argv) == 0


def test_every_row_has_its_figure_and_a_missing_stage_says_so() -> None:
    rows = readme_status.status_rows(_results())
    assert rows and all(measured != "not measured" for _, _, measured, _ in rows)
    data = _results()
    del data["franka"]
    rows = {what: measured for what, _, measured, _ in readme_status.status_rows(data)}
    assert rows["`--cloud` clean over the protocol (twin): removed"] == "not measured"
