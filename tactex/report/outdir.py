"""The run folder a command writes into: made and proved writable before any work starts."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from tactex.errors import InputError

__all__ = ["prepare_out_dir"]


def prepare_out_dir(out: str | Path) -> Path:
    """Create the run folder ``out`` (and its parents) and check that files can be written there.

    Done before a run, so that a bad ``--out`` fails at once with :class:`InputError`, not as an
    ``OSError`` traceback after minutes of computing. An existing folder is reused (files of the
    same name are overwritten).
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
