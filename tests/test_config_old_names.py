"""Renamed parameter fields keep their old names: keyword, attribute and hidden CLI option (tactex.config)."""

from __future__ import annotations

import argparse
import dataclasses
import warnings

import pytest

from tactex.config import accept_old_names, add_dataclass_arguments, dataclass_from_args, option_aliases, param
from tactex.ergodic import HedacConfig


@accept_old_names
@dataclasses.dataclass(frozen=True)
class _Renamed:
    reach_voxels: float = param(1.0, "reach [voxels]", old_names=("reach",))
    other: int = param(3, "something else [-]")


def test_the_old_keyword_sets_the_new_field_with_a_deprecation_warning():
    with pytest.warns(DeprecationWarning, match=r"_Renamed\.reach is now _Renamed\.reach_voxels"):
        obj = _Renamed(reach=2.5)
    assert obj.reach_voxels == 2.5 and obj.reach == 2.5
    assert [f.name for f in dataclasses.fields(obj)] == ["reach_voxels", "other"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _Renamed(reach_voxels=4.0).reach == 4.0  # the new name warns nothing


def test_replace_with_the_old_name_changes_the_field():
    with pytest.warns(DeprecationWarning):
        changed = dataclasses.replace(_Renamed(reach_voxels=1.5, other=7), reach=9.0)
    assert changed == _Renamed(reach_voxels=9.0, other=7)


def test_an_unknown_keyword_is_still_refused():
    with pytest.raises(TypeError):
        _Renamed(rech=1.0)


def test_the_old_option_works_and_is_hidden_from_the_help():
    parser = argparse.ArgumentParser()
    add_dataclass_arguments(parser, _Renamed)
    assert dataclass_from_args(_Renamed, parser.parse_args(["--reach", "2"])).reach_voxels == 2.0
    assert dataclass_from_args(_Renamed, parser.parse_args(["--reach-voxels", "3"])).reach_voxels == 3.0
    text = parser.format_help()
    assert "--reach-voxels" in text and "--reach " not in text
    assert option_aliases(_Renamed)["reach_voxels"] == ["--reach-voxels", "--reach"]


def test_the_old_option_takes_the_prefix():
    parser = argparse.ArgumentParser()
    add_dataclass_arguments(parser, _Renamed, prefix="probe_")
    assert dataclass_from_args(_Renamed, parser.parse_args(["--probe-reach", "5"]), prefix="probe_").reach_voxels == 5


@pytest.mark.parametrize(("old", "new", "value"), [
    ("max_off_cloud", "max_off_cloud_voxels", 2.0),
    ("max_bridge", "max_bridge_voxels", 0.0),
    ("max_snap_distance", "max_snap_distance_voxels", 5.0),
    ("stall_radius", "stall_radius_voxels", 3.0),
])
def test_hedac_config_fields_in_voxels_keep_their_old_names(old, new, value):
    with pytest.warns(DeprecationWarning, match=f"HedacConfig.{old} is now HedacConfig.{new}"):
        cfg = HedacConfig(**{old: value})
    assert getattr(cfg, new) == value and getattr(cfg, old) == value
    parser = argparse.ArgumentParser()
    add_dataclass_arguments(parser, HedacConfig)
    flag = "--" + old.replace("_", "-")
    assert getattr(dataclass_from_args(HedacConfig, parser.parse_args([flag, str(value)])), new) == value
    assert flag + " " not in parser.format_help()
