"""Write the policy study's table (docs/studies/wipe_policies/table.md) from the runs of one or more studies
(the sine panel and the bowl; the cup's wall, with policies sized for it).

Run: .venv/bin/python tools/policy_study_table.py docs/studies/wipe_policies/table.md runs/wipe_policies \
         runs/wipe_policies_cup
"""

from __future__ import annotations

import sys
from pathlib import Path

from tactex.experiments.policy_study import load_records, policy_rows, policy_table_markdown


def main(out: str, *study_dirs: str) -> None:
    if not study_dirs:
        sys.exit("usage: policy_study_table.py OUT.md STUDY_DIR [STUDY_DIR ...]")
    records = [r for d in study_dirs for r in load_records(d)]
    text = policy_table_markdown(policy_rows(records))
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    sources = ", ".join(f"{d}/runs.jsonl" for d in study_dirs)
    Path(out).write_text(f"<!-- written by tools/policy_study_table.py from {sources} -->\n\n{text}")
    print(text)


if __name__ == "__main__":
    main(*sys.argv[1:])
