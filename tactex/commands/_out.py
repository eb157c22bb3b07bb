"""``--force`` and the run-folder check shared by the commands that write a run folder (not a command itself)."""

from __future__ import annotations

import argparse

#: What each command does with a folder that already holds a run of its own (``--help`` says it).
_OWN = {
    "sweep": "resumed (the settings already done are read back)",
    "study": "resumed",
    "demo": "replaced",
}


#: The commands whose --force also lifts the basis size cap (tactex.spectral.estimate).
_BASIS_CAP = ("explore", "sweep", "clean")


def add_force_argument(parser: argparse.ArgumentParser, command: str) -> None:
    """``--force``: write into an ``--out`` folder that holds another run (refused without it)."""
    own = _OWN.get(command)
    parser.add_argument(
        "--force", action="store_true",
        help="write into an --out folder that holds another run (its status.json or metrics.json); without --force "
             "such a folder is refused" + (f", except a {command}'s own, which is {own}" if own else "")
             + "; files of the same name are replaced, others stay"
             + ("; also builds the Laplace basis of a cloud over 200 000 points (refused without it, with its "
                "estimated time and memory and the voxel size that fits)" if command in _BASIS_CAP else ""))


def check_out(args: argparse.Namespace, command: str) -> None:
    """Refuse ``args.out`` if it holds another run and ``--force`` was not given (before any work)."""
    from tactex.experiments.run_folder import check_run_folder

    check_run_folder(args.out, command, force=args.force, own=command in _OWN)
    args._out_taken = True  # the folder is this run's now: status.json there says how it ended
