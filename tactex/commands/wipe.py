"""``tactex wipe --out DIR``: visuo-tactile wiping of an unknown curved surface in simulation (VA-UFIC §III)."""

from __future__ import annotations

import argparse
import warnings

from tactex.commands._task import register_task, run_task_command

NAME = "wipe"
HELP = ("wipe an unknown curved surface (VA-UFIC force-impedance control) in simulation, or on a Franka with "
        "--robot franka, and write a report")


def register(parser: argparse.ArgumentParser) -> None:
    from tactex.tasks.wipe import WipeConfig

    register_task(parser, "wipe", WipeConfig)


#: The options of the built-in sinusoid, which a policy file replaces (its own path and force).
SINUSOID_OPTIONS = ("force_n", "amplitude_m", "omega_rad_s", "drift_m_s")


def run(args: argparse.Namespace) -> int:
    from dataclasses import fields

    from tactex.tasks.wipe import WipeConfig

    if getattr(args, "policy", ""):
        defaults = {f.name: f.default for f in fields(WipeConfig)}
        given = [name for name in SINUSOID_OPTIONS if getattr(args, name, None) not in (None, defaults[name])]
        if given:
            warnings.warn(f"{', '.join(given)} set the built-in sinusoid; the policy file '{args.policy}' sets its own "
                          "path and force, so they are not used", stacklevel=2)
    return run_task_command("wipe", WipeConfig, args)
