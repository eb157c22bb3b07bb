"""SurfaceCloud validation, voxel grid (Open3D semantics), I/O round trips, target from colour."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.errors import CloudError, ConfigError, InputError, UnitsError
from tactex.pointcloud import (
    SurfaceCloud,
    load_cloud,
    load_ply,
    mean_spacing,
    save_cloud,
    save_ply,
    target_from_channel,
    voxel_down_sample,
)
from tests.conftest import TEC_CLOUDS, tec_cloud_path

# Points after 3 mm voxels and target points, from the data README / TEC paper.
EXPECTED_VOXEL = {"bun270_X": (2996, 210), "cup_X": (1511, 162), "plate_shapes": (6228, 1216)}


def grid_cloud(n: int = 10, spacing: float = 0.01) -> SurfaceCloud:
    xs, ys = np.meshgrid(np.arange(n) * spacing, np.arange(n) * spacing)
    pts = np.stack([xs.ravel(), ys.ravel(), np.zeros(n * n)], axis=1)
    return SurfaceCloud(points=pts)


@pytest.mark.shared_data
@pytest.mark.parametrize("name", TEC_CLOUDS)
def test_voxel_grid_reproduces_paper_counts(name: str) -> None:
    cloud = load_ply(tec_cloud_path(name))
    down = target_from_channel(voxel_down_sample(cloud, 0.003), "red", 1.0)
    assert (len(down), down.n_target) == EXPECTED_VOXEL[name]
    assert down.spacing == 0.003


def test_voxel_averages_points_and_colours() -> None:
    pts = np.array([[0.0, 0.0, 0.0], [0.001, 0.0, 0.0], [0.05, 0.0, 0.0]])
    cols = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    with pytest.warns(RuntimeWarning, match="finer than the cloud's own mean spacing"):  # 2 points 5 cm apart
        out = voxel_down_sample(SurfaceCloud(points=pts, colors=cols), 0.01)
    assert len(out) == 2
    np.testing.assert_allclose(out.points[0], [0.0005, 0, 0])
    np.testing.assert_allclose(out.colors[0], [0.5, 0, 0.5])


def test_a_voxel_finer_than_the_cloud_keeps_the_clouds_own_spacing() -> None:
    """On a 5 mm grid a 3 mm voxel changes nothing: h stays 5 mm (it was set to 3 mm, and the agent,
    whose steps are in voxels, then could not step from point to point and never moved)."""
    with pytest.warns(RuntimeWarning, match="finer than the cloud's own mean spacing 5 mm"):
        fine = voxel_down_sample(grid_cloud(spacing=0.005), 0.003)
    assert len(fine) == 100 and fine.spacing == pytest.approx(0.005)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        coarse = voxel_down_sample(grid_cloud(spacing=0.005), 0.012)
    assert coarse.spacing == 0.012


def test_voxel_rejects_bad_size() -> None:
    with pytest.raises(ConfigError, match="voxel size"):
        voxel_down_sample(grid_cloud(), 0.0)


def test_empty_cloud_rejected() -> None:
    with pytest.raises(CloudError, match="empty"):
        SurfaceCloud(points=np.zeros((0, 3)))


def test_wrong_shape_rejected() -> None:
    with pytest.raises(CloudError, match=r"\(N, 3\)"):
        SurfaceCloud(points=np.zeros((5, 2)))


def test_nan_points_rejected_with_index() -> None:
    pts = grid_cloud().points.copy()
    pts[7, 1] = np.nan
    with pytest.raises(CloudError, match="index 7"):
        SurfaceCloud(points=pts)


def test_millimetre_cloud_refused(tmp_path) -> None:
    with pytest.raises(UnitsError, match="millimetres"):
        SurfaceCloud(points=grid_cloud().points * 1000.0)
    np.savez(tmp_path / "mm.npz", points=grid_cloud().points * 1000.0)
    with pytest.raises(UnitsError, match=r"mm\.npz'.*probably in millimetres: give units=mm"):
        load_cloud(tmp_path / "mm.npz")
    # points in metres with a stored spacing in millimetres: the spacing is named, not the points
    np.savez(tmp_path / "h.npz", points=grid_cloud().points, spacing=3.0)
    with pytest.raises(UnitsError, match=r"spacing = 3 m was given.*Give the spacing in metres"):
        load_cloud(tmp_path / "h.npz")


def test_duplicates_are_kept_until_removed() -> None:
    """A raw scan may repeat points: the cloud loads (h from the distinct points), deduplicated() or a
    voxel filter removes them, and the Laplacian refuses them with that advice (test_spectral). Before,
    SurfaceCloud refused them, so a raw scan could not even be loaded to be filtered."""
    pts = np.vstack([grid_cloud().points, grid_cloud().points[:3]])
    with pytest.raises(CloudError, match="coincide"):
        mean_spacing(pts)
    raw = SurfaceCloud(points=pts)
    assert len(raw) == 103 and raw.spacing == pytest.approx(0.01)
    assert len(raw.deduplicated()) == 100 and len(voxel_down_sample(raw, 0.009)) == 100


def test_the_cloud_owns_its_arrays_and_checks_their_types() -> None:
    pts = grid_cloud().points.copy()
    target = np.ones(len(pts))
    cloud = SurfaceCloud(points=pts, target=target)
    pts *= 1000.0  # the caller's arrays stay writable, and changing them changes nothing validated
    target[:] = -5.0
    assert np.ptp(cloud.points[:, 0]) == pytest.approx(0.09) and cloud.target.min() == 1.0
    with pytest.raises(ValueError):
        cloud.points[0, 0] = 1.0  # read-only
    for bad in ({"points": [[0.0, 0.0], [1.0]]}, {"points": "abc"}, {"spacing": None},
                {"target": ["a"] * 100}):
        with pytest.raises(CloudError):
            SurfaceCloud(**{"points": grid_cloud().points, **bad})
    with pytest.raises(CloudError, match="rotation matrix"):
        cloud.transformed(0.5 * np.eye(3), np.zeros(3))


def test_a_wide_camera_cloud_in_metres_is_not_taken_for_millimetres() -> None:
    """A depth frame reaching 3 m with a wide lens spans over 5 m, but its points lie mm apart."""
    u, v = np.meshgrid(np.linspace(-2.8, 2.8, 1200), np.linspace(-0.5, 0.5, 200))
    cam = np.c_[u.ravel(), v.ravel(), np.full(u.size, 3.0)]
    assert len(SurfaceCloud(points=cam)) == 240000
    with pytest.raises(UnitsError, match="millimetres"):
        SurfaceCloud(points=grid_cloud().points * 1000.0)  # 10 mm grid read as 10 "m" apart
    with pytest.raises(UnitsError, match=r"0\.3 m apart.*millimetres"):
        SurfaceCloud(points=grid_cloud(n=14).points * 30.0)  # a 4 mm part in mm: 3.9 "m" wide, 0.3 "m" apart


def test_negative_target_and_bad_colours_rejected() -> None:
    c = grid_cloud()
    with pytest.raises(CloudError, match="≥ 0"):
        c.with_target(-np.ones(len(c)))
    with pytest.raises(CloudError, match="255"):
        SurfaceCloud(points=c.points, colors=np.full((len(c), 3), 200.0))


def test_spacing_is_nearest_neighbour_mean() -> None:
    assert grid_cloud(spacing=0.004).spacing == pytest.approx(0.004)


def test_target_from_channel_marks_exactly_the_painted_points() -> None:
    c = grid_cloud()
    cols = np.full((len(c), 3), 0.3)
    painted = np.array([3, 14, 15, 92])
    cols[painted, 0] = 1.0
    out = target_from_channel(SurfaceCloud(points=c.points, colors=cols), "red", 1.0)
    np.testing.assert_array_equal(np.flatnonzero(out.target), painted)
    with pytest.raises(ConfigError, match="valid: red, green, blue"):
        target_from_channel(SurfaceCloud(points=c.points, colors=cols), "alpha")
    with pytest.raises(InputError, match="no colours"):
        target_from_channel(c)


@pytest.mark.parametrize("suffix", [".ply", ".npz"])
def test_round_trip(tmp_path, suffix: str) -> None:
    c = grid_cloud()
    rng = np.random.default_rng(0)
    cols = np.round(rng.uniform(0, 1, (len(c), 3)) * 255) / 255
    normals = np.tile([0.0, 0.0, 1.0], (len(c), 1))
    src = SurfaceCloud(points=c.points, colors=cols, normals=normals, target=rng.uniform(0, 1, len(c)))
    back = load_cloud(save_cloud(src, tmp_path / f"c{suffix}"))
    np.testing.assert_allclose(back.points, src.points)
    np.testing.assert_allclose(back.colors, src.colors, atol=1e-9)
    np.testing.assert_allclose(back.normals, src.normals)
    np.testing.assert_allclose(back.target, src.target)
    # the spacing h travels too (a PLY recomputed it: 0.003 came back as 0.00195 for the voxelised bunny)
    coarse = SurfaceCloud(points=c.points, spacing=0.013)
    assert load_cloud(save_cloud(coarse, tmp_path / f"h{suffix}")).spacing == 0.013


def _pcd(path, fields: str, types: str, rows, data: str = "ascii") -> None:
    n = len(rows)
    head = (f"# .PCD v0.7\nVERSION 0.7\nFIELDS {fields}\nSIZE {' '.join('4' for _ in types.split())}\n"
            f"TYPE {types}\nCOUNT {' '.join('1' for _ in types.split())}\nWIDTH {n}\nHEIGHT 1\n"
            f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n")
    path.write_text(head + "\n".join(" ".join(str(v) for v in r) for r in rows) + "\n")


def test_pcd_colours_as_pcl_writes_them(tmp_path) -> None:
    """PCL's ascii writer prints the float rgb field as its uint32 integer, and some files declare rgb
    as U 4: both came back wrong (red 255 as 127, so the target mark was lost)."""
    want = [[255, 0, 0], [0, 200, 10], [12, 34, 56]]
    packed = [(r << 16) | (g << 8) | b for r, g, b in want]
    rows = [(0.01 * i, 0.02, 0.03, p) for i, p in enumerate(packed, start=1)]
    for types in ("F F F F", "F F F U"):
        _pcd(tmp_path / "c.pcd", "x y z rgb", types, rows)
        back = load_cloud(tmp_path / "c.pcd")
        np.testing.assert_array_equal(np.round(back.colors * 255).astype(int), want)
    # writers that bit-cast the float (Open3D, struct.pack) print tiny numbers; 9 digits keep the bits
    cast = np.array(packed, dtype=np.uint32).view(np.float32)
    rows = [(0.01 * i, 0.02, 0.03, np.format_float_scientific(f, precision=8)) for i, f in enumerate(cast, start=1)]
    _pcd(tmp_path / "b.pcd", "x y z rgb", "F F F F", rows)
    np.testing.assert_array_equal(np.round(load_cloud(tmp_path / "b.pcd").colors * 255).astype(int), want)
    rows[0] = (0.01, 0.02, 0.03, 0)  # a black point among bit-cast ones
    _pcd(tmp_path / "b.pcd", "x y z rgb", "F F F F", rows)
    back = np.round(load_cloud(tmp_path / "b.pcd").colors * 255).astype(int)
    np.testing.assert_array_equal(back, [[0, 0, 0], *want[1:]])
    rows[0] = (0.01, 0.02, 0.03, 0.5)  # a fraction is neither convention
    _pcd(tmp_path / "b.pcd", "x y z rgb", "F F F F", rows)
    with pytest.raises(CloudError, match=r"b\.pcd': its rgb .* neither PCL's packed integer nor a bit-cast float"):
        load_cloud(tmp_path / "b.pcd")
    _pcd(tmp_path / "s.pcd", "x y z r g b", "F F F U U U", [(0.01 * i, 0.02, 0.03, *c) for i, c in enumerate(want, 1)])
    np.testing.assert_array_equal(np.round(load_cloud(tmp_path / "s.pcd").colors * 255).astype(int), want)


def test_colour_scales(tmp_path) -> None:
    from plyfile import PlyData, PlyElement

    pts = grid_cloud().points
    fields = [("x", "f8"), ("y", "f8"), ("z", "f8"), ("red", "u2"), ("green", "u2"), ("blue", "u2")]
    d = np.empty(len(pts), dtype=fields)
    d["x"], d["y"], d["z"] = pts.T
    d["red"], d["green"], d["blue"] = 65535, 0, 32768  # 16-bit colours
    PlyData([PlyElement.describe(d, "vertex")]).write(str(tmp_path / "u16.ply"))
    np.testing.assert_allclose(load_cloud(tmp_path / "u16.ply").colors[0], [1.0, 0.0, 32768 / 65535])
    cols = np.zeros((len(pts), 3), np.float32)
    cols[:50, 0] = 1.0
    cols[0, 0] = np.float32(1.0000001)  # float32 round-off of a 0..1 colour pipeline
    np.savez(tmp_path / "f.npz", points=pts, colors=cols)
    assert target_from_channel(load_cloud(tmp_path / "f.npz")).n_target == 50  # not all divided by 255


def test_save_and_load_refuse_ambiguous_data(tmp_path) -> None:
    c = grid_cloud()
    with pytest.raises(InputError, match="clashes"):
        save_ply(c, tmp_path / "x.ply", extra={"target": np.ones(len(c))})
    np.savez(tmp_path / "s.npz", points=c.points, spacing=np.array([0.01, 0.02]))
    with pytest.raises(CloudError, match="'spacing' must be one number"):
        load_cloud(tmp_path / "s.npz")


def test_pcd_reader(tmp_path) -> None:
    pts = grid_cloud().points.astype(np.float32)
    header = (
        "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
        f"WIDTH {len(pts)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(pts)}\nDATA ascii\n"
    )
    body = "\n".join(" ".join(f"{v:.6f}" for v in p) for p in pts)
    path = tmp_path / "c.pcd"
    path.write_text(header + body + "\n")
    back = load_cloud(path)
    np.testing.assert_allclose(back.points, pts, atol=1e-6)


def test_unknown_suffix_and_missing_file() -> None:
    with pytest.raises(InputError, match="supported"):
        load_cloud("cloud.xyz")
    with pytest.raises(InputError, match="does not exist"):
        load_cloud("/nonexistent/cloud.ply")


def test_negative_or_nan_spacing_refused() -> None:
    pts = grid_cloud().points
    for bad in (-0.003, float("nan")):
        with pytest.raises(CloudError, match="spacing"):
            SurfaceCloud(points=pts, spacing=bad)
