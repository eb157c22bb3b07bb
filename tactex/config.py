"""Parameter dataclasses ↔ command-line options.

Every parameter set in tactex is a dataclass whose defaults are the papers' values and whose
fields carry ``metadata={"help": "... [unit]"}``. :func:`add_dataclass_arguments` turns such a
class into argparse options (``agent_radius_m`` → ``--agent-radius-m``), so the CLI never drifts from
the code; :func:`dataclass_from_args` builds the instance back, validating through the class.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import typing
import warnings
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from tactex.errors import ConfigError

__all__ = ["accept_old_names", "add_dataclass_arguments", "dataclass_from_args", "option_aliases", "param",
           "to_jsonable", "write_json"]

T = TypeVar("T")


def param(default: Any, help: str, **kw: Any) -> Any:
    """A dataclass field with a help text (units in brackets) used by the generated CLI.

    Metadata the generated CLI reads from ``kw``: ``option`` (the option's own name), ``aliases`` (more
    option strings, hidden from the help), ``old_names`` (former field names: their options are hidden
    aliases, and with :func:`accept_old_names` on the class they work as keywords and attributes too),
    ``cli=False`` (no option), ``unused_with`` (see :func:`dataclass_from_args`)."""
    if isinstance(default, (list, dict, np.ndarray)):
        return dataclasses.field(default_factory=lambda: default, metadata={"help": help, **kw})
    return dataclasses.field(default=default, metadata={"help": help, **kw})


def _option(name: str, prefix: str) -> str:
    return "--" + (prefix + name).replace("_", "-")


def _default_text(default: Any) -> str:
    """A default as a user would type it: tuples as space-separated numbers, nothing for None/''."""
    if default is None or default == "":
        return ""
    if isinstance(default, bool):
        return "on" if default else "off"
    if isinstance(default, (tuple, list)):
        return " ".join(f"{v:g}" if isinstance(v, float) else str(v) for v in default)
    if isinstance(default, float):
        return f"{default:g}"
    return str(default)


def option_aliases(cls: type) -> dict[str, list[str]]:
    """Field name → the option strings of a dataclass's CLI (the first is the one help shows)."""
    out = {}
    for f in dataclasses.fields(cls):
        name = f.metadata.get("option", f.name)
        out[f.name] = [_option(name, ""), *_hidden_options(f, "")]
    return out


def _hidden_options(f: dataclasses.Field, prefix: str) -> list[str]:
    """A field's option strings that work but the help does not show: its aliases and its old names'."""
    return [*f.metadata.get("aliases", ()), *(_option(old, prefix) for old in f.metadata.get("old_names", ()))]


def accept_old_names(cls: type[T]) -> type[T]:
    """Class decorator for a dataclass whose fields were renamed (``param(..., old_names=("old",))``):
    ``cls(old=...)`` still works (a :class:`DeprecationWarning` names the new field) and ``obj.old``
    reads the new field. When a call passes both names, the old one wins: ``dataclasses.replace(obj,
    old=...)`` passes every field by its new name besides the change."""
    renames = {old: f.name for f in dataclasses.fields(cls) for old in f.metadata.get("old_names", ())}
    init = cls.__init__

    @functools.wraps(init)
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        for old, new in renames.items():
            if old in kwargs:
                warnings.warn(f"{cls.__name__}.{old} is now {cls.__name__}.{new}; the old name will go",
                              DeprecationWarning, stacklevel=2)
                kwargs[new] = kwargs.pop(old)
        init(self, *args, **kwargs)

    cls.__init__ = __init__  # type: ignore[method-assign]
    for old, new in renames.items():
        setattr(cls, old, property(lambda self, _new=new: getattr(self, _new), doc=f"The former name of ``{new}``."))
    return cls


