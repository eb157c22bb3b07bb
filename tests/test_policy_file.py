"""The policy file (``tactex wipe --policy FILE.toml``): a good file loads into the segments it
lists; every bad one is refused before the arm moves, one line naming the segment and the field,
exit code 2 through the CLI."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import pytest

from tactex.cli import main
from tactex.errors import ConfigError
from tactex.tasks.policies import LinePolicy, PolicySequence, SamplesPolicy, SpiralPolicy, load_policy_file
from tactex.tasks.wipe import WipeConfig

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "policies"
SPIRAL = 'kind = "spiral"\nduration_s = 6.0\nforce_n = 10.0\nradius_m = 0.035\nturns = 2.5\n'
GOOD_CSV = "t_s,u_m,v_m,force_n\n0,0,0,10\n1,0.01,0,10\n2,0.02,0.01,11\n"


def _run(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code)


def _write(tmp_path: Path, body: str, csv: str | None = None) -> Path:
    if csv is not None:
        (tmp_path / "drawn.csv").write_text(csv)
    p = tmp_path / "policy.toml"
    p.write_text(body)
    return p


def _refused(tmp_path, capsys, body: str, *needles: str, csv: str | None = None) -> str:
    """Through the CLI: exit 2, one line on stderr naming the file and ``needles``, nothing run."""
    path = _write(tmp_path, body, csv)
    out = tmp_path / "run"
    code = _run(["wipe", "--policy", str(path), "--quiet", "--no-video", "--out", str(out)])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2, err
    assert len(lines) == 1, err
    assert lines[0].startswith("tactex wipe: error: policy file "), lines[0]
    assert str(path) in lines[0] and "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], lines[0]
    assert not out.exists()  # refused before anything ran
    return lines[0]


def test_unknown_kind(tmp_path, capsys) -> None:
    _refused(tmp_path, capsys, f"[[segment]]\n{SPIRAL}\n[[segment]]\nkind = \"wobble\"\nduration_s = 2.0\n",
             "segment 2", "kind", "'wobble'", "valid: sinusoid, line, zigzag, spiral, circle, figure8, samples")


def test_missing_field(tmp_path, capsys) -> None:
    _refused(tmp_path, capsys, "[[segment]]\n" + SPIRAL.replace("radius_m = 0.035\n", ""),
             "segment 1 (spiral)", "missing field radius_m")


def test_negative_duration(tmp_path, capsys) -> None:
    _refused(tmp_path, capsys, "[[segment]]\n" + SPIRAL.replace("duration_s = 6.0", "duration_s = -2.0"),
             "segment 1 (spiral)", "duration_s = -2.0 must be > 0")


def test_force_above_the_limit(tmp_path, capsys) -> None:
    body = (f"[[segment]]\n{SPIRAL}\n[[segment]]\nkind = \"line\"\nduration_s = 4.0\nforce_n = [10.0, 45.0]\n"
            "length_m = 0.03\n")
    _refused(tmp_path, capsys, body, "segment 2 (line)", "force_n = ", "outside [1, 20] N")


def test_force_below_the_contact_threshold(tmp_path, capsys) -> None:
    _refused(tmp_path, capsys, "[[segment]]\n" + SPIRAL.replace("force_n = 10.0", "force_n = 0.5"),
             "segment 1 (spiral)", "force_n = 0.5 N", "outside [1, 20] N")


def test_csv_with_nan(tmp_path, capsys) -> None:
    _refused(tmp_path, capsys, '[[segment]]\nkind = "samples"\nfile = "drawn.csv"\n', "segment 1 (samples)",
             "file", "line 3: v_m = nan is not a finite number", csv=GOOD_CSV.replace("1,0.01,0,10", "1,0.01,nan,10"))


def test_csv_with_time_not_increasing(tmp_path, capsys) -> None:
    _refused(tmp_path, capsys, f'[[segment]]\n{SPIRAL}\n[[segment]]\nkind = "samples"\nfile = "drawn.csv"\n',
             "segment 2 (samples)", "line 4: t_s = 1 does not increase",
             csv=GOOD_CSV.replace("2,0.02", "1,0.02"))


def test_a_csv_error_names_the_line_a_user_sees_blank_lines_counted(tmp_path, capsys) -> None:
    # blank lines (a spreadsheet's empty rows) are skipped but counted: the line quoted is the file's own
    spaced = "t_s,u_m,v_m,force_n\n\n0,0,0,10\n\n\n1,0.01,0,10\n2,0.02,0.01,11\n"
    _refused(tmp_path, capsys, '[[segment]]\nkind = "samples"\nfile = "drawn.csv"\n', "segment 1 (samples)",
             "line 7: t_s = 1 does not increase", csv=spaced.replace("2,0.02", "1,0.02"))
    _refused(tmp_path, capsys, '[[segment]]\nkind = "samples"\nfile = "drawn.csv"\n', "segment 1 (samples)",
             "line 6: force_n = 45 N is outside [1, 20] N", csv=spaced.replace("1,0.01,0,10", "1,0.01,0,45"))


def test_path_out_of_reach(tmp_path, capsys) -> None:
    # the sine panel is 26 cm across: a 20 cm stroke along x from its middle leaves it
    body = f"[[segment]]\n{SPIRAL}\n[[segment]]\nkind = \"line\"\nduration_s = 8.0\nforce_n = 10.0\nlength_m = 0.2\n"
    _refused(tmp_path, capsys, body, "segment 2 (line)", "length_m/direction_deg", "leaves the sine_panel's surface",
             "move the start (--start-y-m moves it along the part's y, from 0.08 m now)")


def test_too_fast_and_too_sharp(tmp_path, capsys) -> None:
    fast = "[[segment]]\n" + SPIRAL.replace("duration_s = 6.0", "duration_s = 1.5")
    _refused(tmp_path, capsys, fast, "segment 1 (spiral)", "duration_s: speed", "exceeds the task's 0.15 m/s")
    sharp = ('[[segment]]\nkind = "circle"\nduration_s = 3.0\nforce_n = 10.0\nradius_m = 0.012\nturns = 3.0\n')
    _refused(tmp_path, capsys, sharp, "segment 1 (circle)", "acceleration", "exceeds the task's 1 m/s²")


def test_unblended_velocity_jump(tmp_path, capsys) -> None:
    body = (f"[[segment]]\n{SPIRAL}\n[[segment]]\nkind = \"sinusoid\"\nduration_s = 4.0\nforce_n = 10.0\n"
            "amplitude_m = 0.02\nomega_rad_s = 2.0\ndrift_m_s = 0.0\n")
    _refused(tmp_path, capsys, body, "segment 2 (sinusoid)", "velocity jumps by 0.040 m/s", "set blend_s")
    WipeConfig(policy=str(_write(tmp_path, "blend_s = 0.8\n" + body)))  # blended, it is accepted


@pytest.mark.parametrize(("body", "needle"), [
    ("[[segment]]\n" + SPIRAL + "colour = 3\n", "segment 1 (spiral): colour: not a field of spiral"),
    ("speed = 2\n[[segment]]\n" + SPIRAL, "unknown key 'speed'"),
    ("blend_s = 1.0\n", "no [[segment]]"),
    ("[[segment]]\n" + SPIRAL.replace("turns = 2.5", "turns = \"many\""), "turns must be a finite number"),
    ("[[segment]]\n" + SPIRAL.replace("force_n = 10.0", "force_n = [1, 2, 3]"), "[start, end]"),
    ("[[segment]]\nkind = \"zigzag\"\nduration_s = 8.0\nforce_n = 10.0\nwidth_m = 0.05\nlength_m = 0.04\n"
     "lanes = 2.5\n", "lanes must be a whole number"),
    ("[[segment]]\n" + SPIRAL + "[[segment]]\n" + SPIRAL, None),
    ("[[segment\n", "not valid TOML"),
    ("[segment]\n" + SPIRAL, "[segment] is one table; write [[segment]] (double brackets)"),
    ("[[segment]]\n" + SPIRAL.replace("radius_m = 0.035", "radius_m = 35"), "lengths are in metres (35 mm is 0.035)"),
])
def test_loader_refusals(tmp_path, body, needle) -> None:
    path = _write(tmp_path, body)
    if needle is None:
        pol = load_policy_file(path)
        assert isinstance(pol, PolicySequence) and pol.duration_s == 12.0
        return
    with pytest.raises(ConfigError) as info:
        load_policy_file(path)
    assert needle in str(info.value) and "\n" not in str(info.value)


def test_examples_load_and_pass_the_wipe_checks() -> None:
    for path in sorted(EXAMPLES.glob("*.toml")):
        for obj in ("sine_panel", "bowl"):
            WipeConfig(object_name=obj, start_y_m=0.0, policy=str(path))
    drawn = load_policy_file(EXAMPLES / "drawn.toml")
    assert isinstance(drawn.segments[0], SamplesPolicy) and drawn.duration_s == 12.0
    patch = load_policy_file(EXAMPLES / "patch.toml")
    assert [type(s) for s in patch.segments][:2] == [LinePolicy, SpiralPolicy] and patch.blend_s == 0.6
    assert math.isclose(patch.at(0.0).force_n, 6.0) and math.isclose(patch.at(1.5).force_n, 9.0)


def test_samples_file_is_found_beside_the_policy_file(tmp_path) -> None:
    sub = tmp_path / "elsewhere"
    shutil.copytree(EXAMPLES, sub)
    assert load_policy_file(sub / "drawn.toml").segments[0].source == "drawn.csv"
    (sub / "drawn.csv").unlink()
    with pytest.raises(ConfigError, match=r"segment 1 \(samples\): file: samples file .*drawn.csv' does not exist"):
        load_policy_file(sub / "drawn.toml")


def test_the_cup_wall_reach_is_its_arc_and_height(monkeypatch) -> None:
    WipeConfig(object_name="cup", policy=str(EXAMPLES / "cup" / "spiral.toml"))  # the cup's own: on the wall
    # the sinusoid drifts 8 cm down the tool's −y, which beside the wall is up: above the 10 cm rim
    with pytest.raises(ConfigError, match=r"segment 1 \(sinusoid\): amplitude_m/omega_rad_s: the path leaves the "
                                          r"cup's wall"):
        WipeConfig(object_name="cup", policy=str(EXAMPLES / "sinusoid.toml"))
    import types

    import tactex.tasks.wipe_policy as wp

    monkeypatch.setattr(wp, "object_or_part", lambda name, units="m": types.SimpleNamespace(surface=object()))
    with pytest.raises(ConfigError, match="neither"):
        wp.check_wipe_policy(WipeConfig(), load_policy_file(EXAMPLES / "spiral.toml"))


def test_the_cup_wall_keeps_the_pad_above_the_table(tmp_path) -> None:
    # from mid-height (5 cm) a figure eight 5 cm tall reaches 2.5 cm: the 2.5 cm pad, on its edge, touches the table
    # just below that; one 4.8 cm tall stays on the wall
    def figure8(height_m: float) -> Path:
        path = tmp_path / f"f8_{height_m}.toml"
        path.write_text(f'[[segment]]\nkind = "figure8"\nduration_s = 12.0\nforce_n = 12.0\nwidth_m = 0.025\n'
                        f"height_m = {height_m}\n")
        return path

    WipeConfig(object_name="cup", policy=str(figure8(0.048)))
    with pytest.raises(ConfigError, match=r"segment 1 \(figure8\): width_m/height_m: the path leaves the cup's wall "
                                          r"\(.*the pad's centre at least the pad's radius, 25 mm, above the table\)"):
        WipeConfig(object_name="cup", policy=str(figure8(0.052)))


def test_a_csv_given_as_the_policy_says_how_to_wrap_it(tmp_path) -> None:
    path = tmp_path / "drawn.csv"
    path.write_text(GOOD_CSV)
    with pytest.raises(ConfigError) as info:
        load_policy_file(path)
    assert 'as a [[segment]] with kind = "samples" and file = "drawn.csv"' in str(info.value)
