"""tactex annotate without a browser: the painting (brush, erase, fill, pick, areas), the marked PLY's
round trip through the loaders, and the command's refusals."""

from __future__ import annotations

import socket

import numpy as np
import pytest

from tactex.cli import main
from tactex.pointcloud.annotation import Annotation
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.pointcloud.io import read_cloud, save_ply
from tactex.pointcloud.keep_out import raw_keep_out
from tactex.pointcloud.ply_marks import write_marked_ply

H = 0.002  # grid spacing [m]


def plane(n: int = 41) -> SurfaceCloud:
    """An n × n grid at spacing H in the z = 0 plane, centred on the origin, grey."""
    g = (np.mgrid[0:n, 0:n].reshape(2, -1).T - (n - 1) / 2) * H
    points = np.c_[g, np.zeros(len(g))]
    return SurfaceCloud(points=points, colors=np.full((len(g), 3), 0.5), spacing=H)


def centre_index(cloud: SurfaceCloud) -> int:
    return int(np.argmin(np.linalg.norm(cloud.points, axis=1)))


def test_brush_marks_the_ball_of_its_radius_and_erase_clears_it():
    a = Annotation(plane())
    i = centre_index(a.cloud)
    changed = a.paint(i, 0.0051, "target", weight=2.0)
    inside = np.linalg.norm(a.cloud.points, axis=1) <= 0.0051
    assert set(changed.tolist()) == set(np.flatnonzero(inside).tolist())
    assert np.all(a.target[inside] == 2.0) and np.all(a.target[~inside] == 0.0)
    a.paint(i, 0.0031, "keep_out")
    core = np.linalg.norm(a.cloud.points, axis=1) <= 0.0031
    assert np.array_equal(a.keep_out, core)
    assert np.all(a.target[core] == 0.0), "a point is target or kept out, never both"
    assert np.count_nonzero(a.target) == inside.sum() - core.sum()
    a.paint(i, 0.02, "erase")
    far = np.linalg.norm(a.cloud.points, axis=1) <= 0.02
    assert not a.keep_out[far].any() and not a.target[far].any()


def test_stroke_covers_the_chord_within_its_radius():
    cloud = plane()
    a = Annotation(cloud)
    start = int(np.argmin(np.linalg.norm(cloud.points - [-0.02, -0.01, 0], axis=1)))
    end = int(np.argmin(np.linalg.norm(cloud.points - [0.02, 0.012, 0], axis=1)))
    a.stroke(start, end, 0.003, "target")
    p, q = cloud.points[start], cloud.points[end]
    t = np.clip((cloud.points - p) @ (q - p) / ((q - p) @ (q - p)), 0, 1)
    dist = np.linalg.norm(cloud.points - (p + t[:, None] * (q - p)), axis=1)
    assert np.array_equal(a.target > 0, dist <= 0.003 + 1e-12)


def test_undo_takes_back_the_marks_in_reverse_order():
    a = Annotation(plane())
    i = centre_index(a.cloud)
    a.paint(i, 0.005, "target", weight=2.0)
    first = (a.target.copy(), a.keep_out.copy())
    a.paint(i, 0.003, "keep_out")
    a.paint(i, 0.003, "keep_out")  # changes nothing: nothing to take back for it
    assert a.undo().size > 0
    assert np.array_equal(a.target, first[0]) and np.array_equal(a.keep_out, first[1])
    assert a.undo().size > 0 and not a.target.any() and not a.keep_out.any()
    assert a.undo().size == 0


def test_counts_give_points_and_areas_in_cm2():
    a = Annotation(plane())
    a.paint(centre_index(a.cloud), 0.0051, "target")
    c = a.counts()
    assert c.n_points == 41 * 41
    assert c.target_area_cm2 == pytest.approx(c.n_target * (H * 100) ** 2)
    assert c.n_keep_out == 0 and c.keep_out_area_cm2 == 0.0


def test_fill_stops_at_a_painted_outline():
    cloud = plane()
    a = Annotation(cloud)
    r = np.linalg.norm(cloud.points, axis=1)
    ring = np.flatnonzero((r > 0.010) & (r <= 0.0145))  # a closed stroke about two points wide
    a.mark(ring, "keep_out")
    changed = a.fill(centre_index(cloud), "target", weight=0.5)
    assert set(changed.tolist()) == set(np.flatnonzero(r <= 0.010).tolist())
    # a fill from outside the ring takes the rest of the unmarked plane, not the inside
    outside = int(np.argmax(r))
    a.fill(outside, "target", weight=3.0)
    assert np.all(a.target[r > 0.0145] == 3.0) and np.all(a.target[r <= 0.010] == 0.5)


def test_pick_takes_the_first_point_along_the_ray():
    top = plane()
    below = SurfaceCloud(points=top.points - [0, 0, 0.01], spacing=H)
    two = SurfaceCloud(points=np.vstack([top.points, below.points]), spacing=H)
    a = Annotation(two)
    i = a.pick(np.array([0.0021, 0.0, 1.0]), np.array([0.0, 0.0, -1.0]))
    assert i is not None and a.cloud.points[i][2] == 0.0
    assert np.linalg.norm(a.cloud.points[i][:2] - [0.002, 0.0]) < 1e-9
    assert a.pick(np.array([1.0, 1.0, 1.0]), np.array([0.0, 0.0, -1.0])) is None  # beside the cloud
    assert a.pick(np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0])) is None  # the cloud behind


