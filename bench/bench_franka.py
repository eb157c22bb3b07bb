"""The real-robot path over libfranka's protocol: ``tactex twin`` (franky-sim with our scene) on
loopback, driven by ``tactex wipe`` / ``tactex clean --robot franka`` as separate processes, as a
user runs them. The twin runs on core 0, the control loop pinned to core 1 (``--control-cpu 1``,
SCHED_FIFO when allowed), the vision process beside the twin.

Figures: the wipe's force error and tanks (VA-UFIC §III policy, Net F/T and vision), the loop's
timing (``loop_compute_us``: our share of each 1 ms cycle, target p99.9 ≤ 300 µs), lost cycles,
the twin's command success rate (commands within its 0.5 ms window), torque-rate clips; the clean's
share of the twin's marking removed (the twin measures it). ``link_floor``: ``tactex robot check --bare``
on the same twin just before the wipe (Franka's example joint hold in 7 floats per tick, no vision
process): what this machine allows a loop that does almost nothing, beside which the wipe's figures
read as tactex's share. Skipped without the ``franka`` extra or with fewer than two cores.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

TARGETS = {
    "franka.wipe.force_mae_n": ("<=", 1.0),
    "franka.wipe.lost_cycles": ("<=", 0),
    "franka.wipe.loop_compute_us_p999": ("<=", 300.0),
    "franka.wipe.min_command_success_rate": (">=", 0.99),
    "franka.wipe.torque_rate_clip_ticks": ("<=", 0),
    "franka.clean.dirt_removed_fraction": (">=", 0.90),
    "franka.clean.lost_cycles": ("<=", 0),
}


def _cli(args: list[str], check: bool = True) -> subprocess.CompletedProcess:
    """Run ``tactex ARGS``; with ``check``, a non-zero exit raises with the end of its stderr."""
    done = subprocess.run([sys.executable, "-m", "tactex.cli", *args], stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True)
    if check and done.returncode != 0:
        raise RuntimeError(f"tactex {' '.join(args[:3])} ... ended with {done.returncode}: "
                           f"{done.stderr.strip()[-1500:]}")
    return done


def _timing(m: dict) -> dict:
    return {
        "loop_compute_us_p50": m["loop_compute_us"]["p50"],
        "loop_compute_us_p999": m["loop_compute_us"]["p99.9"],
        "loop_period_us_p999": m["loop_period_us"]["p99.9"],
        "lost_cycles": m["lost_cycles"],
        "min_command_success_rate": m["min_command_success_rate"],
    }


def _loop(m: dict) -> dict:
    return {**_timing(m), "torque_rate_clip_ticks": m["torque_rate_clip_ticks"]}


def run(args) -> dict:
    if importlib.util.find_spec("pylibfranka") is None or importlib.util.find_spec("franky_sim") is None:
        print("   skipped: needs the franka extra")
        return {}
    if (os.cpu_count() or 1) < 2:
        print("   skipped: needs two cores (twin and control loop apart)")
        return {}
    from tactex.twin.process import TwinProcess

    quick = getattr(args, "quick", False)
    out: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp_p = Path(tmp)
        with TwinProcess("sine_panel", cpus={0}) as twin:
            # the check exits non-zero when the link fails; its figures are what is wanted either way
            floor = tmp_p / "floor.json"
            check = _cli(["robot", "check", "--robot-ip", twin.hostname, "--bare", "--control-cpu", "1",
                          "--duration-s", "5" if quick else "10", "--out", str(floor)], check=False)
            if floor.exists():
                out["link_floor"] = _timing(json.loads(floor.read_text()))
            else:  # the check did not get as far as the link test; the wipe and clean still run
                print(f"   link floor not measured: tactex robot check --bare ended with {check.returncode}: "
                      f"{check.stderr.strip()[-500:]}")
            _cli(["wipe", "--robot", "franka", "--robot-ip", twin.hostname, "--ft",
                  f"netft:{twin.hostname}:{twin.ft_port}", "--control-cpu", "1", "--quiet", "--no-video",
                  "--duration-s", "5" if quick else "20", "--out", str(tmp_p / "wipe")])
            m = json.loads((tmp_p / "wipe" / "metrics.json").read_text())
        ti, tf = m["tank_impedance_energy_j"], m["tank_force_energy_j"]
        (li, hi), (lf, hf) = m["tank_impedance_limits_j"], m["tank_force_limits_j"]
        out["wipe"] = {"force_mae_n": m["force_mae_n"], "force_rmse_n": m["force_rmse_n"],
                       "tanks_in_limits": float(li <= ti["min"] and ti["max"] <= hi and lf <= tf["min"]
                                                and tf["max"] <= hf),
                       "vision_estimates": m.get("vision_process_estimates", 0), **_loop(m)}
        with TwinProcess("plate", cpus={0}) as twin:
            cloud = tmp_p / "plate.ply"
            _cli(["twin", "--object", "plate", "--export-cloud", str(cloud)])
            _cli(["clean", "--robot", "franka", "--robot-ip", twin.hostname, "--ft",
                  f"netft:{twin.hostname}:{twin.ft_port}", "--control-cpu", "1", "--quiet", "--no-video",
                  "--cloud", str(cloud), "--budget-s", "30" if quick else "60", "--out", str(tmp_p / "clean")])
            m = json.loads((tmp_p / "clean" / "metrics.json").read_text())
            status = twin.status()
        out["clean"] = {"dirt_removed_fraction": status["dirt_removed_fraction"],
                        "force_within_20pct_fraction": m["force_within_20pct_fraction"],
                        "max_contact_force_n": m["max_contact_force_n"], **_loop(m)}
    return {"franka": out}
