"""Public names of tactex.sim and tactex.robots resolve; the libfranka placeholder fails clearly."""

from __future__ import annotations

import importlib.util

import pytest

import tactex.robots
import tactex.sim
from tactex.errors import InputError, MissingDependencyError


@pytest.mark.parametrize("module", [tactex.sim, tactex.robots])
def test_all_names_resolve(module):
    assert len(set(module.__all__)) == len(module.__all__)
    for name in module.__all__:
        assert getattr(module, name) is not None


def test_libfranka_backend_without_the_extra(monkeypatch):
    from tactex.robots.libfranka_backend import FrankaConfig

    real_find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "pylibfranka" else real_find_spec(name, *a))
    with pytest.raises(MissingDependencyError, match=r"pip install 'tactex\[franka\]'"):
        tactex.robots.LibfrankaBackend(FrankaConfig(robot_ip="172.16.0.2"))


def test_libfranka_backend_takes_a_config():
    with pytest.raises(InputError, match="FrankaConfig"):
        tactex.robots.LibfrankaBackend("172.16.0.2")
