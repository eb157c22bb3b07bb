"""franka-sim, an independent emulator of a Franka's FCI checks, as a child process: :class:`FrankaSimProcess`.

`franka-sim <https://pypi.org/project/franka-sim/>`_ (Apache-2.0, written by nobody here) serves
libfranka's protocol over its own MuJoCo FR3 and implements what our twin does not check: the
robot's motion-limit checker (joint position/velocity/acceleration/jerk limits, torque range,
``controller_torque_discontinuity`` at 1000 N·m/s) and its communication constraints (20
consecutive lost command cycles abort the motion, counted in cycles, so a stalled simulator is not
counted against the client). It pins numpy 1.26 and mujoco < 3.3, so it lives in an environment of
its own (``tools/franka-sim``: its pyproject and uv.lock; ``make franka-sim-env``) and runs as a
separate process: :mod:`tactex.twin.franka_sim_serve`, run by that environment's Python, binds one
loopback address (franka-sim's own launcher binds every interface).

Its FR3 model is franky-sim's ``fr3.xml`` (the ``franka`` extra ships it; franka-sim would
download one) with its mesh folder made absolute, the Franka hand on the flange: other inertias,
joint friction and damping than tactex's MuJoCo world, and a hand where our tool should be. With
``box`` a box is added to its world before it compiles. franka-sim reports no external wrench
(``K_F_ext_hat_K`` stays zero), so a contact there is felt only through the arm's motion.

Every violation franka-sim finds is logged on its stderr, enforced or not: :meth:`FrankaSimProcess.violations`.
"""

from __future__ import annotations

import os
import queue
import re
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from tactex.errors import InputError, MissingDependencyError, TactexError
from tactex.twin.process import _die_with_parent, end_child, free_loopback_address

__all__ = [
    "DEFAULT_PRIORITY", "FRANKA_SIM_PYTHON_ENV", "Box", "FrankaSimProcess", "franka_sim_python", "write_fr3_mjcf",
]

#: Names the Python of franka-sim's environment (default: ``.venv-franka-sim/bin/python`` in the checkout).
FRANKA_SIM_PYTHON_ENV = "TACTEX_FRANKA_SIM_PYTHON"
_READY = "franka-sim ready:"
#: franka-sim's log lines for a check that failed: a motion-limit violation (logged whether enforced or
#: not), an abort, a communication-constraint violation.
_VIOLATION = re.compile(r"motion limit violated|aborting the motion|communication_constraints_violation")
#: franka-sim's own report of its pace, every 5 s: "simulation running at 0.52x real time".
_PACE = re.compile(r"simulation running at ([0-9.]+)x real time")


def franka_sim_python() -> Path | None:
    """The interpreter of franka-sim's environment: ``$TACTEX_FRANKA_SIM_PYTHON``, else the checkout's
    ``.venv-franka-sim`` (built by ``make franka-sim-env``); None when there is none."""
    given = os.environ.get(FRANKA_SIM_PYTHON_ENV)
    if given:
        return Path(given) if Path(given).is_file() else None
    default = Path(__file__).resolve().parents[2] / ".venv-franka-sim" / "bin" / "python"
    return default if default.is_file() else None


@dataclass(frozen=True)
class Box:
    """A box in franka-sim's world: centre [m] in the robot base frame, half extents [m]."""

    center: tuple[float, float, float]
    half_size: tuple[float, float, float]

    def __post_init__(self) -> None:
        vals = [*self.center, *self.half_size]
        if len(self.center) != 3 or len(self.half_size) != 3 or not all(isinstance(v, (int, float)) for v in vals) \
                or not all(abs(v) < 10 for v in vals) or min(self.half_size) <= 0:
            raise InputError(f"Box needs a centre and three positive half sizes in metres, got {self!r}")


