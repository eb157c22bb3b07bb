"""Exception types of tactex.

Every error raised on bad input is a :class:`TactexError`; messages name the input, echo the bad
value or shape, and say what to do. Subclasses also derive from the matching builtin
(``ValueError``, ``ImportError``, ``RuntimeError``) so generic handlers keep working.
"""

from __future__ import annotations

__all__ = [
    "PYGAFRO_FIX",
    "CacheError",
    "CloudError",
    "ConfigError",
    "ControllerFault",
    "ExecutorError",
    "ExplorationError",
    "InputError",
    "MissingDependencyError",
    "PerceptionError",
    "PolicyFault",
    "PolicyFileError",
    "RobotClosedError",
    "RobotCommunicationError",
    "RobotConnectionError",
    "RobotError",
    "RobotRealtimeError",
    "RobotReflexError",
    "RunInterrupted",
    "RunStopped",
    "SafetyFault",
    "SensorFault",
    "SimulationError",
    "SpectralError",
    "SurfaceNotFound",
    "TactexError",
    "UnitsError",
]


class TactexError(Exception):
    """Base class of every exception raised by tactex."""


class InputError(TactexError, ValueError):
    """An argument has the wrong type, shape, dtype or value."""


class CloudError(InputError):
    """A point cloud is empty, holds NaN/inf, duplicates, or too few points for an operation."""


class UnitsError(InputError):
    """Data whose magnitude suggests the wrong unit (e.g. a cloud in millimetres)."""


class SpectralError(TactexError, ValueError):
    """The Laplacian or its eigenbasis cannot be built for the given cloud and parameters."""


class ExplorationError(TactexError, ValueError):
    """The ergodic explorer cannot proceed (no target mass, degenerate neighbourhood, ...)."""


class SurfaceNotFound(ExplorationError):
    """The tool found no surface where the plan expected one (the object moved, or is not there): an
    outcome of a run, not a fault. The task ends, torque control ended first, and keeps what it
    recorded (``aborted`` in its metrics names it)."""


class PerceptionError(InputError):
    """A depth/RGB frame or camera model is invalid."""


class ConfigError(InputError):
    """A parameter is out of its valid range, or an option name is unknown."""


class PolicyFileError(ConfigError):
    """A force-motion policy file is refused; the field names it gives are the file's own, not options."""


class CacheError(TactexError, OSError):
    """A cache file is corrupt or does not match the data it claims to describe."""


class ExecutorError(TactexError, RuntimeError):
    """Where a study's runs execute (local worker processes, a Ray instance) could not be started."""


class SimulationError(TactexError, RuntimeError):
    """The simulation diverged or a scene cannot be assembled."""


class ControllerFault(TactexError, RuntimeError):
    """A controller could not produce a valid torque (NaN state, invalid reference)."""


class RobotError(TactexError, RuntimeError):
    """The real robot (or its protocol twin) refused a command, raised a reflex, or the link to it
    failed; the message names libfranka's error and what to check. A subclass names the kind when it
    is known, for a caller to catch by type; ``except RobotError`` catches every kind."""


class RobotConnectionError(RobotError):
    """The robot cannot be reached, or the link to it was lost (libfranka's ``NetworkException``)."""


class RobotRealtimeError(RobotError):
    """libfranka refuses to run without a real-time kernel (its ``RealtimeException``)."""


class RobotCommunicationError(RobotError):
    """Commands reached the robot late: libfranka's ``communication_constraints_violation``, or our
    loop answered a state later than its budget and ended torque control as the robot would."""


class RobotReflexError(RobotError):
    """The robot stopped the motion: a libfranka reflex or refusal (``ControlException`` and the
    like); Desk names the reflex that fired."""


class RobotClosedError(RobotError):
    """The backend was used after it was closed."""


class SensorFault(TactexError, RuntimeError):
    """A sensor or the vision process stopped delivering (no data within its timeout)."""


class PolicyFault(TactexError, RuntimeError):
    """A force-motion policy broke its contract while a run followed it (it raised, returned something that is
    not a finite ``PolicyPoint``, or left the limits it was checked against): the run stops, its data kept."""


class SafetyFault(ControllerFault):
    """The safety layer tripped and the controller is holding or retreating."""


class RunStopped(TactexError, RuntimeError):
    """A run that had started was stopped by the robot or a sensor (a reflex, a lost link, a camera that
    ended) with nothing of it to keep: the message says what stopped it. Commands exit with code 1, as a
    run that stops early with its data kept does (2 is for what is refused before a run starts)."""


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped a run, and what it had done is saved: the message says what and where.

    A ``KeyboardInterrupt`` (not a :class:`TactexError`), so that the caller's program stops as it
    would on any Ctrl-C, and no ``except Exception`` swallows it."""


#: How to repair pygafro, a core dependency (a failed import means a broken installation, not a missing extra).
PYGAFRO_FIX = "It is a core dependency of tactex: reinstall it with pip install --force-reinstall pygafro"


class MissingDependencyError(TactexError, ImportError):
    """Something optional is missing. The message says how to get it: the ``pip install`` of the
    extra ``extra`` that brings it, or ``fix`` where pip cannot help (a GL context, a display, an
    operating-system feature) or a core dependency is broken."""

    def __init__(self, package: str, extra: str, purpose: str, *, fix: str | None = None) -> None:
        if fix is None and not extra:
            raise ValueError("MissingDependencyError needs an extra to install or a fix to describe")
        if fix is None:
            msg = f"{purpose} needs the optional package '{package}'. Install it with: pip install 'tactex[{extra}]'"
        else:
            msg = f"{purpose}: no {package}. {fix}"
        super().__init__(msg)
        self.package = package
        self.extra = extra
        self.fix = fix


class CameraStreamEnded(SensorFault):
    """The camera delivered no frame when one was needed: a recording played to its end, or a live
    stream (a RealSense, the twin's camera) stalled or stopped. The message names the source."""


__all__ += ["CameraStreamEnded"]  # beside the class, so that merges leave the list above alone
