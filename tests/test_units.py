"""``--units m|mm|in``: a file in millimetres or inches read as metres before it is checked, the same run as its
twin in metres; the refusal of a millimetre file names the option, an inch-sized part gets the inch hint."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from tactex.cli import main
from tactex.errors import ConfigError, UnitsError
from tactex.experiments import ExploreConfig
from tactex.experiments.sweep import SweepConfig
from tactex.pointcloud.io import read_cloud
from tactex.pointcloud.units import check_units, inch_hint, metre_hint, to_metres
from tactex.tasks.clean.config import CleanConfig

#: A box whose edges are whole millimetres and powers of two in metres: the mm file divided by 1000 gives the
#: metre file's vertices bit for bit.
BOX_M = (0.125, 0.0625, 0.03125)


@pytest.fixture(autouse=True)
def _cache_dir(tmp_path_factory, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TACTEX_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "basis-cache"))


def _box_stl(path, scale: float) -> str:
    trimesh.creation.box(extents=np.asarray(BOX_M) * scale).export(path)
    return str(path)


def _explore(source, out, *extra) -> dict:
    code = main(["explore", source, "--out", str(out), "--steps", "40", "--voxel-size-m", "0.005", "--target", "all",
                 "--n-eigen", "40", "--quiet", *extra])
    assert code == 0
    metrics = json.loads((out / "metrics.json").read_text())
    metrics["trajectory"] = np.load(out / "trajectory.npy", allow_pickle=False)
    return metrics


def test_millimetre_stl_with_units_mm_runs_as_the_metre_file(tmp_path) -> None:
    metre = _explore(_box_stl(tmp_path / "box_m.stl", 1.0), tmp_path / "m")
    milli = _explore(_box_stl(tmp_path / "box_mm.stl", 1000.0), tmp_path / "mm", "--units", "mm")
    assert milli["n_points"] == metre["n_points"] > 500
    np.testing.assert_array_equal(milli["trajectory"], metre["trajectory"])
    for key in ("final_ergodicity", "final_coverage_residual", "final_path_length_m", "spacing_m"):
        assert milli[key] == metre[key], key
    assert milli["config"]["units"] == "mm"


def test_millimetre_stl_refused_naming_the_option(tmp_path, capsys) -> None:
    stl = _box_stl(tmp_path / "box_mm.stl", 1000.0)
    assert main(["explore", stl, "--out", str(tmp_path / "r"), "--target", "all", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "spans 125 along one axis" in err and "probably in millimetres: give --units mm" in err
    assert "inches" not in err  # 125 units is no inch part


def test_millimetre_cloud_refused_naming_the_option(tmp_path, capsys) -> None:
    g = np.linspace(0.0, 100.0, 30)
    x, y = np.meshgrid(g, g)
    np.savez(tmp_path / "mm.npz", points=np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)]))
    assert main(["explore", str(tmp_path / "mm.npz"), "--out", str(tmp_path / "r"), "--quiet"]) == 2
    assert "give --units mm" in capsys.readouterr().err
    read = read_cloud(tmp_path / "mm.npz", units="mm")
    assert np.ptp(read.cloud.points[:, 0]) == pytest.approx(0.1)


def test_metre_cloud_read_as_millimetres_is_refused_naming_the_option(tmp_path, capsys) -> None:
    g = np.linspace(0.0, 0.2, 30)  # a 20 cm plate in metres
    x, y = np.meshgrid(g, g)
    np.savez(tmp_path / "m.npz", points=np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)]))
    with pytest.raises(UnitsError, match=r"spans 0.2 mm read with units=mm, smaller than any part a sponge cleans; it "
                                         r"is probably in metres \(0.2 m wide then\): give units=m"):
        read_cloud(tmp_path / "m.npz", units="mm")
    for argv in (["explore", str(tmp_path / "m.npz"), "--target", "all"],
                 ["clean", "--cloud", str(tmp_path / "m.npz")]):
        assert main([*argv, "--units", "mm", "--out", str(tmp_path / argv[0]), "--quiet"]) == 2
        assert "probably in metres (0.2 m wide then): give --units m" in capsys.readouterr().err
    assert read_cloud(tmp_path / "m.npz").cloud.points.shape == (900, 3)  # in its own unit it reads
    assert metre_hint(0.004, "in") and not metre_hint(0.004, "m") and not metre_hint(0.006, "mm")
    assert not metre_hint(1e-6, "mm")  # 1 mm as metres is no part either: no advice


def test_inch_part_gets_the_inch_hint_and_runs_with_units_in(tmp_path, capsys) -> None:
    stl = _box_stl(tmp_path / "box_in.stl", 40.0)  # 5 × 2.5 × 1.25 units: a part in inches
    assert main(["explore", stl, "--out", str(tmp_path / "r"), "--target", "all", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "give --voxel-size-m" in err and "if it is in inches (0.127 m wide then), give --units in" in err
    metrics = _explore(stl, tmp_path / "in", "--units", "in")
    assert metrics["n_points"] > 500
    read = read_cloud(stl, units="in", mesh_spacing_m=0.005)
    assert np.ptp(read.cloud.points, axis=0).max() == pytest.approx(5 * 0.0254, rel=1e-6)


def test_wide_cloud_in_metres_passes_with_an_inch_note(tmp_path) -> None:
    g = np.linspace(0.0, 4.0, 400)  # 4 "m" wide, 1 cm apart: an inch scan read as metres
    x, y = np.meshgrid(g, g[:20])
    np.savez(tmp_path / "wide.npz", points=np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)]))
    notes = read_cloud(tmp_path / "wide.npz").notes
    assert any("spans 4 m, more than a robot arm reaches; if it is in inches (0.102 m wide then), give units=in" in n
               for n in notes)
    assert not any("inches" in n for n in read_cloud(tmp_path / "wide.npz", units="in").notes)


def test_units_scale_every_format_and_the_stored_spacing(tmp_path) -> None:
    pts = np.random.default_rng(0).uniform(0, 100.0, size=(200, 3))
    np.savez(tmp_path / "c.npz", points=pts, spacing=3.0)
    read = read_cloud(tmp_path / "c.npz", units="mm")
    np.testing.assert_array_equal(read.cloud.points, pts / 1000.0)
    assert read.cloud.spacing == pytest.approx(0.003)
    np.testing.assert_allclose(to_metres(np.array([1.0]), "in"), [0.0254])


def test_bad_units_are_refused(tmp_path, capsys) -> None:
    for bad in ("cm", "", None, "MM"):
        with pytest.raises(ConfigError, match="is not a length unit; give one of m, mm, in"):
            check_units(bad)
    with pytest.raises(ConfigError, match="not a length unit"):
        ExploreConfig(units="feet")
    with pytest.raises(ConfigError, match="not a length unit"):
        SweepConfig(units="km")
    with pytest.raises(ConfigError, match="is the unit of a --cloud or --object FILE: give one"):
        CleanConfig(units="mm")
    with pytest.raises(ConfigError, match="not a length unit"):
        CleanConfig(units="yd")
    assert main(["explore", "plate", "--out", str(tmp_path / "b"), "--units", "mm", "--quiet"]) == 2
    assert "built-in 'plate' is in metres" in capsys.readouterr().err
    with pytest.raises(UnitsError):  # without the option the millimetre file stays refused in the library too
        read_cloud(_box_stl(tmp_path / "b.stl", 1000.0))


def test_inch_hint_only_for_part_sized_extents() -> None:
    assert inch_hint(1.5) == "" and inch_hint(150.0) == ""
    assert "units=in" in inch_hint(5.0) and "units=in" in inch_hint(60.0)


def test_units_reach_every_file_command(tmp_path) -> None:
    from tactex.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    for command in ("explore", "sweep", "clean", "study", "annotate"):
        assert "--units" in sub.choices[command]._option_string_actions, command
    from tactex.commands.study import spec_from_args

    (tmp_path / "x.ply").write_text("")  # only its existence is checked here
    args = parser.parse_args(["study", "--out", str(tmp_path / "s"), "--units", "mm", "--set",
                              f"cloud={tmp_path / 'x.ply'}"])
    assert spec_from_args(args).fixed["units"] == "mm"


def test_clean_cloud_in_millimetres_is_the_metre_cloud(tmp_path) -> None:
    from tactex.tasks.clean.target import load_target_cloud

    g = np.arange(0.0, 64.0, 1.0)  # a 64 mm plate sampled every 1 mm, red in one corner
    x, y = np.meshgrid(g, g)
    pts_mm = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, 500.0)])
    colors = np.where((pts_mm[:, :1] < 20) & (pts_mm[:, 1:2] < 20), [1.0, 0.0, 0.0], [0.8, 0.8, 0.8])
    np.savez(tmp_path / "mm.npz", points=pts_mm, colors=colors)
    np.savez(tmp_path / "m.npz", points=pts_mm / 1000.0, colors=colors)
    a = load_target_cloud(tmp_path / "mm.npz", 0.003, units="mm")
    b = load_target_cloud(tmp_path / "m.npz", 0.003)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.target, b.target)
    assert a.n_target > 0


def test_a_millimetre_part_read_in_inches_is_told_to_use_millimetres(tmp_path, capsys) -> None:
    """A 600 mm part given --units in spans 15 m: the hint names millimetres and the width in them, not inches
    again (it advised the --units in it was given, with a width converted twice)."""
    import trimesh

    part = tmp_path / "section_mm.stl"
    mesh = trimesh.creation.box(extents=[600.0, 500.0, 20.0])
    mesh.apply_translation([0.0, 0.0, 10.0])
    mesh.export(part)
    assert main(["clean", "--object", str(part), "--units", "in", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "if it is in millimetres (0.6 m wide then), give --units mm" in err and "give --units in" not in err, err
