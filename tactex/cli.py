"""The ``tactex`` command: discovers the sub-commands in :mod:`tactex.commands`."""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import re
import sys
from collections.abc import Sequence

from tactex import __version__
from tactex.errors import TactexError

__all__ = ["build_parser", "main"]


def _command_modules() -> list:
    import tactex.commands as pkg

    mods = [importlib.import_module(f"tactex.commands.{m.name}") for m in pkgutil.iter_modules(pkg.__path__)]
    return sorted((m for m in mods if hasattr(m, "run")), key=lambda m: m.NAME)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tactex",
        description="Tactile exploration: ergodic coverage on point clouds and visuo-tactile force control.",
    )
    parser.add_argument("--version", action="version", version=f"tactex {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for mod in _command_modules():
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP)
        mod.register(p)
        p.set_defaults(_run=mod.run)
    return parser


# "HedacConfig.max_snap_distance" / "n_eigen=200" in library messages: the names a Python caller sets.
# Only words that stand alone (after a space or "(") outside quotes: quoted spans are the user's own
# paths and values ('runs/seed=3/x.ply'), which must come back as typed.
_CONFIG_FIELD = re.compile(r"(?:^|(?<=[\s(]))[A-Z]\w*(?:Config|Params)\.([a-z_][a-z0-9_]*)\b")
_FIELD_VALUE = re.compile(r"(?:^|(?<=[\s(]))([a-z][a-z0-9_]*)=([^\s,;)'\"]+)")
_QUOTED = re.compile(r"('[^']*'|\"[^\"]*\")")


def _cli_words(message: str, args: argparse.Namespace) -> str:
    """``message`` with the config fields this command exposes as options named as those options."""
    options = vars(args)

    def option(m: re.Match) -> str:  # group 1 the field, group 2 (field=value only) its value
        name = m.group(1)
        if name not in options:
            return m.group(0)
        value = m.group(2) if m.re is _FIELD_VALUE else None
        return f"--{name.replace('_', '-')}" + ("" if value is None else f" {value}")

    parts = _QUOTED.split(message)  # odd indices are the quoted spans
    return "".join(
        part if i % 2 else _FIELD_VALUE.sub(option, _CONFIG_FIELD.sub(option, part)) for i, part in enumerate(parts)
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; bad input prints one line and returns a non-zero code, never a traceback."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "_run"):
        parser.print_help()
        return 2
    try:
        return int(args._run(args) or 0)
    except TactexError as exc:
        print(f"tactex {args.command}: error: {_cli_words(str(exc), args)}", file=sys.stderr)
        return 2
    except OSError as exc:  # a file system refusal the checks up front did not foresee (disk full, ...)
        where = f" ('{exc.filename}')" if exc.filename else ""
        print(f"tactex {args.command}: error: {exc.strerror or exc}{where}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"tactex {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
