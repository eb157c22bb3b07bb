"""The basis cache as a store: the size cap evicts the least recently used basis, ``tactex cache info|clear``,
and bad settings named."""

from __future__ import annotations

import os
import time
import warnings

import numpy as np
import pytest

from tactex.cli import main
from tactex.errors import CacheError, ConfigError
from tactex.pointcloud import SurfaceCloud
from tactex.spectral import build_basis
from tactex.spectral.cache_store import (
    DEFAULT_CACHE_MAX_GB,
    cache_cap_bytes,
    cache_entries,
    cache_info,
    clear_cache,
    enforce_cap,
)


def _cloud(shift: float) -> SurfaceCloud:
    g = np.linspace(0.0, 0.1, 15)
    x, y = np.meshgrid(g, g, indexing="ij")
    pts = np.column_stack([x.ravel(), y.ravel(), 0.01 * np.sin(30 * x.ravel())])
    return SurfaceCloud(points=pts + np.array([shift, 0.0, 0.0]))


def _age(path, seconds_ago: float) -> None:
    t = time.time() - seconds_ago
    os.utime(path, (t, t))


def _files(folder, sizes_and_ages) -> list:
    paths = []
    for i, (size, age) in enumerate(sizes_and_ages):
        p = folder / f"{i:02d}.npz"
        p.write_bytes(b"x" * size)
        _age(p, age)
        paths.append(p)
    return paths


def test_cap_evicts_least_recently_used_first(tmp_path) -> None:
    a, b, c = _files(tmp_path, [(100, 30), (100, 20), (100, 10)])  # a the oldest
    removed = enforce_cap(tmp_path, cap_bytes=250)
    assert [e.path for e in removed] == [a]
    assert sorted(p.name for p in tmp_path.glob("*.npz")) == [b.name, c.name]
    removed = enforce_cap(tmp_path, cap_bytes=100, keep=b)  # b just used: c goes although it is newer
    assert [e.path for e in removed] == [c]
    assert b.is_file()


def test_kept_entry_goes_only_when_alone_over_the_cap(tmp_path) -> None:
    (big,) = _files(tmp_path, [(500, 0)])
    assert [e.path for e in enforce_cap(tmp_path, cap_bytes=400, keep=big)] == [big]
    assert not big.exists()


def test_under_the_cap_nothing_is_removed_and_tmp_files_are_no_entries(tmp_path) -> None:
    _files(tmp_path, [(100, 5), (100, 1)])
    (tmp_path / ".tmp-abc.npz").write_bytes(b"x" * 1000)
    assert enforce_cap(tmp_path, cap_bytes=200) == []
    assert len(cache_entries(tmp_path)) == 2
    assert (tmp_path / ".tmp-abc.npz").is_file()


def test_build_basis_keeps_the_used_basis_and_evicts_the_oldest(tmp_path, monkeypatch) -> None:
    first = build_basis(_cloud(0.0), n_eigen=10, cache_dir=tmp_path)
    second = build_basis(_cloud(1.0), n_eigen=10, cache_dir=tmp_path)
    p1, p2 = tmp_path / f"{first.key}.npz", tmp_path / f"{second.key}.npz"
    _age(p1, 30)
    _age(p2, 20)
    assert build_basis(_cloud(0.0), n_eigen=10, cache_dir=tmp_path).from_cache  # first is now the newest
    size = max(p1.stat().st_size, p2.stat().st_size)
    monkeypatch.setenv("TACTEX_CACHE_MAX_GB", repr(2.5 * size / 1e9))
    third = build_basis(_cloud(2.0), n_eigen=10, cache_dir=tmp_path)
    assert p1.is_file() and (tmp_path / f"{third.key}.npz").is_file()
    assert not p2.exists()


def test_a_basis_over_the_cap_is_not_kept_and_says_so(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("TACTEX_CACHE_MAX_GB", "1e-9")  # one byte
    with pytest.warns(RuntimeWarning, match="larger than the cache's cap .* raise TACTEX_CACHE_MAX_GB"):
        b = build_basis(_cloud(0.0), n_eigen=10, cache_dir=tmp_path)
    assert not b.from_cache and cache_entries(tmp_path) == []


def test_cap_default_and_from_environment(monkeypatch) -> None:
    monkeypatch.delenv("TACTEX_CACHE_MAX_GB", raising=False)
    assert cache_cap_bytes() == int(DEFAULT_CACHE_MAX_GB * 1e9)
    monkeypatch.setenv("TACTEX_CACHE_MAX_GB", " 0.5 ")
    assert cache_cap_bytes() == 500_000_000


@pytest.mark.parametrize("value", ["abc", "0", "-1", "nan", "inf"])
def test_bad_cap_is_refused_before_any_work(value, tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("TACTEX_CACHE_MAX_GB", value)
    with pytest.raises(ConfigError, match=f"TACTEX_CACHE_MAX_GB='{value}' must be a positive number of gigabytes"):
        build_basis(_cloud(0.0), n_eigen=10, cache_dir=tmp_path)
    build_basis(_cloud(0.0), n_eigen=10, cache=False)  # without the cache the variable is not read


def test_cache_folder_that_is_a_file_is_refused(tmp_path) -> None:
    f = tmp_path / "cache"
    f.write_text("not a folder")
    with pytest.raises(CacheError, match="is a file, not a folder"):
        cache_info(f)


def test_cli_info_and_clear(tmp_path, monkeypatch, capsys) -> None:
    folder = tmp_path / "basis"
    monkeypatch.setenv("TACTEX_CACHE_DIR", str(folder))
    monkeypatch.setenv("TACTEX_CACHE_MAX_GB", "2")
    assert main(["cache", "info"]) == 0
    out = capsys.readouterr().out
    assert f"location: {folder} (from TACTEX_CACHE_DIR) (not created yet" in out
    assert "entries: 0" in out and "cap: 2.00 GB (from TACTEX_CACHE_MAX_GB" in out
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for shift in (0.0, 1.0):
            build_basis(_cloud(shift), n_eigen=10)
    total = sum(p.stat().st_size for p in folder.glob("*.npz"))
    (folder / ".tmp-old.npz").write_bytes(b"x" * 10)
    _age(folder / ".tmp-old.npz", 7200)  # a killed run's half-written file
    assert main(["cache", "info"]) == 0
    out = capsys.readouterr().out
    assert "entries: 2" in out and f"total size: {total / 1e6:.2f} MB" in out
    assert main(["cache", "clear"]) == 0
    assert capsys.readouterr().out.startswith(f"removed 3 file(s), {(total + 10) / 1e6:.2f} MB, from {folder}")
    assert list(folder.iterdir()) == []
    assert clear_cache(folder) == (0, 0)


def test_cli_bad_input(tmp_path, monkeypatch, capsys) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["cache", "purge"])
    assert exit_.value.code == 2
    assert "invalid choice: 'purge'" in capsys.readouterr().err
    monkeypatch.setenv("TACTEX_CACHE_MAX_GB", "lots")
    assert main(["cache", "info"]) == 2
    assert "TACTEX_CACHE_MAX_GB='lots' must be a positive number" in capsys.readouterr().err
    monkeypatch.delenv("TACTEX_CACHE_MAX_GB")
    (tmp_path / "f").write_text("")
    monkeypatch.setenv("TACTEX_CACHE_DIR", str(tmp_path / "f"))
    assert main(["cache", "clear"]) == 2
    assert "is a file, not a folder" in capsys.readouterr().err
