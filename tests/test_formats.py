"""Public formats on small fixtures we write ourselves (tests/format_fixtures.py): PCD of PCL's
versions .5/.6/.7 in every encoding, meshes (PLY with faces, STL, OBJ), NaN points, and a
camera-like cloud where only the red marker — not the white table or the beige board — is target."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from tactex.errors import CloudError, UnitsError
from tactex.experiments.explore import ExploreConfig, load_explore_cloud
from tactex.pointcloud import SurfaceCloud, load_cloud, save_npz, save_ply
from tactex.pointcloud.io import read_cloud
from tactex.pointcloud.mesh import MAX_MESH_POINTS
from tactex.pointcloud.target import TargetRule, color_mask, file_target, target_from_channel
from tests.format_fixtures import (
    PCD_ENCODINGS,
    PCD_VERSIONS,
    box_mesh,
    bumpy_patch,
    camera_like_cloud,
    write_pcd,
)

H = 0.003


@pytest.mark.parametrize("version", PCD_VERSIONS)
@pytest.mark.parametrize("encoding", PCD_ENCODINGS)
def test_pcd_every_version_and_encoding(tmp_path, version: str, encoding: str) -> None:
    pts = bumpy_patch()
    rgb = np.zeros((len(pts), 3), dtype=np.uint8)
    rgb[::3] = (255, 0, 0)
    rgb[1::3] = (12, 200, 99)
    path = write_pcd(tmp_path / f"c{version}.pcd", pts, version, encoding, rgb)
    cloud = load_cloud(path)
    np.testing.assert_allclose(cloud.points, pts.astype(np.float32), atol=1e-7)
    np.testing.assert_allclose(cloud.colors * 255.0, rgb, atol=1e-9)


def test_pcd_v05_like_pcl_bunny_without_colours(tmp_path) -> None:
    """PCL's test/bunny.pcd is a VERSION .5 ascii file of x y z only: refused before."""
    pts = bumpy_patch(n_side=12)
    path = write_pcd(tmp_path / "bunny.pcd", pts, ".5", "ascii")
    assert path.read_text().splitlines()[1] == "VERSION .5"
    cloud = load_cloud(path)
    assert len(cloud) == 144 and cloud.colors is None


@pytest.mark.parametrize(
    ("header", "needle"),
    [
        ("VERSION .9\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 1\nDATA ascii\n", "VERSION .9"),
        ("VERSION .7\nFIELDS x y z\nSIZE 4 4\nTYPE F F F\nPOINTS 1\nDATA ascii\n", "3 FIELDS but 2 SIZE"),
        ("VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F Q\nPOINTS 1\nDATA ascii\n", "TYPE Q"),
        ("VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS -3\nDATA ascii\n", "must not be negative"),
        ("VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 1\nDATA zip\n", "DATA is 'zip'"),
        ("VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 9\nDATA binary\n\0\0\0", "truncated"),
        ("VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 1\nSPEED 4\nDATA ascii\n", "unknown line"),
        ("hello, not a cloud\n", "no header ending in a DATA line"),
    ],
)
def test_bad_pcd_headers_are_one_sentence(tmp_path, header: str, needle: str) -> None:
    path = tmp_path / "bad.pcd"
    path.write_bytes(header.encode("ascii") + b"1 2 3\n")
    with pytest.raises(CloudError) as err:
        read_cloud(path)
    message = str(err.value)
    assert needle in message and "\n" not in message
    assert "pydantic" not in message and "http" not in message and "validation error" not in message


def test_a_text_file_named_npz_is_answered_plainly(tmp_path) -> None:
    path = tmp_path / "x.npz"
    path.write_text("hello")
    with pytest.raises(CloudError, match=r"is not an \.npz file") as err:
        read_cloud(path)
    assert "pickle" not in str(err.value)
    objects = tmp_path / "objects.npz"
    np.savez(objects, points=np.array([{"a": 1}], dtype=object))
    with pytest.raises(CloudError, match="Python objects") as err:
        read_cloud(objects)
    assert "allow_pickle" not in str(err.value)


