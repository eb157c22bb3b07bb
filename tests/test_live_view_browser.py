"""``--view`` in a real browser: a short simulated clean shown live in Debian's Chromium driven by Playwright
(every request off localhost aborted): the page loads with no console error, the cloud's colours are sent at
least once a second while the robot cleans (and the drawn cloud turns green), and the page's Stop button ends
the run as Ctrl-C does: exit 130, status.json "interrupted", the data recorded so far saved.
Skipped where Playwright or Chromium is missing (.ci/run installs Chromium with apt)."""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from tactex.report.live_view import FORCE_WINDOW_S

from .test_annotate_browser import CHROMIUM, CHROMIUM_ARGS, guard_page

pytestmark = [
    pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (Debian: apt-get install chromium)"),
    pytest.mark.timeout(900),
    pytest.mark.slow,
]
HANG_S = 400.0  # hang guard only: a clean's capture and plan take minutes on a busy machine
#: Where the test leaves its screenshot of the page, half the dirt gone, when set (docs/live_clean.png is made so).
SHOT_DIR = os.environ.get("TACTEX_SHOT_DIR", "")


def _green_pixels(png: bytes) -> int:
    """Pixels of the page drawn in the live view's 'done' green."""
    import io

    from PIL import Image

    from tactex.report.live_view import DONE_RGB

    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=float)
    return int((np.abs(rgb - DONE_RGB).max(axis=2) < 30).sum())


def _body(page) -> str:
    return page.evaluate("document.body.innerText")


def _wait_text(page, pattern: str, what: str, proc) -> re.Match:
    end = time.monotonic() + HANG_S
    while True:
        found = re.search(pattern, _body(page))
        if found:
            return found
        if proc.poll() is not None:
            raise AssertionError(f"the run ended (exit {proc.returncode}) before {what}")
        if time.monotonic() > end:
            raise AssertionError(f"hung waiting for {what}")
        time.sleep(0.2)


def _cleaning_seconds(samples: list[tuple[int, bool]]) -> list[tuple[int, int]]:
    """The colour-update counts at both ends of each sampled second the page showed cleaning (explore) throughout."""
    return [(a[0], b[0]) for a, b in itertools.pairwise(samples) if a[1] and b[1]]


