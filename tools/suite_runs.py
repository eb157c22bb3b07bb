"""Record one full suite run (a log of `.ci/run`) in bench/suite_runs.json, for the README's test time.

``python tools/suite_runs.py LOG --name quiet-1 --busy 0 --commit SHA --exit-code 0 --wall-s 2044`` appends
{name, busy, commit, exit_code, wall_s, tests_s, passed, failed, skipped} read from pytest's last summary line
of LOG. tools/six_runs.sh calls it after every run; the README's figure reads the file through a marker, so
the time it states is the time the suite took, not a number typed in.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "bench" / "suite_runs.json"
SUMMARY = re.compile(r"^(?P<line>\d+ (?:passed|failed).* in (?P<s>[\d.]+)s.*)$", re.M)


def record(log: str, name: str, busy: bool, commit: str, exit_code: int, wall_s: float) -> dict:
    """The run's record from its log's text (pytest's counts of passed, failed and skipped tests)."""
    found = SUMMARY.findall(log)
    line, tests_s = found[-1] if found else ("", "nan")
    counts = {k: int(m.group(1)) if (m := re.search(rf"(\d+) {k}", line)) else 0
              for k in ("passed", "failed", "skipped")}
    return {"name": name, "busy": busy, "commit": commit, "exit_code": exit_code, "wall_s": wall_s,
            "tests_s": float(tests_s), **counts}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", type=Path)
    ap.add_argument("--name", required=True)
    ap.add_argument("--busy", type=int, choices=(0, 1), required=True)
    ap.add_argument("--commit", required=True)
    ap.add_argument("--exit-code", type=int, required=True)
    ap.add_argument("--wall-s", type=float, required=True)
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args(argv)
    rec = record(a.log.read_text(errors="replace"), a.name, bool(a.busy), a.commit, a.exit_code, a.wall_s)
    runs = json.loads(a.out.read_text())["runs"] if a.out.is_file() else []
    runs.append(rec)
    a.out.write_text(json.dumps({"runs": runs}, indent=1) + "\n")
    print(f"{a.out}: {rec}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