def _with_nan(n: int = 200, bad: int = 9) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    pts = rng.random((n, 3)) * 0.05
    rows = rng.choice(n, bad, replace=False)
    pts[rows[: bad // 2]] = np.nan
    pts[rows[bad // 2 :], 1] = np.inf
    return pts, rows


@pytest.mark.parametrize("suffix", [".ply", ".pcd", ".npz"])
def test_one_nan_rule_for_every_format(tmp_path, suffix: str) -> None:
    """NaN/inf points are dropped and counted in every format (PLY refused them, PCD hid them)."""
    pts, rows = _with_nan()
    path = tmp_path / f"c{suffix}"
    if suffix == ".ply":
        from plyfile import PlyData, PlyElement

        data = np.empty(len(pts), dtype=[("x", "f8"), ("y", "f8"), ("z", "f8")])
        data["x"], data["y"], data["z"] = pts.T
        PlyData([PlyElement.describe(data, "vertex")]).write(str(path))
    elif suffix == ".pcd":
        write_pcd(path, pts, ".7", "binary")
    else:
        np.savez(path, points=pts)
    read = read_cloud(path)
    assert read.n_dropped == len(rows) and len(read.cloud) == len(pts) - len(rows)
    assert read.notes == (f"dropped {len(rows)} of {len(pts)} points with NaN/inf coordinates or normals",)
    keep = np.setdiff1d(np.arange(len(pts)), rows)
    np.testing.assert_allclose(read.cloud.points, pts[keep].astype(np.float32 if suffix == ".pcd" else float))


def test_nan_normals_drop_their_points_too(tmp_path) -> None:
    pts = bumpy_patch()
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    normals[5] = np.nan
    np.savez(tmp_path / "n.npz", points=pts, normals=normals)
    read = read_cloud(tmp_path / "n.npz")
    assert read.n_dropped == 1 and np.isfinite(read.cloud.normals).all()


@pytest.mark.parametrize("suffix", [".ply", ".stl", ".obj"])
def test_meshes_are_sampled_at_the_voxel_spacing(tmp_path, suffix: str) -> None:
    """A box mesh is 8 vertices; its cloud must cover all six faces one point per voxel."""
    edge = 0.08
    path = tmp_path / f"box{suffix}"
    box_mesh(edge).export(str(path))
    read = read_cloud(path, mesh_spacing_m=H)
    cloud = read.cloud
    assert read.n_faces == 12 and "a mesh of 12 faces" in read.notes[0]
    # Every point lies on the box surface (some coordinate at ±edge/2, all within it) ...
    on_face = np.isclose(np.abs(cloud.points), edge / 2, atol=1e-9).any(axis=1)
    assert on_face.all() and (np.abs(cloud.points) <= edge / 2 + 1e-9).all()
    # ... about one per voxel of surface (6 faces of (edge/H)² cells; voxels cut across edges) ...
    cells = 6 * (edge / H) ** 2
    assert 0.9 * cells < len(cloud) < 1.5 * cells
    # ... and no spot of the surface is farther than a voxel diagonal from a point.
    import trimesh

    probe, _ = trimesh.sample.sample_surface(box_mesh(edge), 20000, seed=7)
    gap = cKDTree(cloud.points).query(probe)[0].max()
    assert gap < np.sqrt(3) * H
    assert cloud.normals is not None and np.allclose(np.linalg.norm(cloud.normals, axis=1), 1.0)


def test_a_coloured_ply_mesh_keeps_its_colours_and_marking(tmp_path) -> None:
    path = tmp_path / "box.ply"
    box_mesh(0.06, colored=True).export(str(path))
    cloud, info = load_explore_cloud(path, ExploreConfig(voxel_size_m=H))
    top = cloud.points[:, 2] > 0.03 - 1e-9
    assert cloud.n_target > 0 and (cloud.target[top] > 0).all()  # the top face is all red
    assert (cloud.target[cloud.points[:, 2] < -0.01] == 0).all()  # the lower half is white
    assert info["n_mesh_faces"] == 12


def test_a_two_metre_mesh_is_metres_not_millimetres(tmp_path) -> None:
    """PCL's 2 m cube.ply was 24 vertices called millimetres; now it is a 2 m surface, sampled when
    the spacing allows, and refused with the voxel size that would work when it does not."""
    path = tmp_path / "cube.ply"
    box_mesh(2.0).export(str(path))
    with pytest.raises(CloudError) as err:
        read_cloud(path, mesh_spacing_m=H)
    message = str(err.value)
    assert "millimetre" not in message and f"{MAX_MESH_POINTS:,}" in message and "voxel_size_m=0.011" in message
    cloud = read_cloud(path, mesh_spacing_m=0.02).cloud
    assert np.ptp(cloud.points, axis=0) == pytest.approx([2.0, 2.0, 2.0], abs=0.02)
    mm = tmp_path / "part_mm.stl"
    box_mesh(200.0).export(str(mm))
    with pytest.raises(UnitsError, match="millimetres"):
        read_cloud(mm)


# --- colour targets ------------------------------------------------------------------------------


def test_hue_marks_red_not_white_or_beige() -> None:
    colors = np.array([[1, 1, 1], [0.93, 0.93, 0.9], [0.87, 0.78, 0.63], [1, 0, 0], [0.75, 0.16, 0.19],
                       [0.05, 0.0, 0.0], [0.9, 0.55, 0.1], [0.9, 0.1, 0.5]])
    assert color_mask(colors, "red").tolist() == [False, False, False, True, True, False, False, False]
    # TEC's raw rule calls white and beige red at a camera's level
    pts = 0.01 * np.random.default_rng(0).random((8, 3))
    raw = target_from_channel(SurfaceCloud(points=pts, colors=colors), "red", 0.85)
    assert raw.target.tolist() == [1, 1, 1, 1, 0, 0, 1, 1]


def test_camera_like_cloud_only_the_red_marker_is_target(tmp_path) -> None:
    pts, rgb, red = camera_like_cloud()
    path = write_pcd(tmp_path / "table.pcd", pts, ".7", "binary", rgb)
    read = read_cloud(path)
    assert read.n_dropped == 25
    finite = np.isfinite(pts).all(axis=1)
    cloud, words = file_target(read.cloud, H, TargetRule(), str(path))
    assert "hue" in words
    marked = cloud.points[cloud.target > 0]
    # every marked voxel lies on the red stroke (|y - 0.1| < 4 mm, plus half a voxel)...
    assert np.abs(marked[:, 1] - 0.1).max() < 0.004 + H
    # ... and the stroke is found along its whole length, over the board and the table alike
    assert marked[:, 0].min() < 0.01 and marked[:, 0].max() > 0.19
    stroke_voxels = len(np.unique(np.floor(pts[finite & red, :2] / H), axis=0))
    assert 0.5 * stroke_voxels < len(marked) <= stroke_voxels
    # TEC's raw red ≥ 0.9 marks the white table instead: the reason for the hue rule
    raw, _ = file_target(read.cloud, H, TargetRule("red", threshold=0.9), str(path))
    white_table = (raw.points[:, 0] > 0.1) & (np.abs(raw.points[:, 1] - 0.1) > 0.01)
    assert raw.target[white_table].mean() > 0.9


def test_tec_red_is_marked_as_tec_marks_it() -> None:
    """On the TEC clouds (pure red on black) the hue rule and TEC's red ≥ 1.0 mark the same voxels."""
    from tactex.pointcloud import load_ply, voxel_down_sample
    from tests.conftest import tec_cloud_path

    for name in ("cup_X", "plate_shapes", "bun270_X"):
        raw = load_ply(tec_cloud_path(name))
        by_hue, _ = file_target(raw, H, TargetRule(), name)
        tec = target_from_channel(voxel_down_sample(raw, H), "red", 1.0)
        assert np.array_equal(by_hue.target > 0, tec.target > 0), name


def test_stored_and_all_targets(tmp_path) -> None:
    pts = bumpy_patch()
    target = (pts[:, 0] > 0.03).astype(float)
    save_npz(SurfaceCloud(points=pts, target=target), tmp_path / "t.npz")
    cloud, words = file_target(read_cloud(tmp_path / "t.npz").cloud, 0.0, TargetRule("stored"), "t")
    assert words == "the target stored in the file" and cloud.n_target == int(target.sum())
    path = save_ply(SurfaceCloud(points=pts), tmp_path / "plain.ply")
    cloud, words = file_target(read_cloud(path).cloud, 0.0, TargetRule("ALL"), "plain")
    assert cloud.n_target == len(pts) and words == "the whole surface"


def test_auto_takes_a_stored_target_before_colours(tmp_path) -> None:
    """A cloud tactex wrote (colours and a target array) keeps its target under --target auto, as
    `tactex clean --cloud` always did; without a stored target, auto is red by hue."""
    pts = bumpy_patch()
    target = (pts[:, 0] > 0.03).astype(float)
    grey = np.full((len(pts), 3), 0.6)
    path = save_ply(SurfaceCloud(points=pts, colors=grey, target=target), tmp_path / "written.ply")
    cloud, words = file_target(read_cloud(path).cloud, 0.0, TargetRule(), "written")
    assert words == "the target stored in the file" and cloud.n_target == int(target.sum())
    red = grey.copy()
    red[:40] = (0.9, 0.1, 0.1)
    path = save_ply(SurfaceCloud(points=pts, colors=red), tmp_path / "marked.ply")
    cloud, words = file_target(read_cloud(path).cloud, 0.0, TargetRule("AUTO"), "marked")
    assert "red by hue" in words and cloud.n_target == 40
