"""Package-level contracts: every exported name resolves; config dataclasses map to CLI options."""

from __future__ import annotations

import argparse
import importlib
import json
import pkgutil
from dataclasses import dataclass

import numpy as np
import pytest

import tactex
from tactex.cli import main
from tactex.config import add_dataclass_arguments, dataclass_from_args, param, write_json
from tactex.errors import ConfigError


def _packages() -> list[str]:
    names = ["tactex"]
    names += [m.name for m in pkgutil.walk_packages(tactex.__path__, "tactex.") if m.ispkg]
    return names


@pytest.mark.parametrize("modname", _packages())
def test_all_names_resolve(modname: str) -> None:
    mod = importlib.import_module(modname)
    for name in getattr(mod, "__all__", []):
        assert hasattr(mod, name), f"{modname}.__all__ lists '{name}' but it is not defined"


@dataclass(frozen=True)
class _Demo:
    agent_radius_m: float = param(0.0075, "agent radius [m]")
    steps: int = param(1000, "exploration steps")
    verbose: bool = param(False, "print more")
    x0: tuple[float, float, float] = param((0.0, 0.0, 0.0), "start [m]")

    def __post_init__(self) -> None:
        if self.agent_radius_m <= 0:
            raise ConfigError(f"agent_radius_m must be > 0, got {self.agent_radius_m}")


def test_dataclass_cli_round_trip() -> None:
    parser = argparse.ArgumentParser()
    add_dataclass_arguments(parser, _Demo)
    cfg = dataclass_from_args(_Demo, parser.parse_args(["--steps", "5", "--verbose", "--x0", "1", "2", "3"]))
    assert cfg == _Demo(steps=5, verbose=True, x0=(1.0, 2.0, 3.0))
    assert dataclass_from_args(_Demo, parser.parse_args([])) == _Demo()
    assert "agent radius [m]" in parser.format_help()
    with pytest.raises(ConfigError, match="agent_radius_m"):
        dataclass_from_args(_Demo, parser.parse_args(["--agent-radius-m", "-1"]))


@dataclass(frozen=True)
class _Renamed:
    pad_radius: float = param(0.025, "sponge radius [m]", option="pad_radius_m", aliases=("--tool-pad-radius-m",))


def test_an_option_renamed_keeps_its_old_spelling_hidden() -> None:
    parser = argparse.ArgumentParser()
    add_dataclass_arguments(parser, _Renamed)
    for spelling in ("--pad-radius-m", "--tool-pad-radius-m"):
        assert dataclass_from_args(_Renamed, parser.parse_args([spelling, "0.03"])) == _Renamed(pad_radius=0.03)
    text = parser.format_help()
    assert "--pad-radius-m" in text and "--tool-pad-radius-m" not in text and "--pad-radius " not in text


def test_the_twin_takes_the_sponge_radius_under_the_clean_s_name() -> None:
    from tactex.twin.config import TwinConfig

    parser = argparse.ArgumentParser()
    add_dataclass_arguments(parser, TwinConfig)
    for spelling in ("--pad-radius-m", "--tool-pad-radius-m"):
        assert dataclass_from_args(TwinConfig, parser.parse_args([spelling, "0.03"])).tool_pad_radius_m == 0.03
    assert "--tool-pad-radius-m" not in parser.format_help()


def test_write_json_maps_numpy_and_nan(tmp_path) -> None:
    path = write_json({"a": np.arange(3), "b": np.float32(1.5), "c": float("nan")}, tmp_path / "m.json")
    assert json.loads(path.read_text()) == {"a": [0, 1, 2], "b": 1.5, "c": None}


def test_cli_without_command_prints_help(capsys) -> None:
    assert main([]) == 2
    assert "usage: tactex" in capsys.readouterr().out


def test_missing_dependency_says_how_to_get_it():
    from tactex.errors import PYGAFRO_FIX, MissingDependencyError

    extra = MissingDependencyError("pylibfranka", "franka", "The real-robot backend")
    assert "pip install 'tactex[franka]'" in str(extra)
    core = MissingDependencyError("pygafro", "", "The CGA fit", fix=PYGAFRO_FIX)
    assert "pygafro" in str(core) and "tactex[" not in str(core)
    with pytest.raises(ValueError, match="extra to install or a fix"):
        MissingDependencyError("x", "", "y")
