"""A user's part as a simulated object (tactex.sim.part): its height field follows the mesh, overhangs and
parts out of reach are refused in one line, its red faces become the simulation's dirt where they are, its
units are read, and `tactex clean --object PART.stl` runs on it (and `tactex twin --object PART.stl`
serves it)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import trimesh

from tactex.cli import main
from tactex.errors import ConfigError, InputError, UnitsError
from tactex.sim.part import HFIELD_TOLERANCE_M, MAX_LOST_SHARE, load_part, part_info
from tactex.sim.part_raster import raster_mesh
from tactex.sim.scene import SceneConfig, build_scene
from tests.part_meshes import dome_height, dome_mesh, lip_mesh, patch_colors, write_color_stl

PATCH_XY, PATCH_R = (0.02, -0.01), 0.05


@pytest.fixture(scope="module")
def dome_stl(tmp_path_factory):
    mesh = dome_mesh()
    return write_color_stl(tmp_path_factory.mktemp("part") / "dome.stl", mesh, patch_colors(mesh, PATCH_XY, PATCH_R))


def _one_line(capsys, code: int, *words: str) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


def test_the_height_field_follows_the_mesh_within_a_millimetre(dome_stl):
    obj = load_part(dome_stl)
    info = part_info(obj)
    assert info.size_m == pytest.approx((0.2, 0.2, 0.04), abs=1e-4)
    assert info.lost_share == 0.0 and info.hfield_error_m <= HFIELD_TOLERANCE_M
    assert obj.kind == "hfield" and 0.002 <= obj.hfield_spacing_m <= 0.01
    # MuJoCo's grid (in the part frame raised by the solid under the whole-square part: lift_m)
    xs, ys, z = obj.heightfield()
    gx, gy = np.meshgrid(xs, ys)
    assert np.abs(z + obj.lift_m - dome_height(gx, gy)).max() < 1e-3
    # and between its nodes, where the pad presses: the mesh's own facets are 3.3 mm apart
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-0.099, 0.099, (2, 2000))
    assert np.abs(obj.surface.height(x, y) + obj.lift_m - dome_height(x, y)).max() < 1e-3


def test_a_box_raster_equals_the_box_and_its_outline_drops_to_the_table():
    box = trimesh.creation.box((0.1, 0.06, 0.03))
    box.apply_translation((0, 0, 0.015))
    r = raster_mesh(box.vertices, box.faces, 0.002)
    assert r.footprint.all() and np.allclose(r.z, 0.03) and r.lost_share == 0.0
    # a ring in a larger bounding square: off its footprint the height is the table's
    ring = trimesh.creation.annulus(0.03, 0.05, 0.01)
    ring.apply_translation((0, 0, 0.005))
    r = raster_mesh(ring.vertices, ring.faces, 0.002)
    gx, gy = np.meshgrid(r.xs, r.ys)
    rad = np.hypot(gx, gy)
    assert not r.footprint[rad < 0.029].any() and r.footprint[(rad > 0.031) & (rad < 0.049)].all()
    assert np.allclose(r.z[rad < 0.029], 0.0) and np.allclose(r.z[(rad > 0.031) & (rad < 0.049)], 0.01)


def test_an_overhang_is_measured_and_refused(tmp_path):
    mesh = lip_mesh()
    # the shelf (12 × 12 cm) hides the slab's 144 cm² under it and its post's top, 4 cm², out of the upward area
    # 400 + 144 + 4 cm²
    hidden = (0.12**2 + 0.02**2) / (0.2**2 + 0.12**2 + 0.02**2)
    for spacing in (0.001, 0.002):
        r = raster_mesh(mesh.vertices - [0, 0, mesh.bounds[0, 2]], mesh.faces, spacing)
        assert r.lost_share == pytest.approx(hidden, abs=0.01)
    path = tmp_path / "lip.stl"
    mesh.export(path)
    with pytest.raises(ConfigError, match=r"lies under a higher one") as exc:
        load_part(path)
    said = float(re.search(r"([0-9.]+)% of its upward surface", str(exc.value)).group(1)) / 100
    assert said == pytest.approx(hidden, abs=0.01) and f"at most {MAX_LOST_SHARE:.0%}" in str(exc.value)
    assert "\n" not in str(exc.value)


def test_a_part_beyond_the_reach_is_refused_in_one_line(tmp_path):
    slab = trimesh.creation.box((0.4, 0.6, 0.02))  # a door's size: at 0.5 m its corners are 0.76 m out
    path = tmp_path / "slab.stl"
    slab.export(path)
    SceneConfig(object_name=str(path))
    with pytest.raises(ConfigError, match=r"beyond the arm's reach") as exc:
        SceneConfig(object_name=str(path), object_position=(0.6, 0.0, 0.0))  # its far corners 0.85 m out
    assert "\n" not in str(exc.value) and "0.40–0.85 m" in str(exc.value)
    with pytest.raises(ConfigError, match=r"beyond the arm's reach"):
        SceneConfig(object_name=str(path), object_position=(0.4, 0.0, 0.0))  # its near edge over the robot's base
    huge = trimesh.creation.box((1.8, 0.5, 0.02))
    huge.export(tmp_path / "huge.stl")
    with pytest.raises(ConfigError, match=r"too big for the arm's reach"):
        load_part(tmp_path / "huge.stl")


def test_units_of_a_millimetre_file(tmp_path, dome_stl):
    mesh = dome_mesh()
    mm = write_color_stl(tmp_path / "dome_mm.stl", mesh, patch_colors(mesh, PATCH_XY, PATCH_R), scale=1000.0)
    with pytest.raises(UnitsError, match="units=mm"):
        load_part(mm)
    a, b = load_part(mm, "mm"), load_part(dome_stl)
    assert np.allclose(a.heightfield()[2], b.heightfield()[2], atol=1e-6)
    assert part_info(a).units == "mm"
    assert part_info(a).target_share == pytest.approx(part_info(b).target_share, rel=0.01)


def test_the_red_faces_are_the_dirt_where_they_are(dome_stl):
    scene = build_scene(SceneConfig(object_name=str(dome_stl)))
    dirt = scene.dirt
    pts = dirt.points  # cell centres in the part frame [m]
    d = np.hypot(pts[:, 0] - PATCH_XY[0], pts[:, 1] - PATCH_XY[1])
    dirty = dirt.initial > 0
    assert dirty[d < PATCH_R - 0.004].all()
    assert not dirty[d > PATCH_R + 0.004].any()
    assert dirty.mean() == pytest.approx(np.pi * PATCH_R**2 / 0.04, rel=0.05)
    # the object stands on the table at the default place, its surface where the mesh has it
    pos, rot = scene.config.object_pose()
    assert np.allclose(pos, (0.5, 0.0, scene.sim_object.lift_m)) and np.allclose(rot, np.eye(3))


def test_a_scan_given_as_cloud_and_object_is_simulated_where_it_lies(tmp_path):
    """A scan in the robot base frame (its top surface, red where the dirt is), given as --cloud and --object:
    the part stands where the scan has it, so the cloud's target lies on the simulated surface."""
    from tactex.pointcloud import SurfaceCloud
    from tactex.pointcloud.io import save_ply
    from tactex.tasks.clean import CleanConfig

    xs = np.arange(-0.1, 0.1 + 1e-9, 0.003)
    gx, gy = (g.ravel() for g in np.meshgrid(xs, xs))
    red = np.hypot(gx - PATCH_XY[0], gy - PATCH_XY[1]) <= PATCH_R
    where = np.array([0.45, 0.05, 0.0])
    pts = np.column_stack([gx, gy, dome_height(gx, gy)]) + where
    colors = np.where(red[:, None], [1.0, 0.0, 0.0], [0.8, 0.8, 0.8])
    scan = save_ply(SurfaceCloud(points=pts, colors=colors, spacing=0.003), tmp_path / "scan.ply")
    cfg = CleanConfig(object_name=str(scan), cloud=str(scan))
    lo, hi = pts.min(axis=0), pts.max(axis=0)  # the part frame: its bounding box's centre, its lowest point
    assert np.allclose(cfg.object_position, [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]], atol=1e-6)
    scene = build_scene(cfg.scene())
    pos, rot = scene.config.object_pose()
    local = (pts - pos) @ rot
    assert np.abs(scene.sim_object.surface.height(local[:, 0], local[:, 1]) - local[:, 2]).max() < 1.5e-3
    assert scene.dirt.paint(local[red], 0.003 * np.sqrt(0.5)) > 0.9 * red.sum() * (0.003 / 0.002) ** 2


