"""The basis cache as a store: its location, a size cap with least-recently-used eviction, and what
``tactex cache info|clear`` report.

A basis of a large cloud is big (N × n_K doubles: 240 k points and 1000 pairs are 1.9 GB), so the
folder is capped: after a basis is written, the least recently used files go until the folder fits
under the cap again. "Used" is the file's modification time, which a cache hit refreshes (access
times are often not kept by the file system: ``noatime``/``relatime``).
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

from tactex.errors import CacheError, ConfigError
from tactex.spectral.cache import CACHE_ENV, default_cache_dir

__all__ = [
    "CACHE_MAX_ENV",
    "DEFAULT_CACHE_MAX_GB",
    "CacheEntry",
    "CacheInfo",
    "cache_cap_bytes",
    "cache_entries",
    "cache_info",
    "clear_cache",
    "enforce_cap",
    "mark_used",
]

#: Environment variable holding the cap of the cache folder [GB, 10⁹ bytes].
CACHE_MAX_ENV = "TACTEX_CACHE_MAX_GB"
#: The default cap [GB]: room for a couple of industrial-size bases and many small ones.
DEFAULT_CACHE_MAX_GB = 4.0
_GB = 1e9


class CacheEntry(NamedTuple):
    """One basis file: its path, size [bytes] and last use (modification time, seconds since the epoch)."""

    path: Path
    size_bytes: int
    last_used: float


@dataclass(frozen=True)
class CacheInfo:
    """What the cache folder holds: where it is (and whether the environment chose it), its bases and their
    total size [bytes], and the cap [bytes]."""

    location: Path
    from_env: bool
    entries: tuple[CacheEntry, ...]
    total_bytes: int
    cap_bytes: int
    cap_from_env: bool


def cache_cap_bytes() -> int:
    """The cap of the cache folder [bytes]: ``$TACTEX_CACHE_MAX_GB`` if set, else :data:`DEFAULT_CACHE_MAX_GB`.

    Raises:
        ConfigError: the variable is not a positive number of gigabytes.
    """
    text = os.environ.get(CACHE_MAX_ENV, "").strip()
    if not text:
        return int(DEFAULT_CACHE_MAX_GB * _GB)
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(f"{CACHE_MAX_ENV}='{text}' must be a positive number of gigabytes (e.g. 4; "
                          f"default {DEFAULT_CACHE_MAX_GB:g}); a run's --no-cache stores no basis at all")
    return int(value * _GB)


def _folder(cache_dir: str | Path | None) -> Path:
    folder = Path(cache_dir).expanduser() if cache_dir is not None else default_cache_dir()
    if folder.exists() and not folder.is_dir():
        raise CacheError(f"the basis cache '{folder}' is a file, not a folder; remove it or set {CACHE_ENV}")
    return folder


def cache_entries(cache_dir: str | Path | None = None) -> list[CacheEntry]:
    """The basis files in the folder (None: the default one), least recently used first; none if it is absent.
    Half-written files (``.tmp-*``) are not entries."""
    folder = _folder(cache_dir)
    if not folder.is_dir():
        return []
    entries = []
    for path in folder.glob("*.npz"):
        if path.name.startswith(".tmp-"):
            continue
        try:
            st = path.stat()
        except FileNotFoundError:  # removed by another process meanwhile
            continue
        entries.append(CacheEntry(path, int(st.st_size), float(st.st_mtime)))
    return sorted(entries, key=lambda e: (e.last_used, e.path.name))


def mark_used(path: str | Path) -> None:
    """Make ``path`` the most recently used entry (a cache hit); a file gone meanwhile is left gone."""
    try:
        os.utime(path)
    except FileNotFoundError:
        pass


def enforce_cap(cache_dir: str | Path | None = None, cap_bytes: int | None = None,
                keep: str | Path | None = None) -> list[CacheEntry]:
    """Remove the least recently used basis files until the folder holds at most ``cap_bytes`` (None: the
    configured cap). ``keep`` (the basis just written or read) goes last, only when it alone exceeds the cap.
    Returns the entries removed."""
    cap = cache_cap_bytes() if cap_bytes is None else int(cap_bytes)
    entries = cache_entries(cache_dir)
    keep_path = Path(keep).resolve() if keep is not None else None
    # the kept file last, whatever its time: another process may have used an older one since
    order = sorted(entries, key=lambda e: e.path.resolve() == keep_path)  # stable: LRU order otherwise
    total = sum(e.size_bytes for e in entries)
    removed = []
    for entry in order:
        if total <= cap:
            break
        try:
            entry.path.unlink()
        except FileNotFoundError:  # another process evicted it first
            pass
        total -= entry.size_bytes
        removed.append(entry)
    return removed


def cache_info(cache_dir: str | Path | None = None) -> CacheInfo:
    """Where the cache is, what it holds and its cap."""
    folder = _folder(cache_dir)
    entries = tuple(cache_entries(folder))
    return CacheInfo(location=folder, from_env=cache_dir is None and bool(os.environ.get(CACHE_ENV)),
                     entries=entries, total_bytes=sum(e.size_bytes for e in entries), cap_bytes=cache_cap_bytes(),
                     cap_from_env=bool(os.environ.get(CACHE_MAX_ENV, "").strip()))


def clear_cache(cache_dir: str | Path | None = None, *, stale_tmp_s: float = 3600.0) -> tuple[int, int]:
    """Remove every basis file (and half-written ones older than ``stale_tmp_s`` [s], left by a killed run; a
    younger one may be another run's write in progress). Returns (files removed, bytes freed)."""
    folder = _folder(cache_dir)
    if not folder.is_dir():
        return 0, 0
    count = freed = 0
    now = time.time()
    for path in folder.glob("*.npz"):
        try:
            st = path.stat()
            if path.name.startswith(".tmp-") and now - st.st_mtime < stale_tmp_s:
                continue
            path.unlink()
        except FileNotFoundError:
            continue
        count += 1
        freed += int(st.st_size)
    return count, freed