def add_dataclass_arguments(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    cls: type,
    *,
    prefix: str = "",
    skip: tuple[str, ...] = (),
) -> None:
    """Add one option per scalar/bool/tuple field of dataclass ``cls``; defaults stay ``None``
    so that only options the user gave override the dataclass defaults.

    A field's metadata may rename its option (``option="object"`` for ``object_name``) and give
    older names that still work (``aliases=("--object-name",)``, or a renamed field's ``old_names``,
    hidden from the help). The help
    shows the default once, as it would be typed; a help text that states its own default (it
    says "default") or a default of None/'' adds nothing."""
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if f.name in skip or f.metadata.get("cli") is False:
            continue
        typ = hints[f.name]
        origin = typing.get_origin(typ)
        args = typing.get_args(typ)
        help_text = f.metadata.get("help", "")
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]
        shown = _default_text(default)
        if shown and "default" not in help_text.lower():
            help_text = f"{help_text} (default: {shown})" if help_text else f"default: {shown}"
        help_text = help_text.replace("%", "%%")
        opt = _option(f.metadata.get("option", f.name), prefix)
        dest = prefix + f.name
        kw: dict[str, Any] | None = None
        if typ is bool:
            kw = {"action": argparse.BooleanOptionalAction}
        elif typ in (int, float, str):
            kw = {"type": typ}
        elif origin is tuple and args and all(a in (int, float) for a in args if a is not Ellipsis):
            kw = {"type": _element_type(args), "nargs": "+" if Ellipsis in args else len(args)}
        elif origin in (typing.Union, getattr(__import__("types"), "UnionType", None)) and args:
            base = next(a for a in args if a is not type(None))
            base_args = typing.get_args(base)
            if base in (int, float, str):
                kw = {"type": base}
            elif (typing.get_origin(base) is tuple and base_args
                  and all(a in (int, float) for a in base_args if a is not Ellipsis)):
                kw = {"type": _element_type(base_args), "nargs": "+" if Ellipsis in base_args else len(base_args)}
        if kw is None:
            continue
        parser.add_argument(opt, dest=dest, default=None, help=help_text, **kw)
        for alias in _hidden_options(f, prefix):
            parser.add_argument(alias, dest=dest, default=None, help=argparse.SUPPRESS, **kw)


def dataclass_from_args(cls: type[T], args: argparse.Namespace, *, prefix: str = "", **overrides: Any) -> T:
    """Instantiate ``cls`` from parsed options (those left at None keep the class default).

    A field with ``unused_with=(other, why)`` in its metadata refuses its option when the user gave it
    and ``other`` is set (:class:`ConfigError` naming both options and ``why``)."""
    kwargs: dict[str, Any] = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        value = getattr(args, prefix + f.name, None)
        if value is not None:
            kwargs[f.name] = tuple(value) if isinstance(value, list) else value
    kwargs.update(overrides)
    try:
        obj = cls(**kwargs)
    except TypeError as exc:
        raise ConfigError(f"invalid parameters for {cls.__name__}: {exc}") from exc
    _check_unused(obj, args, prefix)
    return obj


def _element_type(args: tuple) -> type:
    """A numeric tuple's element type on the command line: int when every element is, else float."""
    return int if all(a is int for a in args if a is not Ellipsis) else float


def _check_unused(obj: Any, args: argparse.Namespace, prefix: str) -> None:
    """Refuse an option the user gave that another option makes meaningless: a field's metadata
    ``unused_with=(other_field, why)`` names the other field (set to a true value) and the reason. Only
    options typed count (their value is not None): a default the other option overrides is no mistake."""
    for f in dataclasses.fields(obj):
        other = f.metadata.get("unused_with")
        if other is None or getattr(args, prefix + f.name, None) is None or not getattr(obj, other[0]):
            continue
        this = _option(f.metadata.get("option", f.name), prefix)
        that_field = next(g for g in dataclasses.fields(obj) if g.name == other[0])
        that = _option(that_field.metadata.get("option", that_field.name), prefix)
        raise ConfigError(f"{this} has no effect with {that}: {other[1]}; drop {this}")


def to_jsonable(obj: Any) -> Any:
    """Convert dataclasses, numpy arrays/scalars and paths into JSON-ready values."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_json(data: Any, path: str | Path) -> Path:
    """Write ``data`` as indented JSON (NaN/inf become null)."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(to_jsonable(data), indent=2) + "\n")
    return out