def write_fr3_mjcf(path: str | Path, box: Box | None = None) -> Path:
    """franky-sim's FR3 model (``fr3.xml``, hand included) with its mesh folder made absolute, and
    ``box`` (if given) in its world, written to ``path``."""
    import xml.etree.ElementTree as ET

    try:
        import franky_sim
    except ImportError as exc:
        raise MissingDependencyError("franky_sim", "franka", "franka-sim's FR3 model (franky-sim's fr3.xml)") from exc
    assets = Path(franky_sim.__file__).resolve().parent / "assets"
    root = ET.parse(assets / "fr3.xml").getroot()
    compiler = root.find("compiler")
    if compiler is None:
        compiler = ET.SubElement(root, "compiler")
    compiler.set("meshdir", str(assets / "meshes"))
    _flange_as_link7(root)
    if box is not None:
        world = root.find("worldbody")
        assert world is not None  # franky-sim's model has one
        body = ET.SubElement(world, "body", name="tactex_box", pos=" ".join(f"{v:.6g}" for v in box.center))
        ET.SubElement(body, "geom", name="tactex_box", type="box", size=" ".join(f"{v:.6g}" for v in box.half_size),
                      rgba="0.8 0.8 0.8 1", friction="0.4 0.005 0.0001")
    path = Path(path)
    ET.ElementTree(root).write(path)
    return path


#: The FR3's flange along link7's z axis [m] (franky-sim's hand sits there).
FLANGE_OFFSET_M = 0.107


def _flange_as_link7(root) -> None:
    """Make the body franka-sim reports as the flange the FR3's flange. franka-sim takes the origin of the
    body ``<prefix>link7`` as the flange (``O_T_EE`` = link7 · F_T_EE), where the FR3's flange is 107 mm
    further along link7's z (libfranka's model, from the URDF franka-sim serves, puts it there): over
    franky-sim's model every pose it reports would be short by that offset along the tool axis. The link
    keeps its joint, mass and meshes under another name; a massless body named ``fr3_link7`` at the
    flange carries the hand."""
    import xml.etree.ElementTree as ET

    link7 = next((b for b in root.iter("body") if b.get("name") == "fr3_link7"), None)
    if link7 is None:
        raise InputError("franky-sim's fr3.xml has no body fr3_link7: cannot place the flange for franka-sim")
    link7.set("name", "fr3_link7_arm")
    flange = ET.SubElement(link7, "body", name="fr3_link7", pos=f"0 0 {FLANGE_OFFSET_M}")
    for child in [c for c in link7 if c.tag == "body" and c is not flange]:
        link7.remove(child)
        pos = [float(v) for v in child.get("pos", "0 0 0").split()]
        child.set("pos", f"{pos[0]:.6g} {pos[1]:.6g} {pos[2] - FLANGE_OFFSET_M:.6g}")
        flange.append(child)


#: franka-sim's SCHED_FIFO priority: under the control loop's (80 where tactex pins it, 99 where libfranka
#: raises it), over everything at the normal priority.
DEFAULT_PRIORITY = 70


def _scheduling_of(pid: int) -> str:
    """A process's scheduling policy and priority, one line ("SCHED_FIFO 80")."""
    try:
        policy = os.sched_getscheduler(pid)
        priority = os.sched_getparam(pid).sched_priority
    except (OSError, AttributeError):
        return "unknown"
    name = {getattr(os, n, None): n for n in ("SCHED_OTHER", "SCHED_FIFO", "SCHED_RR", "SCHED_BATCH")}.get(policy)
    return f"{name or policy} {priority}"


