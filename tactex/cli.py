"""The ``tactex`` command: discovers the sub-commands in :mod:`tactex.commands`."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import os
import pkgutil
import re
import signal
import sys
import threading
import time
import typing
import warnings
from collections.abc import Sequence
from pathlib import Path

from tactex import __version__
from tactex.errors import PolicyFileError, RunInterrupted, RunStopped, TactexError

__all__ = ["build_parser", "main"]


def _command_modules() -> list:
    import tactex.commands as pkg

    mods = [importlib.import_module(f"tactex.commands.{m.name}") for m in pkgutil.iter_modules(pkg.__path__)]
    return sorted((m for m in mods if hasattr(m, "run")), key=lambda m: m.NAME)


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors: the option and what is wrong, then where the help is (argparse
    would print the whole usage first, dozens of lines for clean)."""

    def error(self, message: str) -> typing.NoReturn:
        message = re.sub(r"invalid int value: ('[^']*')", r"needs a whole number, got \1", message)
        message = re.sub(r"invalid float value: ('[^']*')", r"needs a number, got \1", message)
        message = message.replace("argument ", "", 1) if message.startswith("argument ") else message
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")

    def _get_option_tuples(self, option_string: str) -> list:
        # An abbreviation matching an option and its alias (--object, --object-name) is not ambiguous.
        tuples = super()._get_option_tuples(option_string)
        seen: set[str] = set()
        unique = []
        for t in tuples:
            if t[0].dest not in seen:
                seen.add(t[0].dest)
                unique.append(t)
        return unique


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
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


# "HedacConfig.max_snap_distance_voxels" / "n_eigen=200" in library messages: the names a Python caller sets.
# Only words that stand alone (after a space or "(") outside quotes: quoted spans are the user's own
# paths and values ('runs/seed=3/x.ply'), which must come back as typed.
_CONFIG_FIELD = re.compile(r"(?:^|(?<=[\s(]))[A-Z]\w*(?:Config|Params)\.([a-z_][a-z0-9_]*)\b")
_FIELD_VALUE = re.compile(r"(?:^|(?<=[\s(]))([a-z][a-z0-9_]*)=([^\s,;)'\"]+)")
_QUOTED = re.compile(r"('[^']*'|\"[^\"]*\")")


# "voxel_size_m must ..." / "force_n = 3 N": a field named bare, with an underscore (never an English
# word) or followed by "must"/"=": the library's way of naming a parameter.
_FIELD_EQ = re.compile(r"(?:^|(?<=[\s(]))([a-z][a-z0-9_]*) = ([^\s,;)'\"]+)")
_FIELD_WORD = re.compile(r"(?:^|(?<=[\s(]))([a-z][a-z0-9]*_[a-z0-9_]+|[a-z]+(?= must\b))(?![\w=-])")


def _typed_options(parser: argparse.ArgumentParser, argv: Sequence[str], command: str | None) -> dict[str, str]:
    """Destination → the option string the user gave for it (an alias as typed, an abbreviation as
    the option it stands for)."""
    sub = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
    cmd_parser = sub.choices.get(command) if sub is not None and command else None
    if cmd_parser is None:
        return {}
    strings = cmd_parser._option_string_actions
    typed: dict[str, str] = {}
    for token in argv:
        if not token.startswith("--") or token == "--":
            continue
        word = token.split("=", 1)[0]
        action = strings.get(word)
        if action is None:
            matches = [s for s in strings if s.startswith(word)]
            if len({id(strings[m]) for m in matches}) != 1:
                continue
            word, action = matches[0], strings[matches[0]]
        if action.dest not in typed and action.dest != "help":
            typed[action.dest] = word
    return typed


