"""Exception types of tactex.

Every error raised on bad input is a :class:`TactexError`; messages name the input, echo the bad
value or shape, and say what to do. Subclasses also derive from the matching builtin
(``ValueError``, ``ImportError``, ``RuntimeError``) so generic handlers keep working.
"""

from __future__ import annotations

__all__ = [
    "CacheError",
    "CloudError",
    "ConfigError",
    "ControllerFault",
    "ExplorationError",
    "InputError",
    "MissingDependencyError",
    "PerceptionError",
    "SafetyFault",
    "SimulationError",
    "SpectralError",
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


class PerceptionError(InputError):
    """A depth/RGB frame or camera model is invalid."""


class ConfigError(InputError):
    """A parameter is out of its valid range, or an option name is unknown."""


class CacheError(TactexError, OSError):
    """A cache file is corrupt or does not match the data it claims to describe."""


class SimulationError(TactexError, RuntimeError):
    """The simulation diverged or a scene cannot be assembled."""


class ControllerFault(TactexError, RuntimeError):
    """A controller could not produce a valid torque (NaN state, invalid reference)."""


class SafetyFault(ControllerFault):
    """The safety layer tripped and the controller is holding or retreating."""


class MissingDependencyError(TactexError, ImportError):
    """An optional extra is needed; the message names the ``pip install`` command."""

    def __init__(self, package: str, extra: str, purpose: str) -> None:
        super().__init__(
            f"{purpose} needs the optional package '{package}', which is not installed. "
            f"Install it with: pip install 'tactex[{extra}]'"
        )
        self.package = package
        self.extra = extra
