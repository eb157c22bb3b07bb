"""``tactex twin`` as a child process, for tests and scripts: :class:`TwinProcess`.

franky-sim must run in another process than the pylibfranka client (in one process they deadlock:
pylibfranka holds the GIL while it waits for the robot). :class:`TwinProcess` starts ``python -m
tactex.cli twin`` on a loopback address of its own (127.0.0.X, X random in 2..250, so that it does
not clash with a twin the user runs on 127.0.0.1) and a free UDP port for the Net F/T stream,
waits for its ready line, and always reaps it; on Linux the twin also ends when the process that
started it dies without closing it (killed, or by a signal it does not handle).
"""

from __future__ import annotations

import json
import os
import queue
import random
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from tactex.errors import TactexError
from tactex.twin.clock import linux_prctl

__all__ = ["TwinProcess", "end_child", "free_loopback_address"]

_READY = "twin ready:"


def _bindable(host: str, port: int, kind: int) -> bool:
    sock = socket.socket(socket.AF_INET, kind)
    if kind == socket.SOCK_STREAM:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
        return True
    except OSError:
        return False
    finally:
        sock.close()


def _die_with_parent() -> None:
    """In the child, before the twin starts (Linux): SIGTERM when the process that started it dies, even
    by SIGKILL or a signal that skips :meth:`TwinProcess.close`; a twin left behind keeps a core busy.
    Linux ties this to the starting thread: start a twin from a thread that outlives it."""
    linux_prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


def _free_tcp_port(host: str) -> int:
    """A TCP port free on ``host`` now (the twin binds it a moment later)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        sock.bind((host, 0))
        return int(sock.getsockname()[1])
    finally:
        sock.close()


def free_loopback_address(rng: random.Random | None = None, attempts: int = 50) -> tuple[str, int]:
    """(127.0.0.X with TCP 1337 and 1338 free, a free UDP port on it)."""
    rng = rng or random.Random()
    for _ in range(attempts):
        host = f"127.0.0.{rng.randint(2, 250)}"
        if not (_bindable(host, 1337, socket.SOCK_STREAM) and _bindable(host, 1338, socket.SOCK_STREAM)):
            continue
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind((host, 0))
            return host, int(sock.getsockname()[1])
        finally:
            sock.close()
    raise TactexError(f"no free loopback address with TCP 1337/1338 after {attempts} tries (127.0.0.2–250)")


def end_child(proc: subprocess.Popen | None, stderr, timeout_s: float) -> int | None:
    """End a server started as a child: SIGTERM, wait ``timeout_s`` [s], SIGKILL if it is still there;
    always reaps it and closes its stdout pipe and its stderr file (``stderr``, may be None). Its exit
    code, None when there was no process."""
    code = None
    if proc is not None:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                proc.kill()
        code = proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()
    if stderr is not None and not stderr.closed:
        stderr.close()
    return code


class TwinProcess:
    """A ``tactex twin`` child process (context manager).

    Args:
        object_name: the object (``--object``).
        args: further ``tactex twin`` options, e.g. ``["--marking", "full"]``.
        timeout_s: longest wait for the ready line [s]; then the child is killed and
            :class:`~tactex.errors.TactexError` raised with its stderr.
        hostname, ft_port, camera_port: fixed addresses instead of free ones (camera_port 0: no camera).

    Attributes: ``hostname``, ``ft_port``, ``camera_port``, ``status_file``, ``ready_line``, ``process``.
    """

    def __init__(self, object_name: str = "plate", args: list[str] | tuple[str, ...] = (), *,
                 timeout_s: float = 60.0, hostname: str | None = None, ft_port: int | None = None,
                 python: str | None = None, cpus: set[int] | None = None, camera_port: int | None = None) -> None:
        self.cpus = set(cpus) if cpus else None  # cores the twin may run on (None: any)
        if hostname is None or ft_port is None:
            host, port = free_loopback_address()
            hostname = hostname or host
            ft_port = ft_port if ft_port is not None else port
        self.hostname = hostname
        self.ft_port = int(ft_port)
        if camera_port is None:
            camera_port = _free_tcp_port(hostname)
        self.camera_port = int(camera_port)
        self.object_name = object_name
        self._dir = tempfile.TemporaryDirectory(prefix="tactex-twin-")
        self.status_file = Path(self._dir.name) / "status.json"
        self._stderr_path = Path(self._dir.name) / "stderr.txt"
        self.command = [python or sys.executable, "-m", "tactex.cli", "twin", "--object", object_name,
                        "--hostname", hostname, "--port-ft", str(self.ft_port),
                        "--port-camera", str(self.camera_port), "--status-file",
                        str(self.status_file), *args]
        self.timeout_s = float(timeout_s)
        self.process: subprocess.Popen | None = None
        self.ready_line = ""
        self._lines: queue.Queue[str | None] = queue.Queue()
        self.stdout_lines: list[str] = []

    # -- lifecycle ----------------------------------------------------------------------------------
    def start(self) -> TwinProcess:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self._stderr = open(self._stderr_path, "w")
        self.process = subprocess.Popen(self.command, stdout=subprocess.PIPE, stderr=self._stderr, text=True,
                                        env=env, start_new_session=True, preexec_fn=_die_with_parent)
        if self.cpus:  # e.g. off the core a pinned control loop uses
            os.sched_setaffinity(self.process.pid, self.cpus)
        threading.Thread(target=self._read_stdout, daemon=True).start()
        deadline = time.monotonic() + self.timeout_s
        while True:
            left = deadline - time.monotonic()
            try:
                line = self._lines.get(timeout=max(0.01, min(left, 0.5)))
            except queue.Empty:
                line = ""
            if line is None or (left <= 0 and not line.startswith(_READY)):
                why = "exited" if line is None else f"was not ready within {self.timeout_s:g} s"
                self.close()
                raise TactexError(f"tactex twin ({' '.join(self.command[1:])}) {why}; its stderr:\n{self.stderr()}")
            if line.startswith(_READY):
                self.ready_line = line.strip()
                return self

    def _read_stdout(self) -> None:
        assert self.process is not None and self.process.stdout is not None
        for line in self.process.stdout:
            self.stdout_lines.append(line)
            self._lines.put(line)
        self._lines.put(None)

    def stderr(self) -> str:
        """The child's stderr so far."""
        try:
            return self._stderr_path.read_text()
        except OSError:
            return ""

    def status(self) -> dict:
        """The latest status JSON ({} before the first one is written)."""
        try:
            return json.loads(self.status_file.read_text())
        except (OSError, ValueError):
            return {}

    def wait_status(self, predicate, timeout_s: float = 5.0) -> dict:
        """Wait until ``predicate(status)`` holds (the file is rewritten every 0.5 s); the last status."""
        deadline = time.monotonic() + timeout_s
        status = self.status()
        while not predicate(status) and time.monotonic() < deadline:
            time.sleep(0.1)
            status = self.status()
        return status

    def kill(self, sig: int = signal.SIGTERM) -> None:
        """Send ``sig`` to the child (if it still runs)."""
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(sig)

    def close(self, timeout_s: float = 10.0) -> int | None:
        """SIGTERM, wait, SIGKILL if needed; always reaps the child. Its exit code."""
        return end_child(self.process, getattr(self, "_stderr", None), timeout_s)

    def cleanup(self) -> None:
        """close() and remove the temporary folder (status file, stderr)."""
        self.close()
        self._dir.cleanup()

    def __enter__(self) -> TwinProcess:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.cleanup()