def _cli_words(message: str, args: argparse.Namespace, typed: dict[str, str] | None = None) -> str:
    """``message`` with the config fields this command exposes named as the options the user typed
    (or, if not typed, as the command's option for them)."""
    options = vars(args)
    typed = typed or {}
    canonical = getattr(args, "_options", {})

    def name_of(field: str) -> str:
        return typed.get(field) or canonical.get(field) or f"--{field.replace('_', '-')}"

    def option(m: re.Match) -> str:  # group 1 the field, group 2 (field=value only) its value
        name = m.group(1)
        if name not in options or name.startswith("_"):
            return m.group(0)
        value = m.group(2) if m.re in (_FIELD_VALUE, _FIELD_EQ) else None
        return name_of(name) + ("" if value is None else f" {value}")

    def words(part: str) -> str:
        for pattern in (_CONFIG_FIELD, _FIELD_VALUE, _FIELD_EQ, _FIELD_WORD):
            part = pattern.sub(option, part)
        return part

    parts = _QUOTED.split(message)  # odd indices are the quoted spans
    text = "".join(part if i % 2 else words(part) for i, part in enumerate(parts))
    return _once(text)


def _once(text: str) -> str:
    """Drop a repeated "--opt value" echo: "--steps -1: --steps -1 must be ..." says it twice."""
    m = re.match(r"(--[\w-]+(?: \S+)?): (.*)$", text)
    if m and m.group(2).startswith(m.group(1)):
        return m.group(2)
    return text


def _show_warning(args: argparse.Namespace, typed: dict[str, str]):
    """Python warnings as one plain line, "tactex explore: warning: ...", without file and line, the
    parameters it names named as options."""

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        text = _cli_words(str(message), args, typed)
        own = f"{args.command}: "
        text = text[len(own):] if text.startswith(own) else text  # the library's "clean: ..." says it twice
        print(f"tactex {args.command}: warning: {text}", file=sys.stderr, flush=True)

    return show


def _write_status(args: argparse.Namespace, argv: Sequence[str], status: str, started: float,
                  error: str | None = None) -> None:
    """status.json in the run folder, if the command made one or took over one that held a run (see
    :func:`_held_run`): what was asked, how it ended, and why."""
    out = getattr(args, "out", None)
    if not out or not Path(out).is_dir() or not getattr(args, "_out_taken", True):
        return
    data = {
        "command": args.command,
        "argv": list(argv),
        "options": {k: v for k, v in vars(args).items() if not k.startswith("_")},
        "status": status,
        "error": error,
        "started": time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(started)),
        "wall_time_s": round(time.time() - started, 3),
    }
    with contextlib.suppress(OSError):  # a folder we cannot write must not hide the error itself
        (Path(out) / "status.json").write_text(json.dumps(data, indent=2, default=str) + "\n")


def _held_run(args: argparse.Namespace) -> None:
    """Note whether ``--out`` already holds a run: then only a command that took the folder over
    (:func:`tactex.commands._out.check_out` sets ``_out_taken``) writes status.json there; one refused,
    or stopped by a bad option before its check, leaves the other run's status alone."""
    out = getattr(args, "out", None)
    if isinstance(out, str) and out and Path(out).expanduser().is_dir():
        from tactex.experiments.run_folder import run_in_folder

        if run_in_folder(out) is not None:
            args._out_taken = False


def _canonical_options(parser: argparse.ArgumentParser, command: str | None) -> dict[str, str]:
    """Destination → the option a command's help shows for it."""
    sub = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
    cmd_parser = sub.choices.get(command) if sub is not None and command else None
    if cmd_parser is None:
        return {}
    return {a.dest: a.option_strings[0] for a in cmd_parser._actions
            if a.option_strings and a.help != argparse.SUPPRESS and a.dest not in ("help",)}


#: Signals that end a run as Ctrl-C does (torque control ended, what was done saved, ``status.json``): a
#: ``kill``, ``timeout``, ``docker stop`` or ``systemctl stop`` (SIGTERM), a closed terminal or SSH session
#: (SIGHUP).
STOP_SIGNALS = ("SIGTERM", "SIGHUP")


