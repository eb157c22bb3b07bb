"""tactex annotate in a real browser: Debian's Chromium driven by Playwright loads the viser page from
the local server with every request off localhost aborted, the cloud is drawn, a click and a
Shift+click on it stroke a target, a click a keep-out zone (taken back with Undo and painted again),
and the page's Save button writes them.
Skipped where Playwright or Chromium is missing (.ci/run installs Chromium with apt)."""

from __future__ import annotations

import shutil
import time

import numpy as np
import pytest

from tactex.pointcloud.annotation import Annotation
from tactex.pointcloud.io import read_cloud
from tactex.pointcloud.ply_marks import write_marked_ply

from .test_annotate import plane

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = [
    pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (Debian: apt-get install chromium)"),
    pytest.mark.timeout(300),
]
#: Chromium's own calls home would be refused on a closed network, many at a time.
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--disable-quic",
                 "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync"]
HANG_S = 60.0  # hang guard only


def guard_page(page, allowed: tuple[str, ...], outside: list[str], errors: list[str]) -> None:
    """Abort every request of ``page`` whose URL starts with none of ``allowed`` (recorded in ``outside``), and
    collect the page's console errors and uncaught exceptions in ``errors``: a page that works offline asks for
    nothing else, and one that renders says nothing in red."""

    def route(r):
        if r.request.url.startswith(allowed):
            r.continue_()
        else:
            outside.append(r.request.url)
            r.abort()

    page.route("**/*", route)
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))


def _wait_for(predicate, what: str) -> None:
    end = time.monotonic() + HANG_S
    while not predicate():
        if time.monotonic() > end:
            raise AssertionError(f"hung waiting for {what}")
        time.sleep(0.1)


def _ball(points: np.ndarray, mask: np.ndarray, radius_m: float) -> float:
    """The radius of the smallest ball about a marked point holding every marked point [m]."""
    marked = points[mask]
    return float(min(np.linalg.norm(marked - p, axis=1).max() for p in marked)) if len(marked) else np.inf


def _segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance [m] of each point to the segment from a to b."""
    t = np.clip((points - a) @ (b - a) / float((b - a) @ (b - a)), 0.0, 1.0)
    return np.linalg.norm(points - (a + t[:, None] * (b - a)), axis=1)


def test_paint_in_chromium_then_save(tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (the dev extra)")
    from tactex.report.annotate_view import AnnotateView

    scan = tmp_path / "scan.ply"
    base = plane(61)
    write_marked_ply(base, np.zeros(len(base)), np.zeros(len(base), dtype=bool), scan)
    read = read_cloud(scan)
    out = tmp_path / "marked.ply"
    view = AnnotateView(Annotation(read.cloud), out, port=0, source=scan)
    outside: list[str] = []
    errors: list[str] = []
    try:
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1000, "height": 700})
            local = ("http://127.0.0.1", "ws://127.0.0.1", "data:", "blob:")

            guard_page(page, local, outside, errors)
            page.goto(view.url, timeout=HANG_S * 1000)
            page.get_by_text(f"{len(read.cloud)} points", exact=False).wait_for(timeout=HANG_S * 1000)
            canvas = page.locator("canvas").first
            canvas.wait_for(timeout=HANG_S * 1000)
            box = canvas.bounding_box()
            cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
            time.sleep(2.0)  # let the first frames draw before a click is taken for one on the cloud
            # the camera looks at the cloud's centre: a click there paints a target around it
            view.radius.value = 6.0
            page.mouse.click(cx, cy)
            _wait_for(lambda: view.annotation.counts().n_target > 0, "the click to paint a target")
            start = view.last_index
            dab = view.annotation.counts().n_target
            page.keyboard.down("Shift")  # Shift+click: a stroke from the last click
            page.mouse.click(cx - box["width"] / 8, cy + box["height"] / 10)
            page.keyboard.up("Shift")
            _wait_for(lambda: view.annotation.counts().n_target > dab, "the Shift+click to stroke the target")
            end = view.last_index
            view.mark.value = "keep-out"
            page.mouse.click(cx + box["width"] / 8, cy)
            _wait_for(lambda: view.annotation.counts().n_keep_out > 0, "the click to paint a keep-out zone")
            page.get_by_role("button", name="Undo").click()
            _wait_for(lambda: view.annotation.counts().n_keep_out == 0, "the Undo button to take it back")
            page.mouse.click(cx + box["width"] / 8, cy)
            _wait_for(lambda: view.annotation.counts().n_keep_out > 0, "the click to paint it again")
            shot = page.screenshot(path=str(tmp_path / "annotate.png"))
            page.get_by_role("button", name="Save").click()
            _wait_for(lambda: out.is_file() and view.unsaved == 0, "the Save button to write the file")
            page.get_by_text("saved", exact=False).first.wait_for(timeout=HANG_S * 1000)
            target_saved = view.annotation.target.copy()
            # a change after the save (the keep-out brush over the target at the centre): the status no longer
            # says the file holds the page's marks
            page.mouse.click(cx, cy)
            _wait_for(lambda: view.unsaved == 1, "a click after the save to paint")
            page.get_by_text("1 change(s) since", exact=False).first.wait_for(timeout=HANG_S * 1000)
            browser.close()
    finally:
        view.stop()
    assert outside == [], f"the page asked for something off localhost: {outside}"
    assert not errors, errors
    assert len(shot) > 10_000  # a drawn page, not a blank one
    saved = read_cloud(out)
    t, k = saved.cloud.target > 0, saved.keep_out
    assert t.any() and k.any() and not (t & k).any()
    r, h = 6e-3, read.cloud.spacing
    pts = saved.cloud.points
    a, b = pts[start], pts[end]
    # the stroke starts at the centre, where the camera looks, and is the brush dragged from there to the
    # second click: every target point within a brush radius of the chord, and the chord covered
    assert np.linalg.norm(a) <= h and np.linalg.norm(b - a) > 4 * r
    assert _segment_distance(pts[t], a, b).max() <= r + 1e-9
    along = a + np.linspace(0, 1, 50)[:, None] * (b - a)
    assert all(np.linalg.norm(pts[t] - q, axis=1).min() <= h for q in along)
    # the keep-out is one dab on the other side of the centre
    assert _ball(pts, k, r) <= r + 1e-9
    assert (pts[k].mean(axis=0) - a) @ (b - a) < 0
    assert np.array_equal(saved.cloud.target, target_saved)