def test_a_part_without_a_marking_takes_a_named_one(tmp_path, capsys):
    plain = tmp_path / "plain.stl"
    dome_mesh().export(plain)
    code = main(["clean", "--object", str(plain), "--quiet", "--no-video", "--out", str(tmp_path / "a")])
    _one_line(capsys, code, "marks no dirt", "--marking")
    scene = build_scene(SceneConfig(object_name=str(plain), marking="blobs"))
    assert scene.dirt.total_initial > 100


@pytest.mark.parametrize(("argv", "words"), [
    (["--object", "missing.stl"], ("'missing.stl' is not a file",)),
    (["--units", "mm"], ("--cloud or --object FILE",)),
    (["--object", "{dome}", "--units", "ft"], ("units='ft'",)),
    (["--object", "{dome}", "--object-position", "0.9", "0", "0"], ("beyond the arm's reach",)),
    (["--object", "{lip}"], ("under a higher one",)),
    (["--object", "{flat}"], ("rises 0 mm above its lowest point", "cannot tell so flat a part from the table")),
    (["--object", "plate", "--object-position", "5", "0", "0"],
     ("--object plate at [5.0, 0.0, 0.0] m stands 5.00 m from the robot's base axis", "--object-position")),
])
def test_clean_bad_part_input_is_one_line_and_exit_2(tmp_path, capsys, dome_stl, argv, words):
    lip = tmp_path / "lip.stl"
    lip_mesh().export(lip)
    g = np.linspace(-0.1, 0.1, 41)  # a scan of a flat face: no thickness
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    np.savez(tmp_path / "flat.npz", points=np.column_stack([x, y, np.zeros(x.size)]),
             target=(np.hypot(x, y) < 0.05).astype(float))
    argv = [a.format(dome=dome_stl, lip=lip, flat=tmp_path / "flat.npz") for a in argv]
    code = main(["clean", *argv, "--quiet", "--no-video", "--out", str(tmp_path / "run")])
    _one_line(capsys, code, "tactex clean: error:", *words)


