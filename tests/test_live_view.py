"""``--view`` without a browser: the feed's latest-value slot (never a queue; a torn read refused), the page's
colours of what is left, its Stop (SIGINT to the run, as Ctrl-C), and the commands' refusals."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys

import numpy as np
import pytest

from tactex.cli import main
from tactex.tasks import live_feed as lf
from tactex.tasks.live_feed import LiveFeed, read_snapshot


@pytest.fixture
def feed():
    f = LiveFeed()
    yield f
    f.close()


def test_the_slot_holds_only_the_latest_snapshot(feed):
    feed.set_cloud(np.eye(3), target=np.ones(3))
    field = np.memmap(feed.folder / "field_1.f32", dtype=np.float32, mode="r", shape=(3,))
    seqs = []
    for k in range(50):  # a page that reads nothing in between: nothing piles up, the last one is there
        feed.publish(0.1 * k, phase="explore", force_n=float(k), field=np.full(3, k, dtype=float),
                     breakdown_s={"contact": float(k)})
        seqs.append(feed.numbers[lf.SEQ])
    snap = read_snapshot(feed, field)
    assert snap.t_s == pytest.approx(4.9) and snap.force_n == 49.0 and snap.phase == "explore"
    assert np.array_equal(snap.field, np.full(3, 49.0)) and snap.breakdown_s == {"contact": 49.0}
    assert np.all(np.diff(seqs) == 2.0) and snap.seq == seqs[-1]  # each write: odd while inside, even after
    assert {p.name for p in feed.folder.iterdir()} == {"slot.bin", "cloud_1.npz", "field_1.f32"}


def test_a_read_while_the_writer_is_inside_is_refused(feed):
    feed.publish(1.0)
    feed.numbers[lf.SEQ] += 1.0  # the writer is inside the slot
    assert read_snapshot(feed, None) is None
    feed.numbers[lf.SEQ] += 1.0
    assert read_snapshot(feed, None).t_s == 1.0


def test_a_snapshot_is_due_once_per_period(feed, monkeypatch):
    now = [100.0]
    monkeypatch.setattr(lf.time, "monotonic", lambda: now[0])
    assert feed.due()
    feed.publish(0.0)
    assert not feed.due()
    now[0] += 0.099
    assert not feed.due()
    now[0] += 0.002
    assert feed.due()
    with pytest.raises(lf.InputError, match="period_s"):
        LiveFeed(period_s=0.0)


def test_the_page_colours_what_is_left_and_stop_sends_sigint(feed):
    pytest.importorskip("viser")
    from tactex.report.annotate_view import KEEP_OUT_RGB
    from tactex.report.live_view import DONE_RGB, LEFT_RGB, LiveView

    # stands in for the run; ready once it says so (a SIGINT during the interpreter's start-up exits 1, not as
    # an interrupted program)
    run = subprocess.Popen([sys.executable, "-c", "import time; print('ready', flush=True); time.sleep(120)"],
                           stdout=subprocess.PIPE, text=True)
    assert run.stdout.readline().strip() == "ready"
    view = LiveView(feed, run.pid, port=0, force_set_point_n=10.0)
    try:
        target = np.array([1.0, 2.0, 0.0, 0.0])
        keep_out = np.array([False, False, False, True])
        feed.set_cloud(np.random.default_rng(0).random((4, 3)), target=target, keep_out=keep_out)
        feed.publish(0.5, field=np.array([1.0, 0.0, 0.0, 0.0]), force_n=9.0, set_point_n=10.0, tcp_m=np.zeros(3),
                     world_R_tool=np.eye(3))
        assert view.poll() and view.colour_updates == 1
        rgb = view._cloud.colors
        assert tuple(rgb[0]) == tuple(LEFT_RGB.astype(int)) and tuple(rgb[1]) == tuple(DONE_RGB.astype(int))
        assert tuple(rgb[3]) == KEEP_OUT_RGB and tuple(rgb[2]) != tuple(LEFT_RGB.astype(int))
        assert not view.poll()  # nothing new in the slot: nothing sent
        feed._next = 0.0
        feed.publish(0.6, field=np.array([1.0, 0.0, 0.0, 0.0]))
        assert view.poll() and view.colour_updates == 1  # the same dirt left: the colours are not sent again
        view.stop()  # the Stop button
        assert run.wait(timeout=60) == -signal.SIGINT and feed.stop_requested and view.stop_button.disabled
        view.stop()  # once only
    finally:
        view.close()
        if run.poll() is None:
            run.kill()
            run.wait()


def test_bad_view_options_are_one_line_and_exit_2(tmp_path, capsys):
    not_cloud = tmp_path / "notes.ply"
    not_cloud.write_text("this is not a point cloud\n")
    cases = [
        (["explore", "plate", "--out", str(tmp_path / "a"), "--view-port", "9000"], "add --view"),
        (["clean", "--out", str(tmp_path / "b"), "--view", "--compare"], "--view shows one run"),
        (["explore", str(not_cloud), "--out", str(tmp_path / "c"), "--view", "--view-port", "0"], "notes.ply"),
    ]
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = str(held.getsockname()[1])
        for command in ("explore", "clean", "wipe"):
            source = ["plate"] if command == "explore" else []
            cases.append(([command, *source, "--out", str(tmp_path / f"{command}-port"), "--view", "--view-port",
                           port], f"--view-port {port} is in use"))
        for argv, words in cases:
            assert main(argv) == 2, argv
            err = capsys.readouterr().err.strip().splitlines()
            err = [line for line in err if "live view at" not in line]  # a page that started, then the refusal
            assert len(err) == 1 and err[0].startswith(f"tactex {argv[0]}: error:") and words in err[0], (argv, err)


def test_a_run_killed_outright_leaves_no_feed_behind():
    """SIGKILL gives the run no chance to close its page: the page's process sees it gone, ends and removes the
    feed's folder (in /dev/shm)."""
    import os
    import time

    pytest.importorskip("viser")
    code = ("from tactex.experiments.live import open_live_page; import time; p = open_live_page(0, 't'); "
            "print(p.feed.folder, flush=True); time.sleep(120)")
    run = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    folder = run.stdout.readline().strip()
    run.stdout.close()
    assert folder and os.path.isdir(folder)
    run.kill()
    run.wait()
    end = time.monotonic() + 60.0  # hang guard only
    while os.path.isdir(folder) and time.monotonic() < end:
        time.sleep(0.1)
    assert not os.path.isdir(folder)
