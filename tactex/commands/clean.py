"""``tactex clean --out DIR``: ergodic cleaning of a built-in object in simulation (TEC §V-A)."""

from __future__ import annotations

import argparse

from tactex.commands._task import register_task, run_task_command

NAME = "clean"
HELP = ("clean the marked dirt off an object (tactile ergodic control) in simulation, or on a Franka with "
        "--robot franka, and write a report")


def register(parser: argparse.ArgumentParser) -> None:
    from tactex.tasks.clean import CleanConfig

    register_task(parser, "clean", CleanConfig)


def run(args: argparse.Namespace) -> int:
    from tactex.tasks.clean import CleanConfig

    return run_task_command("clean", CleanConfig, args)
