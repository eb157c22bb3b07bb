"""Write the policy study's table (docs/studies/wipe_policies/table.md) from the study's runs.

Run: .venv/bin/python tools/policy_study_table.py runs/wipe_policies docs/studies/wipe_policies/table.md
"""

from __future__ import annotations

import sys
from pathlib import Path

from tactex.experiments.policy_study import load_records, policy_rows, policy_table_markdown


def main(study_dir: str, out: str) -> None:
    text = policy_table_markdown(policy_rows(load_records(study_dir)))
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_text(f"<!-- written by tools/policy_study_table.py from {study_dir}/runs.jsonl -->\n\n{text}")
    print(text)


if __name__ == "__main__":
    main(*sys.argv[1:3])
