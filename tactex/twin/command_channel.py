"""The client's commands as the twin's loop sees them through franky-sim's server, and the check
that this franky-sim has the private members that view reads."""

from __future__ import annotations

import select
import time
from typing import Any

from tactex.errors import MissingDependencyError
from tactex.twin.clock import TwinClock

__all__ = ["CommandChannel", "check_franky_internals"]


class CommandChannel:
    """The client's commands as the twin's loop sees them, through franky-sim's server: which state
    the newest command answered (libfranka sends the state's message id back in the first 8 bytes
    of its UDP command), and a wait for that answer on franky-sim's UDP socket.

    Uses franky-sim's private members (checked by :func:`check_franky_internals`): the UDP socket
    (made when a client connects, closed when it leaves) and the next state's message id.
    """

    def __init__(self, robot_server: Any) -> None:
        self.server = robot_server
        self.answered = -1  # message id of the newest state a command answered
        handle = robot_server._handle_udp_command

        def handle_command(data: bytes) -> None:
            self.answered = max(self.answered, int.from_bytes(data[:8], "little"))
            handle(data)

        robot_server._handle_udp_command = handle_command  # the hook franky-sim calls per UDP command

    def last_sent(self) -> int:
        """Message id of the last state sent (−1: none yet); a new client restarts the count."""
        last = int(self.server._FrankaServer__message_id) - 1
        if last < self.answered:  # franky-sim numbers a new client's states from 0 again
            self.answered = -1
        return last

    def _socket(self) -> Any:
        sock = getattr(self.server, "_FrankaServer__udp_socket", None)
        return sock if sock is not None and sock.fileno() >= 0 else None

    def take(self, servers: list, last: int, deadline: float | None) -> None:
        """Process the commands once the answer to state ``last`` is in, or at ``deadline``
        (monotonic s); at once when ``deadline`` is None. Commands are processed once a cycle,
        more often only when a stale answer came first (each pass then has a new command)."""
        if deadline is not None:
            processed = False
            while self.answered < last:
                left = deadline - time.monotonic()
                sock = self._socket()  # closed when the client leaves, possibly by the last pass
                if left <= 0.0:
                    break
                if sock is None:
                    TwinClock.wait_until(deadline)
                    break
                try:
                    if not select.select([sock], [], [], left)[0]:
                        break
                except (OSError, ValueError):  # closed meanwhile: the client is gone
                    break
                for rs in servers:
                    rs.process_commands()
                processed = True
            if processed:
                return
        for rs in servers:
            rs.process_commands()


def check_franky_internals(robot_server: Any) -> None:
    """Fail early when franky-sim lacks the members the twin's loop reads (tested with 1.0.x)."""
    needed = ("_FrankaServer__message_id", "_FrankaServer__udp_socket", "_handle_udp_command", "current_motion_id")
    missing = [name for name in needed if not hasattr(robot_server, name)]
    if missing:
        import importlib.metadata

        version = importlib.metadata.version("franky-sim")
        raise MissingDependencyError("franky-sim", "franka", "tactex twin", fix=(
            f"franky-sim {version} lacks {', '.join(missing)}, which the twin's loop reads; install the "
            "version tactex is tested with: pip install 'franky-sim>=1.0,<1.1'"))