def test_a_live_clean_updates_its_colours_and_stop_ends_it_as_ctrl_c(tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (the dev extra)")
    out = tmp_path / "run"
    proc = subprocess.Popen(
        # a slow agent over the whole plate: the run must outlast the page's checks on a quiet machine too (at
        # the default speed the plate is clean after about 10 s of wall time, before Stop is pressed)
        [sys.executable, "-m", "tactex.cli", "clean", "--out", str(out), "--view", "--view-port", "0", "--no-video",
         "--quiet", "--budget-s", "600", "--marking", "full", "--max-velocity", "0.25"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    said: list[str] = []
    url_seen = threading.Event()

    def drain() -> None:  # a full pipe would block the run
        for line in proc.stderr:
            said.append(line)
            if "live view at" in line:
                url_seen.set()

    threading.Thread(target=drain, daemon=True).start()
    outside: list[str] = []
    errors: list[str] = []
    plots: list = []
    t_shown = float("nan")
    samples: list[tuple[int, bool]] = []  # (colour updates shown, whether the phase shown was explore)
    try:
        assert url_seen.wait(HANG_S), "".join(said)
        url = re.search(r"live view at (http://127\.0\.0\.1:\d+/)", "".join(said)).group(1)
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1100, "height": 720})
            local = ("http://127.0.0.1", "ws://127.0.0.1", "data:", "blob:")

            guard_page(page, local, outside, errors)
            page.goto(url, timeout=HANG_S * 1000)
            _wait_text(page, r"phase explore", "the robot to clean (phase explore)", proc)
            first = page.locator("canvas").first.screenshot()
            if SHOT_DIR:  # the docs' picture: about half the dirt gone
                _wait_text(page, r"dirt left \(simulation\) \[-\]: 0\.(5[0-5]|[1-4]\d)", "half the dirt gone", proc)
                with contextlib.suppress(sync_api.Error):  # the page's note that Chromium draws without a GPU
                    page.locator("button.mantine-Notification-closeButton").first.click(timeout=2000)
                page.screenshot(path=str(Path(SHOT_DIR) / "live_clean.png"))
            # once a second: the count of colour updates the page shows, and the phase; the run leaves explore for
            # each camera look, so sample until three seconds were seen cleaning from end to end (hang guard only)
            deadline = time.monotonic() + HANG_S
            while len(_cleaning_seconds(samples)) < 3 and time.monotonic() < deadline and proc.poll() is None:
                body = _body(page)
                found = re.search(r"cloud colours sent (\d+) times", body)
                samples.append((int(found.group(1)) if found else -1, "phase explore" in body))
                time.sleep(1.0)
            # the drawn cloud turns greener as the dirt goes; Chromium draws without a GPU here, and on a busy machine a
            # frame can lag the colours it was sent by seconds: look again until it does (hang guard only)
            deadline = time.monotonic() + HANG_S
            later = page.locator("canvas").first.screenshot()
            while _green_pixels(later) <= _green_pixels(first) and time.monotonic() < deadline and proc.poll() is None:
                time.sleep(1.0)
                later = page.locator("canvas").first.screenshot()
            # the force plot (uPlot, through viser's test hook) spans the data it was sent
            t_shown = float(re.search(r"t = ([\d.]+) s", _body(page)).group(1))
            plots = page.evaluate("() => Object.values(window.__viserTestpoints?.uplots || {}).map(p => "
                                  "[p.chart.scales.x.min, p.chart.scales.x.max, p.chart.data[0].length])")
            page.get_by_role("button", name="Stop").click()
            code = proc.wait(timeout=HANG_S)
            browser.close()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    text = "".join(said)
    assert outside == [], f"the page asked for something off localhost: {outside}"
    assert not errors, errors
    # every second the robot cleaned through (explore shown at both ends), new colours reached the page
    cleaning = _cleaning_seconds(samples)
    assert len(cleaning) >= 3 and all(b > a for a, b in cleaning), samples
    # a line over at most the plot's window of run time, following the run: its right end within a second or two
    # of the run time the page showed (the run publishes every 0.1 s of wall time and the simulation runs faster
    # than that on a quiet machine, so the points in the window depend on the machine: a line, not a count)
    assert len(plots) == 1 and plots[0][2] >= 3 and plots[0][1] > plots[0][0] > 0.0, plots
    assert plots[0][1] - plots[0][0] <= FORCE_WINDOW_S + 0.5, plots
    assert plots[0][1] >= t_shown - 2.0, (plots, t_shown)
    assert _green_pixels(later) > _green_pixels(first), "the cloud drawn turned no greener while the robot cleaned"
    # Stop is Ctrl-C: the same exit, status and saved data
    assert code == 130, text
    assert "tactex clean: interrupted" in text
    status = json.loads((out / "status.json").read_text())
    assert status["status"] == "interrupted", status
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["partial"] and metrics["aborted"].startswith("KeyboardInterrupt"), metrics["aborted"]
    with np.load(out / "series.npz", allow_pickle=False) as z:
        assert len(z["t"]) > 0 and float(z["t"][-1]) > 1.0


@pytest.mark.franka
def test_stop_on_the_page_ends_a_twin_wipe_as_ctrl_c(tmp_path):
    """On a robot (tactex twin over libfranka's protocol), Stop ends torque control as Ctrl-C does: the run
    says it stopped, keeps what it recorded, exits 130, and the robot takes a new connection at once."""
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (the dev extra)")
    pytest.importorskip("pylibfranka", reason="needs the franka extra")
    pytest.importorskip("franky_sim", reason="needs the franka extra")
    from tactex.robots.libfranka_backend import FrankaConfig, LibfrankaBackend
    from tactex.twin.process import TwinProcess

    out = tmp_path / "run"
    with TwinProcess("sine_panel") as twin:
        proc = subprocess.Popen(
            [sys.executable, "-m", "tactex.cli", "wipe", "--robot", "franka", "--robot-ip", twin.hostname,
             "--late-abort-ms", "5000", "--camera", "none", "--duration-s", "20", "--no-video", "--out", str(out),
             "--view", "--view-port", "0"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        said: list[str] = []
        url_seen, contact, stopped = threading.Event(), threading.Event(), threading.Event()

        def drain() -> None:
            for line in proc.stderr:
                said.append(line)
                url_seen.set() if "live view at" in line else None
                contact.set() if "contact=" in line else None
                stopped.set() if "stopped early" in line else None

        threading.Thread(target=drain, daemon=True).start()
        try:
            assert url_seen.wait(HANG_S), "".join(said)
            url = re.search(r"live view at (http://127\.0\.0\.1:\d+/)", "".join(said)).group(1)
            with sync_api.sync_playwright() as p:
                browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
                page = browser.new_page(viewport={"width": 1100, "height": 720})
                page.goto(url, timeout=HANG_S * 1000)
                assert contact.wait(HANG_S), "".join(said)  # the policy runs on the robot, in contact
                _wait_text(page, r"phase wipe", "the page to show the wipe", proc)
                page.get_by_role("button", name="Stop").click()
                assert stopped.wait(HANG_S), "".join(said)  # torque control has ended
                code = proc.wait(timeout=HANG_S)
                browser.close()
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        text = "".join(said)
        assert code == 130, text
        metrics = json.loads((out / "metrics.json").read_text())
        assert metrics["aborted"].startswith("KeyboardInterrupt") and metrics["partial"] is True
        assert metrics["loop_ticks"] > 100 and (out / "series.npz").is_file()
        assert json.loads((out / "status.json").read_text())["status"] == "interrupted"
        check = LibfrankaBackend(FrankaConfig(robot_ip=twin.hostname))  # the robot is free again
        check.close()