def test_round_trip_paint_save_load(tmp_path):
    a = Annotation(plane())
    i = centre_index(a.cloud)
    a.paint(i, 0.0051, "target", weight=1.5)
    a.paint(int(np.argmax(a.cloud.points[:, 0])), 0.004, "keep_out")
    path = write_marked_ply(a.cloud, a.target, a.keep_out, tmp_path / "marked.ply")
    read = read_cloud(path)
    assert np.allclose(read.cloud.points, a.cloud.points)
    assert np.array_equal(read.cloud.target, a.target)
    assert np.array_equal(read.keep_out, a.keep_out)
    assert read.cloud.spacing == pytest.approx(H)
    assert any("keep_out" in n for n in read.notes)
    # the loaders' keep-out: the file's zone alone, or merged with an option (said in a warning)
    assert np.array_equal(raw_keep_out(read.cloud, "", 1.0, "", read), a.keep_out)
    mask = np.zeros(len(a.cloud), dtype=bool)
    mask[0] = True
    np.save(tmp_path / "m.npy", mask)
    with pytest.warns(RuntimeWarning, match="merged with --keep-out-mask"):
        merged = raw_keep_out(read.cloud, "", 1.0, str(tmp_path / "m.npy"), read)
    assert np.array_equal(merged, a.keep_out | mask)
    # opening the marked file again starts from its marks
    from tactex.report.annotate_view import open_annotation

    again, notes = open_annotation(path)
    assert again.counts() == a.counts() and np.array_equal(again.keep_out, a.keep_out)
    assert any("keep_out" in n for n in notes)


def test_a_ply_without_keep_out_reads_as_before(tmp_path):
    path = save_ply(plane(), tmp_path / "plain.ply")
    read = read_cloud(path)
    assert read.keep_out is None and raw_keep_out(read.cloud, "", 1.0, "", read) is None


def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys):
    scan = save_ply(plane(), tmp_path / "scan.ply")
    cases = [
        (["annotate", str(tmp_path / "missing.ply"), "--out", str(tmp_path / "o.ply"), "--no-browser",
          "--port", "0"], "does not exist"),
        (["annotate", str(scan), "--out", str(scan), "--no-browser", "--port", "0"], "--force"),
        (["annotate", str(scan), "--out", str(tmp_path / "o.npz"), "--no-browser", "--port", "0"], ".ply"),
        # the page's Save would fail there, after the marks were painted: said before the page opens
        (["annotate", str(scan), "--out", str(tmp_path / "no_such_folder" / "o.ply"), "--no-browser", "--port", "0"],
         "does not exist (the page's Save could not write there"),
        (["annotate", str(scan), "--out", str(scan / "o.ply"), "--no-browser", "--port", "0"], "does not exist"),
    ]
    not_cloud = tmp_path / "notes.ply"
    not_cloud.write_text("this is not a point cloud\n")
    cases.append((["annotate", str(not_cloud), "--out", str(tmp_path / "o.ply"), "--no-browser", "--port", "0"],
                  "notes.ply"))
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        cases.append((["annotate", str(scan), "--out", str(tmp_path / "o.ply"), "--no-browser", "--port", str(port)],
                      "in use"))
        for argv, words in cases:
            assert main(argv) == 2, argv
            err = capsys.readouterr().err.strip().splitlines()
            assert len(err) == 1 and err[0].startswith("tactex annotate: error:") and words in err[0], (argv, err)


@pytest.mark.slow
def test_explore_takes_the_painted_target_and_keep_out(tmp_path):
    import json

    a = Annotation(plane(31))
    a.paint(centre_index(a.cloud), 0.008, "target")
    a.paint(int(np.argmax(a.cloud.points[:, 0])), 0.006, "keep_out")
    marked = write_marked_ply(a.cloud, a.target, a.keep_out, tmp_path / "marked.ply")
    assert main(["explore", str(marked), "--out", str(tmp_path / "run"), "--steps", "200",
                 "--voxel-size-m", "0"]) == 0
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    c = a.counts()
    assert (m["n_target"], m["keep_out_points"], m["keep_out_contacts"]) == (c.n_target, c.n_keep_out, 0)


def test_the_command_serves_the_page_until_ctrl_c(tmp_path):
    import os
    import re
    import signal
    import subprocess
    import sys
    import urllib.request

    a = Annotation(plane(11))
    a.paint(0, 0.003, "keep_out")
    scan = write_marked_ply(a.cloud, a.target, a.keep_out, tmp_path / "scan.ply")
    proc = subprocess.Popen([sys.executable, "-m", "tactex.cli", "annotate", str(scan), "--out",
                             str(tmp_path / "o.ply"), "--no-browser", "--port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        line = proc.stdout.readline()  # hang guard: the test's timeout
        url = re.search(r"open (http://127\.0\.0\.1:\d+/)", line)
        assert url and f"{a.counts().n_keep_out} keep-out already" in line, line
        with urllib.request.urlopen(url.group(1), timeout=60) as page:
            assert page.status == 200 and b"<html" in page.read(2000).lower()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=60) == 0, proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()
    assert not (tmp_path / "o.ply").exists()  # nothing saved without the Save button
