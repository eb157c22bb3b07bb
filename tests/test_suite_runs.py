"""tools/suite_runs.py: a suite run's record read from its log, appended to bench/suite_runs.json."""

from __future__ import annotations

import importlib.util
import json

from tests.conftest import REPO

_spec = importlib.util.spec_from_file_location("suite_runs", REPO / "tools" / "suite_runs.py")
suite_runs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(suite_runs)

LOG = """All checks passed!
.venv/bin/python -m pytest -q
....F.s
FAILED tests/test_x.py::test_y - AssertionError
2 failed, 1791 passed, 2 skipped, 4 warnings in 2075.93s (0:34:35)
"""


def test_a_runs_record_is_read_from_pytests_last_summary_line(tmp_path) -> None:
    rec = suite_runs.record(LOG, "busy-1", True, "abc", 2, 2100.0)
    assert rec == {"name": "busy-1", "busy": True, "commit": "abc", "exit_code": 2, "wall_s": 2100.0,
                   "tests_s": 2075.93, "passed": 1791, "failed": 2, "skipped": 2}
    green = suite_runs.record("1794 passed, 1 skipped in 2023.65s (0:33:43)\n", "quiet-1", False, "abc", 0, 2044.0)
    assert (green["passed"], green["failed"], green["skipped"]) == (1794, 0, 1)
    # a run that never reached pytest's summary (set-up failed) is still recorded, with no counts
    broken = suite_runs.record("make: *** [test] Error 1\n", "quiet-2", False, "abc", 2, 30.0)
    assert broken["passed"] == 0 and broken["tests_s"] != broken["tests_s"]  # NaN


def test_runs_are_appended_to_the_file(tmp_path) -> None:
    log, out = tmp_path / "run.log", tmp_path / "suite_runs.json"
    log.write_text(LOG)
    for name in ("busy-1", "busy-2"):
        assert suite_runs.main([str(log), "--name", name, "--busy", "1", "--commit", "abc", "--exit-code", "2",
                                "--wall-s", "2100", "--out", str(out)]) == 0
    assert [r["name"] for r in json.loads(out.read_text())["runs"]] == ["busy-1", "busy-2"]
