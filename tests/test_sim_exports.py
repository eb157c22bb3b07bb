"""Public names of tactex.sim and tactex.robots resolve; the libfranka placeholder fails clearly."""

from __future__ import annotations

import importlib.util

import pytest

import tactex.robots
import tactex.sim
from tactex.errors import MissingDependencyError, TactexError


@pytest.mark.parametrize("module", [tactex.sim, tactex.robots])
def test_all_names_resolve(module):
    assert len(set(module.__all__)) == len(module.__all__)
    for name in module.__all__:
        assert getattr(module, name) is not None


def test_libfranka_backend_without_the_extra():
    if importlib.util.find_spec("pylibfranka") is not None:
        with pytest.raises(TactexError, match="not implemented"):
            tactex.robots.LibfrankaBackend("172.16.0.2")
    else:
        with pytest.raises(MissingDependencyError, match=r"pip install 'tactex\[franka\]'"):
            tactex.robots.LibfrankaBackend("172.16.0.2")