class FrankaSimProcess:
    """franka-sim on a loopback address of its own (context manager).

    Args:
        enforce: its motion limits and communication constraints abort a motion, as on the robot
            (False: they are checked and logged only).
        box: a box in its world (None: nothing but its ground plane).
        python: franka-sim's interpreter (default :func:`franka_sim_python`).
        timeout_s: longest wait for the ready line [s].
        priority: SCHED_FIFO priority franka-sim runs at where the system allows it (root, or an rtprio
            limit); None: the normal priority. The robot's controller has a computer of its own and keeps
            its 1 kHz whatever ours does; an emulator sharing our cores keeps it only if nothing else runs
            first. Below the control loop's, so the loop is never preempted
            by its robot; franka-sim sleeps between its steps, so it takes only the CPU it needs.

    Attributes: ``hostname``, ``process``, ``ready_line``, ``scheduling`` (what franka-sim runs at, one line).

    Raises:
        MissingDependencyError: no franka-sim environment (``make franka-sim-env``).
        TactexError: franka-sim exited or was not ready in time (its stderr attached).
    """

    def __init__(self, *, enforce: bool = True, box: Box | None = None, python: str | Path | None = None,
                 timeout_s: float = 90.0, priority: int | None = DEFAULT_PRIORITY) -> None:
        py = Path(python) if python is not None else franka_sim_python()
        if py is None or not py.is_file():
            raise MissingDependencyError(
                "franka-sim", "", "The franka-sim rehearsal target",
                fix="It runs in an environment of its own: build it with `make franka-sim-env` (from "
                    f"tools/franka-sim/uv.lock), or name its Python in ${FRANKA_SIM_PYTHON_ENV}.")
        self.hostname, _ = free_loopback_address()
        self._dir = tempfile.TemporaryDirectory(prefix="tactex-franka-sim-")
        self.mjcf = write_fr3_mjcf(Path(self._dir.name) / "fr3.xml", box)
        self._stderr_path = Path(self._dir.name) / "stderr.txt"
        serve = Path(__file__).resolve().parent / "franka_sim_serve.py"
        self.command = [str(py), str(serve), "--host", self.hostname, *([] if enforce else ["--no-enforce"])]
        self.timeout_s = float(timeout_s)
        self.priority = priority
        self.scheduling = "not started"
        self.process: subprocess.Popen | None = None
        self.ready_line = ""
        self._lines: queue.Queue[str | None] = queue.Queue()

    def start(self) -> FrankaSimProcess:
        env = dict(os.environ, PYTHONUNBUFFERED="1", FR3_MJCF=str(self.mjcf))
        env.pop("PYTHONPATH", None)  # its own environment only
        self._stderr = open(self._stderr_path, "w")
        self.process = subprocess.Popen(self.command, stdout=subprocess.PIPE, stderr=self._stderr, text=True, env=env,
                                        start_new_session=True, preexec_fn=self._in_child)
        self.scheduling = _scheduling_of(self.process.pid)
        threading.Thread(target=self._read_stdout, daemon=True).start()
        deadline = time.monotonic() + self.timeout_s
        while True:
            try:
                line = self._lines.get(timeout=max(0.01, min(deadline - time.monotonic(), 0.5)))
            except queue.Empty:
                line = ""
            if line is not None and line.startswith(_READY):
                self.ready_line = line.strip()
                return self
            if line is None or time.monotonic() > deadline:
                why = "exited" if line is None else f"was not ready within {self.timeout_s:g} s"
                self.close()
                raise TactexError(f"franka-sim ({' '.join(self.command)}) {why}; its stderr:\n{self.stderr()[-4000:]}")

    def _in_child(self) -> None:
        """Before franka-sim starts: die with us, and take the real-time priority if allowed (every thread
        franka-sim starts inherits it). Without the permission it runs at the normal priority."""
        _die_with_parent()
        if self.priority is not None and hasattr(os, "sched_setscheduler"):
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.priority))
            except OSError:
                pass

    def _read_stdout(self) -> None:
        assert self.process is not None and self.process.stdout is not None
        for line in self.process.stdout:
            self._lines.put(line)
        self._lines.put(None)

    def stderr(self) -> str:
        """franka-sim's log so far."""
        try:
            return self._stderr_path.read_text(errors="replace")
        except OSError:
            return ""

    def violations(self) -> list[str]:
        """Every check franka-sim logged as failed so far (motion limits, aborts, lost commands)."""
        return [line for line in self.stderr().splitlines() if _VIOLATION.search(line)]

    def realtime_factors(self) -> list[float]:
        """franka-sim's real-time factors as it logged them so far (every 5 s while it runs behind): below 1
        its physics lags its state clock and it sends the same state again with its clock advanced."""
        return [float(m.group(1)) for m in _PACE.finditer(self.stderr())]

    def close(self, timeout_s: float = 20.0) -> int | None:
        """SIGTERM, wait, SIGKILL if needed; always reaps the child. Its exit code."""
        return end_child(self.process, getattr(self, "_stderr", None), timeout_s)

    def __enter__(self) -> FrankaSimProcess:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()
        self._dir.cleanup()
