"""Ctrl-C on a long run keeps what was done: ``explore``, ``sweep`` and ``clean`` write the steps,
settings or seconds done (metrics marked ``"partial": true``), exit with 130 and say where the data
are in one line. Each run is a real process sent SIGINT once its progress shows work done; the
time bounds are hang guards only, far above what the runs take on a loaded machine."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

#: Hang guards [s]: the set-up before the first progress line, and the exit after SIGINT (the report).
START_GUARD_S = 400.0
EXIT_GUARD_S = 300.0


class _Run:
    """A ``tactex`` process whose stderr lines are collected as they come (a reader thread, so that a
    silent process never blocks the test)."""

    def __init__(self, argv: list[str]) -> None:
        self.proc = subprocess.Popen([sys.executable, "-m", "tactex.cli", *argv], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)
        self.err: list[str] = []
        self.out: list[str] = []
        self._readers = [threading.Thread(target=self._read, args=(s, d), daemon=True)
                         for s, d in ((self.proc.stderr, self.err), (self.proc.stdout, self.out))]
        for r in self._readers:
            r.start()

    @staticmethod
    def _read(stream, into: list[str]) -> None:
        for line in stream:
            into.append(line.rstrip("\n"))

    def wait_for(self, seen: Callable[[str], bool]) -> None:
        """Until a stderr line satisfies ``seen`` (the run has done some work)."""
        t_end = time.monotonic() + START_GUARD_S
        while time.monotonic() < t_end:
            if any(seen(line) for line in list(self.err)):
                return
            if self.proc.poll() is not None:
                break
            time.sleep(0.05)
        self.proc.kill()
        raise AssertionError("the run showed no progress:\n" + "\n".join(self.err))

    def interrupt(self, sig: signal.Signals = signal.SIGINT) -> int:
        self.proc.send_signal(sig)
        try:
            code = self.proc.wait(timeout=EXIT_GUARD_S)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
        for r in self._readers:
            r.join(timeout=10)
        return code

    def last_error_line(self) -> str:
        return [ln for ln in self.err if ln.strip()][-1]


def _status(out: Path) -> dict:
    return json.loads((out / "status.json").read_text())


@pytest.mark.timeout(1200)
def test_ctrl_c_on_explore_keeps_the_steps_done(tmp_path) -> None:
    """The 8 000 steps a long explore had done were thrown away on Ctrl-C."""
    out = tmp_path / "explore"
    steps = 1_000_000  # never finishes: the progress line every few seconds is the sign to interrupt
    run = _Run(["explore", "cup", "--steps", str(steps), "--n-eigen", "8", "--voxel-size-m", "0.006", "--no-html",
                "--no-cache", "--out", str(out)])
    run.wait_for(lambda line: line.startswith("tactex explore: step "))
    code = run.interrupt()
    assert code == 130, "\n".join(run.err)
    line = run.last_error_line()
    assert line.startswith("tactex explore: interrupted; the ") and str(out) in line and "partial" in line, line
    m = json.loads((out / "metrics.json").read_text())
    done = m["steps_done"]
    assert m["partial"] is True and 0 < done < steps
    assert np.load(out / "trajectory.npy").shape == (done, 3)
    with np.load(out / "series.npz") as s:
        ergodicity = s["ergodicity"]
    assert ergodicity.shape == (done,) and np.isfinite(ergodicity).all()
    assert m["final_ergodicity"] == pytest.approx(float(ergodicity[-1]))
    assert (out / "cloud.png").is_file() and (out / "metrics.png").is_file()
    assert _status(out)["status"] == "interrupted" and str(out) in _status(out)["error"]


@pytest.mark.timeout(1200)
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_a_kill_or_a_closed_terminal_keeps_the_steps_done_as_ctrl_c_does(tmp_path, sig) -> None:
    """SIGTERM (kill, timeout, docker stop) and SIGHUP (a closed SSH session) killed a run outright: nothing
    saved, and on a robot nothing ended torque control but the robot's own reflex."""
    out = tmp_path / "explore"
    run = _Run(["explore", "cup", "--steps", "1000000", "--n-eigen", "8", "--voxel-size-m", "0.006", "--no-html",
                "--no-cache", "--out", str(out)])
    run.wait_for(lambda line: line.startswith("tactex explore: step "))
    code = run.interrupt(sig)
    assert code == 128 + int(sig), "\n".join(run.err)
    if sig == signal.SIGTERM:  # after a SIGHUP the terminal is gone: its output goes nowhere
        assert run.last_error_line().startswith("tactex explore: interrupted by SIGTERM; the ")
    m = json.loads((out / "metrics.json").read_text())
    assert m["partial"] is True and 0 < m["steps_done"] < 1_000_000
    assert np.load(out / "trajectory.npy").shape == (m["steps_done"], 3)
    status = _status(out)
    assert status["status"] == "interrupted" and status["error"].startswith(f"interrupted by {sig.name}; the ")


@pytest.mark.timeout(1200)
def test_ctrl_c_on_sweep_writes_the_settings_done(tmp_path) -> None:
    out = tmp_path / "sweep"
    run = _Run(["sweep", "cup", "--voxel-size-m", "0.006", "--n-eigen", "10", "20", "--alpha", "1", "5", "10", "50",
                "100", "--starts", "1", "--steps", "20000", "--workers", "1", "--no-cache", "--out", str(out)])
    run.wait_for(lambda line: line.startswith("tactex sweep: [1/10] "))
    code = run.interrupt()
    assert code == 130, "\n".join(run.err)
    line = run.last_error_line()
    assert line.startswith("tactex sweep: interrupted; the ") and str(out) in line and "resume" in line, line
    summary = json.loads((out / "sweep.json").read_text())
    done = len(list((out / "settings").glob("*.npz")))
    assert summary["partial"] is True and 1 <= done < 10
    assert len(summary["not_run"]) == 10 - done and not summary["failed"]
    table = (out / "table.csv").read_text()
    assert table.count(",ok,") == done and table.count(",not run,") == 10 - done
    assert (out / "curves.npz").is_file()
    assert _status(out)["status"] == "interrupted"


@pytest.mark.slow
@pytest.mark.timeout(1200)
def test_ctrl_c_on_clean_keeps_what_it_recorded(tmp_path) -> None:
    out = tmp_path / "clean"
    budget = 600.0  # simulated seconds: far more than the run lasts before the interrupt
    run = _Run(["clean", "--budget-s", str(budget), "--no-video", "--out", str(out)])
    # the progress bar's first line comes from the cleaning loop, with the robot at work
    run.wait_for(lambda line: line.startswith("clean tactex: ") and "%" in line)
    code = run.interrupt()
    assert code == 130, "\n".join(run.err)
    line = run.last_error_line()
    assert line.startswith("tactex clean: interrupted; what the clean run recorded") and str(out) in line, line
    m = json.loads((out / "metrics.json").read_text())
    assert m["partial"] is True and m["aborted"].startswith("KeyboardInterrupt")
    assert 0 < m["sim_time_s"] < budget
    with np.load(out / "series.npz") as s:
        assert s["t"].shape[0] > 0 and s["t"][-1] <= m["sim_time_s"] + 0.02
    assert (out / "report.html").is_file()
    assert _status(out)["status"] == "interrupted"
