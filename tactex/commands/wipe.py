"""``tactex wipe --out DIR``: visuo-tactile wiping of an unknown curved surface in simulation (VA-UFIC §III)."""

from __future__ import annotations

import argparse

from tactex.commands._task import register_task, run_task_command

NAME = "wipe"
HELP = ("wipe an unknown curved surface (VA-UFIC force-impedance control) in simulation, or on a Franka with "
        "--robot franka, and write a report")


def register(parser: argparse.ArgumentParser) -> None:
    from tactex.tasks.wipe import WipeConfig

    register_task(parser, "wipe", WipeConfig)


def run(args: argparse.Namespace) -> int:
    from tactex.tasks.wipe import WipeConfig

    return run_task_command("wipe", WipeConfig, args)
