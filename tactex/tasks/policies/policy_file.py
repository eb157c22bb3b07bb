"""The policy file: segments of any kind, one after another, in TOML::

    blend_s = 0.5          # optional: velocity jumps at the joins are blended over this [s]

    [[segment]]            # segments run one after another
    kind = "spiral"        # sinusoid | line | zigzag | spiral | circle | figure8 | samples
    duration_s = 6.0
    force_n = 10.0         # a number, or [start, end] for a linear ramp over the segment
    radius_m = 0.035       # spiral/circle: radius_m, turns; line: length_m, direction_deg;
    turns = 2.5            # zigzag: width_m, length_m, lanes; figure8: width_m, height_m (turns);
                           # sinusoid: amplitude_m, omega_rad_s, drift_m_s; samples: file (relative to
                           # this file; its force_n column is the set point, its time the duration)

Every refusal is a :class:`ConfigError` of one line naming the segment and the field.
"""

from __future__ import annotations

import inspect
import math
from pathlib import Path
from typing import Any

from tactex.errors import ConfigError, InputError, MissingDependencyError, PolicyFileError
from tactex.tasks.policies.base import ForceRamp, PolicySegment
from tactex.tasks.policies.circle import CirclePolicy
from tactex.tasks.policies.figure8 import Figure8Policy
from tactex.tasks.policies.line import LinePolicy
from tactex.tasks.policies.samples import SamplesPolicy, read_sample_lines
from tactex.tasks.policies.sequence import PolicySequence
from tactex.tasks.policies.sinusoid import SinusoidPolicy
from tactex.tasks.policies.spiral import SpiralPolicy
from tactex.tasks.policies.zigzag import ZigzagPolicy

__all__ = ["POLICY_KINDS", "load_policy_file", "policy_from_dict"]

#: Kind name → its class (one file each).
POLICY_KINDS: dict[str, type[PolicySegment]] = {
    c.kind: c for c in (SinusoidPolicy, LinePolicy, ZigzagPolicy, SpiralPolicy, CirclePolicy, Figure8Policy,
                        SamplesPolicy)}
#: Fields that may be 0 (a drift, a direction); every other length or count must be > 0.
_MAY_BE_ZERO = {"drift_m_s", "direction_deg", "amplitude_m"}
#: Fields that may be negative (a direction).
_MAY_BE_NEGATIVE = {"direction_deg"}


#: A length in a policy file over this is no stroke an arm makes on a part [m]: millimetres typed as metres.
MAX_LENGTH_M = 1.0


