"""The figures of a fuzz run: executions, time and crashes per reader, and whether each crash class
is fixed (its kept input replayed on the current code passes). Printed, and written to
``OUT/results.json`` (or ``--results``) under the round's name (earlier rounds there are kept).

    python tools/fuzz/summary.py fuzz [--round NAME] [--results FILE]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from targets import TARGETS, LogRecords


def replay(reader: str, example: Path) -> str:
    """"passes" when the reader now returns or raises an expected error naming the file, else the crash."""
    from tactex.errors import TactexError

    target = TARGETS[reader]
    data = example.read_bytes()
    # a kept input is the file as read, under its suffix (for two-format readers, without the selector byte)
    suffix = example.suffix if callable(target.suffix) else target.suffix
    path = example.parent / f"replay{suffix}"
    path.write_bytes(data)
    records = LogRecords()
    logging.getLogger().addHandler(records)
    try:
        with tempfile.TemporaryFile("w+") as sink:
            with contextlib.redirect_stderr(sink), contextlib.redirect_stdout(sink):
                target.read(path)
            sink.seek(0)
            if sink.read():
                return "printed output"
    except TactexError as exc:
        if target.names_file and path.name not in str(exc):
            return f"{type(exc).__name__} without the file name"
    except Exception as exc:
        return f"{type(exc).__name__}: {str(exc)[:100]}"
    finally:
        logging.getLogger().removeHandler(records)
        path.unlink()
    if records.records:
        return f"log record from {records.records[0].name}"
    return "passes"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--round", default=time.strftime("%Y-%m-%dT%H:%M", time.gmtime()))
    parser.add_argument("--results", type=Path, help="the results file (default: OUT/results.json)")
    args = parser.parse_args(argv)
    readers = {}
    for reader in TARGETS:
        stats_file = args.out / f"{reader}.json"
        if not stats_file.is_file():
            continue
        stats = json.loads(stats_file.read_text())
        classes = {}
        for key, entry in stats["crash_classes"].items():
            now = replay(reader, Path(entry["example"]))
            classes[key] = {"inputs": entry["count"], "detail": entry["detail"][:160], "now": now}
        readers[reader] = {"executions": stats["executions"], "seconds": stats["seconds"],
                           "crashing_inputs": stats["crashes"], "classes_found": len(classes),
                           "classes_fixed": sum(c["now"] == "passes" for c in classes.values()),
                           "classes": classes, "warnings": stats.get("warnings", {})}
        r = readers[reader]
        print(f"{reader:22s} {r['executions']:9d} executions in {r['seconds']:6.0f} s; "
              f"{r['classes_found']} crash classes ({r['crashing_inputs']} inputs), {r['classes_fixed']} fixed")
        for key, c in classes.items():
            print(f"    {key}: {c['inputs']} inputs; now {c['now']}")
    results_file = args.results or args.out / "results.json"
    results = json.loads(results_file.read_text()) if results_file.is_file() else {"rounds": {}}
    results["rounds"][args.round] = readers
    results_file.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
