"""The kinds of RobotError: each libfranka failure becomes the subclass of its kind, raised where the
kind is known, and every kind is still a RobotError (and a stop the tasks keep their data on)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from tactex.errors import (
    RobotClosedError,
    RobotCommunicationError,
    RobotConnectionError,
    RobotError,
    RobotRealtimeError,
    RobotReflexError,
    TactexError,
)
from tactex.robots.libfranka_backend import FrankaConfig, LibfrankaBackend, libfranka_error_kind
from tactex.tasks.robot import ROBOT_STOPS

KINDS = (RobotClosedError, RobotCommunicationError, RobotConnectionError, RobotRealtimeError, RobotReflexError)


class _FrankaException(Exception):  # stand-ins for pylibfranka's exception types
    pass


class _ControlException(_FrankaException):
    pass


class _NetworkException(_FrankaException):
    pass


class _CommandException(_FrankaException):
    pass


PLF = SimpleNamespace(ControlException=_ControlException, NetworkException=_NetworkException)


@pytest.mark.parametrize("kind", KINDS)
def test_every_kind_is_caught_as_a_robot_error_and_stops_a_task(kind: type[RobotError]) -> None:
    assert issubclass(kind, RobotError) and issubclass(kind, TactexError) and issubclass(kind, RuntimeError)
    with pytest.raises(RobotError):
        raise kind("x")
    assert isinstance(kind("x"), ROBOT_STOPS)


@pytest.mark.parametrize(
    ("exc", "kind"),
    [
        (_NetworkException("libfranka: UDP receive: Timeout"), RobotConnectionError),
        # the network type wins over the text: a lost link is the link, whatever the message says
        (_NetworkException("communication_constraints_violation"), RobotConnectionError),
        (_ControlException("Motion aborted by reflex! ['communication_constraints_violation']"),
         RobotCommunicationError),
        (RuntimeError("communication_constraints_violation"), RobotCommunicationError),
        (_ControlException("Motion aborted by reflex! ['cartesian_reflex']"), RobotReflexError),
        (_CommandException("command rejected"), RobotReflexError),
    ],
)
def test_libfranka_errors_map_to_their_kind(exc: BaseException, kind: type[RobotError]) -> None:
    assert libfranka_error_kind(exc, PLF) is kind


def _backend_mid_control() -> LibfrankaBackend:
    """A backend as :meth:`LibfrankaBackend._fault` finds it during torque control, without a robot."""
    backend = LibfrankaBackend.__new__(LibfrankaBackend)
    backend._plf = PLF
    backend.config = FrankaConfig(robot_ip="127.0.0.1")
    backend.events = []
    backend._control = object()
    backend._pending_write = True
    backend._gc_was_on = False
    return backend


@pytest.mark.parametrize(
    ("exc", "kind", "hint"),
    [
        (_NetworkException("UDP timeout"), RobotConnectionError, "the link to the robot was lost"),
        (_ControlException("['communication_constraints_violation']"), RobotCommunicationError,
         "commands arrived late"),
        (_ControlException("['joint_velocity_violation']"), RobotReflexError, "a libfranka reflex or refusal"),
    ],
)
def test_a_fault_during_torque_control_is_its_kind_with_its_hint(exc, kind, hint) -> None:
    backend = _backend_mid_control()
    error = backend._fault(exc)
    assert type(error) is kind
    assert str(error).startswith(f"libfranka {type(exc).__name__}: {exc}") and hint in str(error)
    assert backend._control is None and not backend._pending_write
    assert backend.events == [f"{type(exc).__name__}: {exc}"]


def test_set_up_failures_are_their_kind(monkeypatch: pytest.MonkeyPatch) -> None:
    pylibfranka = pytest.importorskip("pylibfranka")

    def no_rt_kernel(*_args):
        raise pylibfranka.RealtimeException("no real-time kernel")

    monkeypatch.setattr(pylibfranka, "Robot", no_rt_kernel)
    with pytest.raises(RobotRealtimeError, match="PREEMPT_RT"):
        LibfrankaBackend(FrankaConfig(robot_ip="127.0.0.254"))

    def refused(*_args):
        raise pylibfranka.NetworkException("connection refused")

    monkeypatch.setattr(pylibfranka, "Robot", refused)
    with pytest.raises(RobotConnectionError, match=r"127\.0\.0\.254"):
        LibfrankaBackend(FrankaConfig(robot_ip="127.0.0.254"))


def test_a_closed_backend_says_so_by_type() -> None:
    backend = LibfrankaBackend.__new__(LibfrankaBackend)
    backend._closed = True
    with pytest.raises(RobotClosedError, match="closed"):
        backend.step()


def test_the_connect_is_announced_before_libfranka_waits(monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    """An address where nothing answers holds libfranka silent for its TCP timeout: the task says first what it
    waits for, and how long it may."""
    pylibfranka = pytest.importorskip("pylibfranka")
    from tactex.robots.libfranka_backend import CONNECT_TIMEOUT_S
    from tactex.sim.scene import SceneConfig
    from tactex.tasks.robot import RealRobotParams, open_backend

    said: list[str] = []  # stderr as it stood when libfranka was called

    def refused(*_args):
        said.append(capsys.readouterr().err)
        raise pylibfranka.NetworkException("connection refused")

    monkeypatch.setattr(pylibfranka, "Robot", refused)
    with pytest.raises(RobotConnectionError):
        open_backend(SceneConfig(), RealRobotParams(robot_ip="127.0.0.254"), announce=True)
    with pytest.raises(RobotConnectionError):
        open_backend(SceneConfig(), RealRobotParams(robot_ip="127.0.0.254"), announce=False)
    assert len(said) == 2
    assert f"connecting to the Franka at 127.0.0.254 (libfranka waits up to {CONNECT_TIMEOUT_S} s" in said[0]
    assert "connecting" not in said[1]
    assert CONNECT_TIMEOUT_S == 60  # libfranka's Network default tcp_timeout


def test_the_wipe_refuses_the_twins_capture_camera_before_the_robot_is_touched(monkeypatch: pytest.MonkeyPatch) -> None:
    """--camera twin serves clean's captures and calibrate's views; the wipe's surface estimate needs a stream
    (--camera sim on the twin): refused before libfranka is called."""
    pylibfranka = pytest.importorskip("pylibfranka")
    from tactex.errors import ConfigError
    from tactex.tasks.robot import RealRobotParams
    from tactex.tasks.wipe import WipeConfig, run_wipe

    calls: list = []
    monkeypatch.setattr(pylibfranka, "Robot", lambda *args: calls.append(args))
    with pytest.raises(ConfigError, match="--camera sim"):
        run_wipe(WipeConfig(), progress=False, robot=RealRobotParams(robot_ip="127.0.0.254", camera="twin"))
    assert calls == []