def _number(where: str, name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{where}: {name} must be a finite number, got {value!r:.40}")
    if name not in _MAY_BE_NEGATIVE and (value < 0 or (value == 0 and name not in _MAY_BE_ZERO)):
        raise ConfigError(f"{where}: {name} = {value!r} must be {'≥' if name in _MAY_BE_ZERO else '>'} 0")
    if name.endswith("_m") and value > MAX_LENGTH_M:
        raise ConfigError(f"{where}: {name} = {value!r} m is longer than any stroke on a part: lengths are in "
                          f"metres ({value!r} mm is {value / 1000:g})")
    return float(value)


def _force(where: str, value: Any) -> ForceRamp:
    if isinstance(value, list):
        if len(value) != 2:
            raise ConfigError(f"{where}: force_n must be a number or [start, end], got a list of {len(value)}")
        a, b = (_number(where, "force_n", v) for v in value)
        return ForceRamp(a, b)
    a = _number(where, "force_n", value)
    return ForceRamp(a, a)


def _segment(k: int, table: Any, folder: Path) -> PolicySegment:
    where = f"segment {k}"
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: must be a table ([[segment]] with kind = ...), got {table!r:.40}")
    kind = table.get("kind")
    if kind is None:
        raise ConfigError(f"{where}: missing field kind; valid: {', '.join(POLICY_KINDS)}")
    cls = POLICY_KINDS.get(kind) if isinstance(kind, str) else None
    if cls is None:
        raise ConfigError(f"{where}: kind: unknown kind {kind!r:.40}; valid: {', '.join(POLICY_KINDS)}")
    where = f"segment {k} ({kind})"
    if cls is SamplesPolicy:
        extra = sorted(set(table) - {"kind", "file"})
        if extra:
            raise ConfigError(f"{where}: {extra[0]}: not a field of samples (its file gives time and force); "
                              "valid: kind, file")
        if not isinstance(table.get("file"), str) or not table["file"]:
            raise ConfigError(f"{where}: missing field file (a CSV t_s,u_m,v_m,force_n, relative to the policy file)")
        try:
            samples, lines = read_sample_lines(folder / table["file"])
            return SamplesPolicy(samples, source=table["file"], lines=lines)
        except InputError as exc:
            raise ConfigError(f"{where}: file: {exc}") from None
    params = list(inspect.signature(cls.__init__).parameters.values())[3:]  # after self, duration_s, force
    known = {"kind", "duration_s", "force_n", *(p.name for p in params)}
    extra = sorted(set(table) - known)
    if extra:
        raise ConfigError(f"{where}: {extra[0]}: not a field of {kind}; valid: {', '.join(sorted(known))}")
    for name in ("duration_s", "force_n"):
        if name not in table:
            raise ConfigError(f"{where}: missing field {name}")
    duration = _number(where, "duration_s", table["duration_s"])
    kwargs: dict[str, Any] = {}
    for p in params:
        if p.name not in table:
            if p.default is inspect.Parameter.empty:
                raise ConfigError(f"{where}: missing field {p.name}")
            continue
        v = table[p.name]
        if p.name == "lanes":
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ConfigError(f"{where}: lanes must be a whole number ≥ 1, got {v!r:.40}")
            kwargs[p.name] = v
        else:
            kwargs[p.name] = _number(where, p.name, v)
    return cls(duration, _force(where, table["force_n"]), **kwargs)


def policy_from_dict(data: dict[str, Any], folder: str | Path = ".") -> PolicySequence:
    """A :class:`PolicySequence` from a policy file's tables (``folder`` resolves ``samples`` files)."""
    unknown = sorted(set(data) - {"segment", "blend_s"})
    if unknown:
        raise ConfigError(f"policy: unknown key '{unknown[0]}' at the top; valid: blend_s, [[segment]]")
    segments = data.get("segment")
    if isinstance(segments, dict):  # [segment]: one table, not an array of them
        raise ConfigError("policy: [segment] is one table; write [[segment]] (double brackets) above each segment")
    if not isinstance(segments, list) or not segments:
        raise ConfigError("policy: no [[segment]] tables; give at least one segment")
    blend = data.get("blend_s", 0.0)
    if isinstance(blend, bool) or not isinstance(blend, (int, float)) or not math.isfinite(blend) or blend < 0:
        raise ConfigError(f"policy: blend_s must be a number of seconds ≥ 0, got {blend!r:.40}")
    return PolicySequence([_segment(k, t, Path(folder)) for k, t in enumerate(segments, start=1)], float(blend))


def load_policy_file(path: str | Path) -> PolicySequence:
    """The policy of a TOML file (module docstring); unchecked against a task's limits
    (:func:`~tactex.tasks.policies.check.check_policy` does that)."""
    try:
        import tomllib
    except ImportError:  # Python 3.10
        try:
            import tomli as tomllib
        except ImportError as exc:
            raise MissingDependencyError("tomli", "", "reading a policy file on Python 3.10",
                                         fix="pip install tomli") from exc
    p = Path(path).expanduser()
    if p.suffix.lower() != ".toml":
        hint = (f"; a CSV of samples goes in one, as a [[segment]] with kind = \"samples\" and file = \"{p.name}\""
                if p.suffix.lower() == ".csv" else "")
        raise PolicyFileError(f"policy file '{p}': give a .toml file{hint}")
    if not p.is_file():
        raise PolicyFileError(f"policy file '{p}' does not exist")
    try:
        data = tomllib.loads(p.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise PolicyFileError(f"policy file '{p}' is not valid TOML: {exc}") from None
    try:
        return policy_from_dict(data, p.parent)
    except ConfigError as exc:
        raise PolicyFileError(f"policy file '{p}': {exc}") from None