def test_wipe_and_twin_take_a_part(dome_stl):
    from tactex.tasks.wipe import WipeConfig

    cfg = WipeConfig(object_name=str(dome_stl), start_y_m=-0.07)  # the default start is near its edge
    assert cfg.scene().sim_object is load_part(dome_stl)
    with pytest.raises(InputError, match="not a file"):
        WipeConfig(object_name="nope.obj")


@pytest.mark.slow
def test_clean_a_part_end_to_end(tmp_path, capsys, dome_stl):
    """A short clean of the domed part in simulation: it runs, removes dirt, writes its metrics (the full
    acceptance run, ≥ 95 % removed, is the same command without --budget-s: docs/own_part.md)."""
    out = tmp_path / "clean"
    code = main(["clean", "--object", str(dome_stl), "--budget-s", "4", "--quiet", "--no-video", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    m = json.loads((out / "metrics.json").read_text())
    assert m["object"] == str(dome_stl.resolve()) and m["marking"] == "part"
    assert m["n_target_initial"] > 100 and m["dirt_removed_fraction"] > 0.1
    assert m["force_over_2x_ticks"] == 0


@pytest.mark.franka
@pytest.mark.timeout(300)
def test_the_twin_serves_the_parts_height_field(dome_stl):
    pytest.importorskip("pylibfranka", reason="needs the franka extra")
    pytest.importorskip("franky_sim", reason="needs the franka extra")
    from tactex.perception.depth import frame_to_cloud
    from tactex.perception.mount import CameraMount
    from tactex.perception.twin_camera import TwinCameraSource, twin_status
    from tactex.robots.read_pose import read_tool_pose
    from tactex.tasks.robot import nominal_tool_T_camera
    from tactex.twin.process import TwinProcess

    obj = load_part(dome_stl)
    with TwinProcess(str(dome_stl), ["--camera-width", "160", "--camera-height", "120"]) as twin:
        assert str(dome_stl.resolve()) in twin.ready_line
        base_T_tool = read_tool_pose(twin.hostname)
        mount = CameraMount(nominal_tool_T_camera(SceneConfig(object_name=str(dome_stl))))
        with TwinCameraSource(twin.hostname, twin.camera_port, mount=mount,
                              tool_pose_provider=lambda: base_T_tool) as source:
            frame = source.read()
        status = twin_status(twin.hostname, twin.camera_port)
    cloud = frame_to_cloud(frame)
    local = cloud.points - [0.5, 0.0, obj.lift_m]
    on = (np.abs(local[:, 0]) < 0.09) & (np.abs(local[:, 1]) < 0.09)
    assert on.sum() > 100
    # the depth the twin serves is the part's top surface, red where the file is
    assert np.abs(local[on, 2] - obj.surface.height(local[on, 0], local[on, 1])).max() < 2e-3
    c = cloud.colors[on]
    red = (c[:, 0] > 0.6) & (c[:, 1] < 0.4) & (c[:, 2] < 0.4)
    d = np.hypot(local[on, 0] - PATCH_XY[0], local[on, 1] - PATCH_XY[1])
    assert red[d < PATCH_R - 0.005].all() and not red[d > PATCH_R + 0.005].any()
    assert status["dirt_removed_fraction"] == 0.0