@contextlib.contextmanager
def _stop_on_signals():
    """While in the block, :data:`STOP_SIGNALS` raise ``KeyboardInterrupt`` in the main thread (once: a second one
    while the run saves its data is ignored); the dict it gives gets the first one received under ``"signal"``.
    After a SIGHUP the terminal is gone: output goes to /dev/null, so that writing progress cannot fail the
    saving. The handlers before are put back after the block (a caller's own process, a test's)."""
    received: dict[str, signal.Signals] = {}
    if threading.current_thread() is not threading.main_thread():
        yield received
        return

    def stop(signum, frame) -> None:
        if received:
            return
        received["signal"] = signal.Signals(signum)
        if signum == getattr(signal, "SIGHUP", None):
            with contextlib.suppress(OSError):
                null = os.open(os.devnull, os.O_WRONLY)
                os.dup2(null, 1)
                os.dup2(null, 2)
        raise KeyboardInterrupt(received["signal"].name)

    kinds = [getattr(signal, name) for name in STOP_SIGNALS if hasattr(signal, name)]
    before = {kind: signal.signal(kind, stop) for kind in kinds}
    try:
        yield received
    finally:
        for kind, handler in before.items():
            signal.signal(kind, handler)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; bad input prints one line and returns a non-zero code, never a traceback.

    Python warnings reach the user as one line each, without a source path. When the command made
    its run folder (``--out``), ``status.json`` there says how the run ended: done, failed (with the
    error) or interrupted (Ctrl-C, exit code 130: explore, sweep, clean and wipe save what they had
    done first, marked ``"partial": true``; SIGTERM and SIGHUP the same, exit code 143 and 129)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:  # named by the command's own parser: "tactex explore: error: unrecognized arguments: ..."
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        (sub.choices.get(getattr(args, "command", None)) or parser).error(f"unrecognized arguments: {' '.join(extra)}")
    if not hasattr(args, "_run"):
        parser.print_help()
        return 2
    args._options = _canonical_options(parser, args.command)
    typed = _typed_options(parser, argv, args.command)
    _held_run(args)
    started = time.time()
    with warnings.catch_warnings(), _stop_on_signals() as received:
        warnings.showwarning = _show_warning(args, typed)
        try:
            code = int(args._run(args) or 0)
        except RunStopped as exc:  # a run that started and stopped with nothing to keep: as one that kept its data
            print(f"tactex {args.command}: stopped early: {exc}", file=sys.stderr)
            _write_status(args, argv, "stopped early", started, str(exc))
            return 1
        except TactexError as exc:
            # a policy file's field names are the file's own, not options
            message = str(exc) if isinstance(exc, PolicyFileError) else _cli_words(str(exc), args, typed)
            print(f"tactex {args.command}: error: {message}", file=sys.stderr)
            _write_status(args, argv, "failed", started, message)
            return 2
        except OSError as exc:  # a file system refusal the checks up front did not foresee (disk full, ...)
            where = f" ('{exc.filename}')" if exc.filename else ""
            message = f"{exc.strerror or exc}{where}"
            print(f"tactex {args.command}: error: {message}", file=sys.stderr)
            _write_status(args, argv, "failed", started, message)
            return 2
        except KeyboardInterrupt as exc:  # a RunInterrupted says what the run saved, and where
            kept = f"; {exc}" if isinstance(exc, RunInterrupted) and str(exc) else ""
            by = received.get("signal")
            print(f"tactex {args.command}: interrupted{f' by {by.name}' if by else ''}{kept}", file=sys.stderr)
            _write_status(args, argv, "interrupted", started,
                          f"interrupted by {by.name if by else 'the user (Ctrl-C)'}{kept}")
            return 128 + int(by) if by else 130
    _write_status(args, argv, "done" if code == 0 else "stopped early", started)
    return code


if __name__ == "__main__":
    sys.exit(main())
