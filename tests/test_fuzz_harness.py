"""The fuzz harness's own parts (tools/fuzz/, run by ``make fuzz``, not here): every seed it starts
from is a file its reader accepts, so a fuzz run mutates valid files, and the replay that decides
whether a crash class is fixed tells a crash from a pass."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import pytest

from tactex.errors import CloudError

FUZZ = Path(__file__).resolve().parents[1] / "tools" / "fuzz"
sys.path.insert(0, str(FUZZ))

import summary  # noqa: E402
from targets import TARGETS, Target  # noqa: E402


@pytest.mark.parametrize("reader", sorted(TARGETS))
def test_every_seed_is_read(tmp_path, reader) -> None:
    target = TARGETS[reader]
    seeds = target.seeds()
    assert seeds
    for i, data in enumerate(seeds):
        suffix = target.suffix
        if callable(suffix):
            suffix, data = suffix(data)
        path = tmp_path / f"seed{i}{suffix}"
        path.write_bytes(data)
        target.read(path)  # a valid result: no exception


def _returns(path) -> None:
    pass


def _refuses(path) -> None:
    raise CloudError(f"'{path}' is damaged")


def _refuses_unnamed(path) -> None:
    raise CloudError("damaged")


def _raises(path) -> None:
    raise ValueError("bad")


def _prints(path) -> None:
    print("noise", file=sys.stderr)


def _logs(path) -> None:
    logging.getLogger("trimesh.x").warning("noise")


@pytest.mark.parametrize(("read", "verdict"), [
    (_returns, "passes"), (_refuses, "passes"), (_refuses_unnamed, "CloudError without the file name"),
    (_raises, "ValueError: bad"), (_prints, "printed output"), (_logs, "log record from trimesh.x"),
])
def test_replay_tells_a_crash_from_a_pass(tmp_path, monkeypatch, read, verdict) -> None:
    monkeypatch.setitem(summary.TARGETS, "npz", Target(".npz", read, list))
    example = tmp_path / "example.npz"
    example.write_bytes(b"x")
    assert summary.replay("npz", example) == verdict
