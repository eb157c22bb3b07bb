"""``tactex cache info|clear``: where the Laplace basis cache is, what it holds, and emptying it."""

from __future__ import annotations

import argparse

NAME = "cache"
HELP = ("the Laplace basis cache ($TACTEX_CACHE_DIR, default ~/.cache/tactex/basis; capped at "
        "$TACTEX_CACHE_MAX_GB, default 4 GB): info shows its location, entries, size and cap; clear empties it")


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("action", choices=("info", "clear"),
                        help="info: location, entries, total size and cap; clear: remove every stored basis")


def _gb(n_bytes: float) -> str:
    return f"{n_bytes / 1e9:.2f} GB" if n_bytes >= 1e8 else f"{n_bytes / 1e6:.2f} MB"


def run(args: argparse.Namespace) -> int:
    from tactex.spectral.cache import CACHE_ENV
    from tactex.spectral.cache_store import CACHE_MAX_ENV, cache_info, clear_cache

    info = cache_info()
    if args.action == "clear":
        count, freed = clear_cache(info.location)
        print(f"removed {count} file(s), {_gb(freed)}, from {info.location}")
        return 0
    where = f"(from {CACHE_ENV})" if info.from_env else f"(default; set {CACHE_ENV} to move it)"
    state = "" if info.location.is_dir() else " (not created yet: no basis stored)"
    print(f"location: {info.location} {where}{state}")
    print(f"entries: {len(info.entries)}")
    print(f"total size: {_gb(info.total_bytes)}")
    origin = f"from {CACHE_MAX_ENV}" if info.cap_from_env else f"default; set {CACHE_MAX_ENV} to change it"
    print(f"cap: {info.cap_bytes / 1e9:.2f} GB ({origin}; beyond it the least recently used bases are removed)")
    if info.entries:
        newest = info.entries[-1]
        largest = max(info.entries, key=lambda e: e.size_bytes)
        print(f"largest: {largest.path.name} ({_gb(largest.size_bytes)}); most recently used: {newest.path.name}")
    return 0
