"""The length unit of a cloud or mesh file (``--units m|mm|in``), applied when the file is read, before the
points are checked: tactex works in metres, CAD parts come in millimetres or inches.

Also the hints for a file read in the wrong unit: one over :data:`~tactex.pointcloud.cloud.MAX_EXTENT_M`
is refused as millimetres (or inches, when its size in inches is a part's); one between
:data:`INCH_HINT_MIN_M` and that limit passes, with a note that it may be in inches.
"""

from __future__ import annotations

import numpy as np

from tactex.errors import ConfigError

__all__ = ["INCH_HINT_MAX_UNITS", "INCH_HINT_MIN_M", "METRES_PER", "METRE_HINT_MAX_M", "UNITS", "check_units",
           "inch_hint", "metre_hint", "millimetre_hint", "to_metres"]

#: Metres per file unit.
METRES_PER = {"m": 1.0, "mm": 1e-3, "in": 0.0254}
#: The ``--units`` choices.
UNITS = tuple(METRES_PER)
#: Above this extent [m] a part read in metres is wider than a robot arm reaches (a Franka: 0.855 m), so a
#: file in inches (a 5-inch part read as 5 m) is the likelier reading; the run still goes on, with a note.
INCH_HINT_MIN_M = 2.0
#: A file up to this many units wide may be in inches (2.5 m then); a wider one refused as too big is
#: millimetres.
INCH_HINT_MAX_UNITS = 100.0


def check_units(units: object) -> str:
    """``units`` if it is one of :data:`UNITS`, else :class:`ConfigError` naming them."""
    if units not in METRES_PER:
        raise ConfigError(f"units={units!r} is not a length unit; give one of {', '.join(UNITS)} (the file's unit: "
                          "a CAD part is often in mm or in)")
    return str(units)


def to_metres(values: np.ndarray, units: str) -> np.ndarray:
    """``values`` in ``units`` as metres (float64). Millimetres are divided by 1000 (exact for a value that is
    a whole number of millimetres' worth of metres, so a file in mm gives the points of its twin in m)."""
    arr = np.asarray(values, dtype=np.float64)
    units = check_units(units)
    if units == "m":
        return arr
    if units == "mm":
        return arr / 1000.0
    return arr * METRES_PER[units]


def inch_hint(extent: float) -> str:
    """For a file ``extent`` units wide read as metres: the clause suggesting inches, '' when implausible."""
    if not INCH_HINT_MIN_M < extent <= INCH_HINT_MAX_UNITS:
        return ""
    return f"if it is in inches ({extent * METRES_PER['in']:.3g} m wide then), give units=in"


#: Below this extent [m] a file read in millimetres or inches is smaller than any part a sponge cleans; when its
#: size as metres is a part's, it is a file in metres read in the wrong unit.
METRE_HINT_MAX_M = 0.005


def metre_hint(extent_m: float, units: str) -> str:
    """For a file ``extent_m`` [m] wide after reading it in ``units``: the clause saying it is probably in metres,
    '' when it is not that small or its size in metres would not be a part's either."""
    if units == "m" or not 0.0 < extent_m < METRE_HINT_MAX_M:
        return ""
    as_metres = extent_m / METRES_PER[units]
    if not METRE_HINT_MAX_M <= as_metres <= 2.0:
        return ""
    return (f"it spans {extent_m * 1e3:.3g} mm read with units={units}, smaller than any part a sponge cleans; it is "
            f"probably in metres ({as_metres:.3g} m wide then): give units=m")


def millimetre_hint(extent: float, units: str = "m") -> str:
    """What to do with a file ``extent`` [m] wide once read in ``units``, refused as too wide (in metres, its
    numbers are ``extent``; in inches or millimetres they are that over the unit)."""
    if units == "m":
        inches = inch_hint(extent)
        return ("it is probably in millimetres: give units=mm (or convert it to metres)"
                + (f"; {inches}" if inches else ""))
    numbers = extent / METRES_PER[check_units(units)]  # its width in the file's own numbers
    if units == "in":
        return (f"read in inches it is {extent:.3g} m wide; if it is in millimetres ({numbers * 1e-3:.3g} m wide "
                "then), give units=mm")
    return f"even read in millimetres it is {extent:.3g} m wide: check the file's unit and scale"
