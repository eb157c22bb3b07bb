"""The twin's wait for the client's answer (tactex.twin.command_channel.CommandChannel), on a real UDP socket
with a stand-in for franky-sim's robot server (no franky-sim needed)."""

from __future__ import annotations

import socket
import time

import pytest

from tactex.errors import MissingDependencyError
from tactex.twin.command_channel import CommandChannel, check_franky_internals


class FakeServer:
    """franky-sim's robot server as the twin's loop uses it: a UDP command socket, the next state's
    message id, the per-command hook, and process_commands reading every queued datagram."""

    def __init__(self, close_on_process: bool = False) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self._FrankaServer__udp_socket = self.sock
        self._FrankaServer__message_id = 0
        self.current_motion_id = 1
        self.processed = 0
        self.commands: list[int] = []
        self.close_on_process = close_on_process

    def _handle_udp_command(self, data: bytes) -> None:
        self.commands.append(int.from_bytes(data[:8], "little"))

    def process_commands(self) -> None:
        self.processed += 1
        if self.close_on_process:  # the client's TCP link closed: franky-sim resets and closes the socket
            self.sock.close()
            self._FrankaServer__udp_socket = None
            return
        while True:
            try:
                data = self.sock.recv(1024)
            except BlockingIOError:
                return
            self._handle_udp_command(data)


#: A window long enough that ending well before it tells "at once" from "at the deadline" on a loaded
#: machine [s] (the tests that wait for the deadline use short ones: a lower bound holds under load).
WINDOW_S = 30.0
#: A hang guard past a short window's end [s].
HANG_S = 10.0


@pytest.fixture()
def client():
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    yield sock
    sock.close()


def _send(client, server: FakeServer, answers: int) -> None:
    client.sendto(answers.to_bytes(8, "little") + bytes(64), server.sock.getsockname())


def test_the_answer_to_the_last_state_is_taken_at_once(client):
    server = FakeServer()
    server._FrankaServer__message_id = 8  # states 0..7 sent
    channel = CommandChannel(server)
    assert channel.last_sent() == 7
    _send(client, server, 7)
    t0 = time.monotonic()
    channel.take([server], 7, deadline=t0 + WINDOW_S)
    assert time.monotonic() - t0 < WINDOW_S / 2 and server.processed == 1
    assert channel.answered == 7 and server.commands == [7]  # franky-sim's own handler still runs


def test_without_an_answer_the_window_closes_at_its_deadline(client):
    server = FakeServer()
    server._FrankaServer__message_id = 3
    channel = CommandChannel(server)
    t0 = time.monotonic()
    channel.take([server], 2, deadline=t0 + 0.05)
    assert time.monotonic() - t0 >= 0.045 and server.processed == 1 and channel.answered == -1


def test_a_stale_answer_is_processed_and_the_wait_goes_on(client):
    server = FakeServer()
    server._FrankaServer__message_id = 6
    channel = CommandChannel(server)
    _send(client, server, 4)  # the client answers an older state
    t0 = time.monotonic()
    channel.take([server], 5, deadline=t0 + 0.05)
    assert time.monotonic() - t0 >= 0.045
    assert server.processed == 1 and channel.answered == 4  # not processed a second time for nothing


def test_a_client_that_leaves_mid_window_ends_the_wait_without_error(client):
    server = FakeServer(close_on_process=True)
    server._FrankaServer__message_id = 6
    channel = CommandChannel(server)
    _send(client, server, 4)  # a stale answer wakes the wait; processing it finds the client gone
    t0 = time.monotonic()
    channel.take([server], 5, deadline=t0 + 0.2)
    assert server.processed == 1 and time.monotonic() - t0 < 0.2 + HANG_S  # ends at the window's end


def test_out_of_a_motion_the_commands_are_taken_at_once(client):
    server = FakeServer()
    channel = CommandChannel(server)
    t0 = time.monotonic()
    channel.take([server], 0, deadline=None)
    assert server.processed == 1 and time.monotonic() - t0 < WINDOW_S / 2


def test_a_new_client_restarts_the_count():
    server = FakeServer()
    server._FrankaServer__message_id = 100
    channel = CommandChannel(server)
    channel.answered = 99
    server._FrankaServer__message_id = 2  # franky-sim numbers a new client's states from 0
    assert channel.last_sent() == 1 and channel.answered == -1


def test_a_franky_sim_without_the_members_the_loop_reads_is_named():
    class Bare:
        pass

    with pytest.raises(MissingDependencyError, match=r"_FrankaServer__message_id.*franky-sim>=1\.0,<1\.1"):
        check_franky_internals(Bare())
