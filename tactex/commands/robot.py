"""``tactex robot check --robot-ip IP``: connect to a Franka without moving it and test the 1 kHz link."""

from __future__ import annotations

import argparse
import sys

NAME = "robot"
HELP = "check a real Franka (or tactex twin): set-up, state, and whether the link holds 1 kHz"


def register(parser: argparse.ArgumentParser) -> None:
    from tactex.config import add_dataclass_arguments
    from tactex.robots.libfranka_backend import FrankaConfig

    parser.add_argument("action", choices=("check",), help="check: connect, report, hold still and count lost cycles")
    parser.add_argument("--duration-s", type=float, default=10.0, help="length of the link test [s] (default: 10)")
    from tactex.robots.check import LINK_MAX_LOST_FRACTION, LINK_MIN_SUCCESS_RATE

    default_pct = 100 * LINK_MAX_LOST_FRACTION
    parser.add_argument("--max-lost-percent", type=float, default=default_pct,
                        help=f"fail the link test when more than this share of cycles is lost [%%] "
                             f"(default: {default_pct:g})")
    parser.add_argument("--min-success-rate", type=float, default=LINK_MIN_SUCCESS_RATE,
                        help="fail the link test when the robot's control_command_success_rate (its share of "
                             "the last 100 commands that came in time) falls below this [0–1] "
                             f"(default: {LINK_MIN_SUCCESS_RATE:g})")
    parser.add_argument("--bare", action="store_true",
                        help="hold with Franka's example joint impedance in 7 floats per tick instead of tactex's "
                             "controller and safety layer: the link's floor (what the PC, network and robot allow); "
                             "when the check fails both ways, tactex is not the cause")
    parser.add_argument("--out", metavar="FILE.json", help="also write the findings as JSON")
    add_dataclass_arguments(parser, FrankaConfig)


def run(args: argparse.Namespace) -> int:
    import math

    from tactex.config import dataclass_from_args, write_json
    from tactex.errors import ConfigError
    from tactex.robots.check import check_robot
    from tactex.robots.libfranka_backend import FrankaConfig

    if not (math.isfinite(args.duration_s) and 0 < args.duration_s <= 600):
        raise ConfigError(f"--duration-s must be in (0, 600] s, got {args.duration_s}")
    if not (math.isfinite(args.max_lost_percent) and 0 <= args.max_lost_percent < 100):
        raise ConfigError(f"--max-lost-percent must be in [0, 100) %, got {args.max_lost_percent}")
    if not (math.isfinite(args.min_success_rate) and 0 <= args.min_success_rate <= 1):
        raise ConfigError(f"--min-success-rate must be in [0, 1], got {args.min_success_rate}")
    cfg = dataclass_from_args(FrankaConfig, args)
    result = check_robot(cfg, args.duration_s, note=lambda m: print(f"tactex robot: {m}", file=sys.stderr),
                         max_lost_fraction=args.max_lost_percent / 100.0, min_success_rate=args.min_success_rate,
                         bare=args.bare)
    i = result.info
    print(f"robot {i['robot_ip']}: mode {i.get('robot_mode')}, TCP at {[round(x, 4) for x in i['tcp_position_m']]} m, "
          f"load {i['load_mass_kg']:.3f} kg, wrench source {i['wrench_source']}")
    if "loop_ticks" in i:
        c, p = i["loop_compute_us"], i["loop_period_us"]
        link = "link (bare)" if args.bare else "link"
        print(f"{link}: {i['loop_ticks']} cycles, {i['lost_cycles']} lost, min success rate "
              f"{i['min_command_success_rate']:.3f}, period p50/p99.9 {p['p50']:.0f}/{p['p99.9']:.0f} µs, "
              f"loop compute p50/p99.9 {c['p50']:.0f}/{c['p99.9']:.0f} µs, drift {i['q_drift_rad'] * 1e3:.2f} mrad")
    for w in result.warnings:
        print(f"warning: {w}")
    for pr in result.problems:
        print(f"problem: {pr}")
    if args.out:
        write_json({"ok": result.ok, **i, "problems": result.problems, "warnings": result.warnings}, args.out)
    print("check passed" if result.ok else "check FAILED")
    return 0 if result.ok else 1
