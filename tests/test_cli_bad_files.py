"""The damaged files of issue 33 through the CLI: each is one line on stderr, exit code 2, no
traceback, and names the file (a PLY whose vertex count was multiplied or set to -1, an NPZ whose
points are strings, an ascii PCD with fewer rows than its POINTS), and a PLY naming a texture that
is not there is read with its vertex colours, saying so, without trimesh's tracebacks."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.cli import main
from tactex.pointcloud.io import read_cloud
from tests.format_fixtures import pcd_bytes

FORBIDDEN = ("Traceback", "allow_pickle", "numpy", "Error:", "File \"", ".py", "GiB")


def _run(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code)


def _one_line(capsys, code: int, command: str, path, *needles: str) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2, err
    assert len(lines) == 1, err
    line = lines[0]
    assert line.startswith(f"tactex {command}: error: "), line
    assert f"'{path}'" in line, line
    for word in FORBIDDEN:
        assert word not in line, line
    for needle in needles:
        assert needle in line, line
    return line


def _ascii_ply(n: int, rows: int | None = None, rgb: str = "200 30 40") -> bytes:
    points = np.random.default_rng(0).random((n, 3)) * 0.05
    head = (f"ply\nformat ascii 1.0\nelement vertex {n if rows is None else rows}\nproperty float x\n"
            "property float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
            "end_header\n")
    return (head + "".join(f"{x:.5f} {y:.5f} {z:.5f} {rgb}\n" for x, y, z in points)).encode()


def _explore(path, tmp_path) -> list[str]:
    return ["explore", str(path), "--quiet", "--out", str(tmp_path / "run")]


def test_ply_vertex_count_multiplied(tmp_path, capsys) -> None:
    # numpy asked for 67.1 GiB for the rows the header announced, before reading one
    path = tmp_path / "multiplied.ply"
    path.write_bytes(_ascii_ply(40, rows=40 * 10**9))
    _one_line(capsys, _run(_explore(path, tmp_path)), "explore", path, "40000000000 vertex rows", "holds 40")


@pytest.mark.parametrize("edit", [("element vertex 40", "element vertex -1"), ("200 30 40\n", "-1 30 40\n")])
def test_ply_edited_to_minus_one(tmp_path, capsys, edit) -> None:
    # the count: numpy's "negative dimensions"; a colour: OverflowError out of bounds for uint8
    path = tmp_path / "minus_one.ply"
    path.write_bytes(_ascii_ply(40).decode().replace(*edit, 1).encode())
    line = _one_line(capsys, _run(_explore(path, tmp_path)), "explore", path, "not a readable PLY file")
    assert "negative count (-1)" in line or "does not fit its property's type (-1 out of bounds for uint8)" in line


@pytest.mark.parametrize("command", ["explore", "clean"])
def test_npz_points_hold_strings(tmp_path, capsys, command) -> None:
    path = tmp_path / "strings.npz"
    np.savez(path, points=np.array([["0.1", "0.2", "x"]] * 10))
    argv = _explore(path, tmp_path) if command == "explore" else ["clean", "--cloud", str(path), "--quiet", "--out",
                                                                   str(tmp_path / "run")]
    _one_line(capsys, _run(argv), command, path, "'points' array holds text", "real numbers")


def test_ascii_pcd_shorter_than_its_points(tmp_path, capsys) -> None:
    # it loaded 397 points without a word
    path = tmp_path / "short.pcd"
    data = pcd_bytes(np.random.default_rng(0).random((397, 3)) * 0.05, ".7", "ascii")
    path.write_bytes(data.replace(b"POINTS 397", b"POINTS 5000").replace(b"WIDTH 397", b"WIDTH 5000"))
    _one_line(capsys, _run(_explore(path, tmp_path)), "explore", path, "announces 5000 points", "has 397 rows")


def _textured_ply(path, rgb: tuple[int, int, int]):
    """A tetrahedron with vertex colours ``rgb``, per-face texture coordinates and a texture file
    named in its header that does not exist."""
    v = np.array([[0, 0, 0], [0.05, 0, 0], [0, 0.05, 0], [0, 0, 0.05]])
    faces = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]
    lines = ["ply", "format ascii 1.0", "comment TextureFile missing.png", "element vertex 4",
             *(f"property float {a}" for a in "xyz"), *(f"property uchar {c}" for c in ("red", "green", "blue")),
             "element face 4", "property list uchar int vertex_indices", "property list uchar float texcoord",
             "end_header", *(" ".join(map(str, [*p, *rgb])) for p in v),
             *("3 " + " ".join(map(str, f)) + " 6 0 0 1 0 0 1" for f in faces)]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_ply_missing_texture_falls_back_to_vertex_colours(tmp_path, capsys) -> None:
    # trimesh printed two tracebacks, then the file "carried no target (no colours...)"
    got = read_cloud(_textured_ply(tmp_path / "red.ply", (200, 30, 40)))
    assert got.cloud.colors is not None
    np.testing.assert_allclose(got.cloud.colors, np.tile([200, 30, 40], (len(got.cloud), 1)) / 255.0, atol=1e-6)
    assert "its texture 'missing.png' could not be loaded: using its vertex colours" in got.notes
    assert capsys.readouterr().err == ""
    # through the CLI: white vertex colours, so the colours are read and hold no red: one line, no traceback
    path = _textured_ply(tmp_path / "white.ply", (240, 240, 240))
    line = _one_line(capsys, _run(_explore(path, tmp_path)), "explore", path, "no point of")
    assert "no colours" not in line
