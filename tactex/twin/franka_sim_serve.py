"""Serve franka-sim (an independent FCI emulator) on one loopback address; runs in .venv-franka-sim.

franka-sim's own ``run-franka-sim-server`` binds every interface (0.0.0.0:1337), which would clash
with a ``tactex twin`` or a second emulator on this machine; this launcher binds the address it is
given. It prints ``franka-sim ready: HOST:PORT`` once the FCI port is bound and served and the physics
loop starts, then serves until SIGTERM/SIGINT. (franka-sim's own health check cannot be used on
127.0.0.X: its state datagrams leave from 127.0.0.1, which the check discards as a stranger's.)

Usage: serve.py --host 127.0.0.X [--port 1337] [--no-enforce]. ``$FR3_MJCF`` names the arm model
(tactex writes one from franky-sim's fr3.xml, optionally with a box in its world: no download). Run
by :class:`tactex.twin.franka_sim_process.FrankaSimProcess`; imports nothing of tactex.
Every motion-limit violation and communication abort is logged by franka-sim on stderr.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys


def main() -> int:
    # run by path: its folder (tactex/twin) heads sys.path, and nothing of tactex may shadow franka-sim's modules
    here = os.path.dirname(os.path.abspath(__file__))
    sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != here]
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--host", required=True)
    parser.add_argument("--port", type=int, default=1337)
    parser.add_argument("--no-enforce", action="store_true",
                        help="check and log the limits and the command loss, but do not abort on them")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    from franka_sim import FrankaSimServer

    enforce = not args.no_enforce
    server = FrankaSimServer(host=args.host, port=args.port, enable_gripper=False,
                             enforce_comm_constraints=enforce, enforce_motion_limits=enforce)

    step_loop = server.physics_sim.start

    def ready_then_step() -> None:  # start() calls it once the FCI port is bound and served
        print(f"franka-sim ready: {args.host}:{args.port} enforce={enforce}", flush=True)
        step_loop()

    server.physics_sim.start = ready_then_step

    def stop(*_: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, stop)
    try:
        server.start()
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
