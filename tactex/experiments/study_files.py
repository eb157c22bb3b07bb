"""The input files a study's runs name (``cloud``, ``keep_out_mask``) travel with the study.

On a cluster a run executes on a machine that does not have the files of the machine the study
was started from. The driver reads each file the runs name once (:func:`pack_files`) and gives
the contents to the executor as the runs' shared input (on Ray: the object store, once per
node); a run writes its copy into its own machine's temporary folder, named by the content's hash
so that the runs of a machine write it once, and runs with that path (:func:`local_config`). The
records keep the path as the study names it: the run ids and tables do not depend on where a
run executed.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from tactex.errors import ConfigError

__all__ = ["FILE_FIELDS", "local_config", "pack_files"]

#: Config fields of the tasks that name an input file.
FILE_FIELDS = ("cloud", "keep_out_mask")


def pack_files(configs: Iterable[dict[str, Any]]) -> dict[str, tuple[str, bytes]] | None:
    """The contents of every file the configs name: path as named → (file suffix, bytes); None if none.

    Read on the machine that starts the study, relative paths from its working directory."""
    files: dict[str, tuple[str, bytes]] = {}
    for config in configs:
        for name in FILE_FIELDS:
            path = config.get(name)
            if not path or path in files:
                continue
            try:
                files[path] = (Path(path).suffix, Path(path).read_bytes())
            except OSError as exc:
                raise ConfigError(f"{name} = '{path}': cannot read the file to send it to the runs ({exc}); "
                                  "give a path readable where the study is started") from exc
    return files or None


def local_config(config: dict[str, Any], files: dict[str, tuple[str, bytes]] | None) -> dict[str, Any]:
    """``config`` with each packed file's path replaced by this machine's copy of it (written once,
    in the temporary folder under its content hash)."""
    if not files:
        return config
    out = dict(config)
    for name in FILE_FIELDS:
        path = out.get(name)
        if path and path in files:
            suffix, data = files[path]
            out[name] = str(_local_copy(data, suffix))
    return out


def _local_copy(data: bytes, suffix: str) -> Path:
    folder = Path(tempfile.gettempdir()) / "tactex-study-inputs"
    folder.mkdir(parents=True, exist_ok=True)
    target = folder / f"{hashlib.sha256(data).hexdigest()[:32]}{suffix}"
    if not target.is_file() or target.stat().st_size != len(data):
        # written aside and renamed: runs of this machine may write the same file at once
        fd, tmp = tempfile.mkstemp(dir=folder, suffix=suffix)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, target)
    return target
