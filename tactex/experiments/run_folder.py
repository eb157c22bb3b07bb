"""The run folder a command writes into: made and proved writable before any work starts."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

from tactex.errors import InputError

__all__ = ["RUN_FILES", "check_run_folder", "prepare_out_dir", "run_in_folder"]

#: Files that make a folder a run's: what the commands' runs write (explore, clean, wipe: metrics.json;
#: sweep: sweep.json; study: study.json, runs.jsonl), and the CLI's status.json unless it says the run
#: failed (a run stopped by its checks or an error leaves no results to protect: run it again there).
RUN_FILES = ("status.json", "metrics.json", "sweep.json", "study.json", "runs.jsonl")
#: The command a result file belongs to, where only one command writes it.
_RESULTS_OF = {"sweep.json": "sweep", "study.json": "study", "runs.jsonl": "study"}


def prepare_out_dir(out: str | Path) -> Path:
    """Create the run folder ``out`` (and its parents) and check that files can be written there.

    Done before a run, so that a bad ``--out`` fails at once with :class:`InputError`, not as an
    ``OSError`` traceback after minutes of computing. An existing folder is reused (files of the
    same name are overwritten): the commands refuse one that holds another run before they get here
    (:func:`check_run_folder`).
    """
    p = Path(out).expanduser()
    if p.exists() and not p.is_dir():
        raise InputError(f"--out '{p}' is an existing file; give a directory for the run folder")
    try:
        p.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=p, prefix=".tactex-write-test-")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise InputError(
            f"cannot write the run folder --out '{p}': {exc.strerror or exc}; choose a writable directory"
        ) from exc
    return p


def run_in_folder(out: str | Path) -> str | None:
    """What run ``out`` holds: None when none (no folder, or none of :data:`RUN_FILES` in it), else
    a description ("a tactex explore run (done, 2026-12-02T01:00:00)"; "a run" when no status.json
    names its command)."""
    p = Path(out).expanduser()
    if not p.is_dir():
        return None
    results = any((p / name).is_file() for name in RUN_FILES if name != "status.json")
    status_file = p / "status.json"
    if not status_file.is_file():  # a run killed before the CLI wrote it: its files say whose it is
        owners = {command for name, command in _RESULTS_OF.items() if (p / name).is_file()}
        if len(owners) == 1:
            return f"a tactex {owners.pop()} run (stopped before it wrote status.json)"
        return "a run" if results else None
    try:
        status = json.loads(status_file.read_text())
        said = f"a tactex {status['command']} run ({status['status']}, {status['started']})"
        failed = status["status"] == "failed"
    except (OSError, ValueError, KeyError, TypeError):  # not one the CLI wrote
        said, failed = "a run", False
    return said if results or not failed else None


def check_run_folder(out: str | Path, command: str, *, force: bool = False, own: bool = False) -> None:
    """Refuse ``--out`` when it holds another run, unless ``force``: a run written over another leaves
    a folder of mixed files that no longer describe one run.

    ``own``: a run of the same ``command`` there is this command's to take over (sweep and study
    resume it, the demo replaces its previous one); a run of another command is still refused."""
    if force:
        return
    held = run_in_folder(out)
    if held is None or (own and held.startswith(f"a tactex {command} run ")):
        return
    raise InputError(f"--out '{Path(out).expanduser()}' holds {held}; give a new folder, or add --force to write "
                     "into it (files of the same name are replaced)")
