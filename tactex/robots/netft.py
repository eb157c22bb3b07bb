"""ATI Net F/T over UDP: the RDT (Raw Data Transfer) protocol, client and server.

The Net F/T box answers on UDP port 49152. A request is 8 bytes, big-endian::

    uint16 header = 0x1234, uint16 command, uint32 sample_count (0 = stream until stopped)

with command 0 (stop), 2 (start real-time streaming) or 0x42 (set the box's software bias). Each
record it streams back is 36 bytes, big-endian::

    uint32 rdt_sequence, uint32 ft_sequence, uint32 status, int32 Fx, Fy, Fz, Tx, Ty, Tz

in *counts*; counts per newton and per newton-metre come from the sensor's calibration (the box's
web page, ``netftapi2.xml``: ``cfgcpf`` and ``cfgcpt``; 1 000 000 on most calibrations).

:class:`NetFTClient` polls the stream from the control loop and keeps the latest record with its
arrival time; it tares at start and reports a stream that stops (its reading goes non-finite, which the
safety layer treats as a lost sensor). :class:`NetFTServer` is the box's side, used by ``tactex
twin`` to publish the simulated wrist sensor: it answers the same requests on loopback.
"""

from __future__ import annotations

import math
import socket
import struct
import threading
import time
from collections.abc import Callable

import numpy as np

from tactex.errors import ConfigError, SensorFault

__all__ = [
    "NETFT_PORT",
    "NetFTClient",
    "NetFTServer",
    "pack_record",
    "pack_request",
    "parse_netft_address",
    "unpack_record",
    "unpack_request",
]

NETFT_PORT = 49152
RDT_HEADER = 0x1234
CMD_STOP = 0x0000
CMD_START_REALTIME = 0x0002
CMD_SET_BIAS = 0x0042
_REQUEST = struct.Struct(">HHI")
_RECORD = struct.Struct(">III6i")
RECORD_SIZE = _RECORD.size  # 36 bytes
_INT32_MAX = 2**31 - 1


def pack_request(command: int, sample_count: int = 0) -> bytes:
    """An RDT request (8 bytes): ``command`` (0 stop, 2 stream, 0x42 bias) for ``sample_count``
    records (0: until stopped)."""
    return _REQUEST.pack(RDT_HEADER, command, sample_count)


def unpack_request(data: bytes) -> tuple[int, int]:
    """(command, sample_count) of an RDT request; ValueError for anything else."""
    if len(data) != _REQUEST.size:
        raise ValueError(f"an RDT request is {_REQUEST.size} bytes, got {len(data)}")
    header, command, count = _REQUEST.unpack(data)
    if header != RDT_HEADER:
        raise ValueError(f"RDT header 0x{header:04x}, expected 0x{RDT_HEADER:04x}")
    return command, count


def pack_record(rdt_sequence: int, ft_sequence: int, status: int, wrench: np.ndarray,
                counts_per_force: float, counts_per_torque: float) -> bytes:
    """An RDT record (36 bytes) of ``wrench`` [N, N·m] (6,) in counts (saturated at int32)."""
    scale = (counts_per_force,) * 3 + (counts_per_torque,) * 3
    counts = [max(-_INT32_MAX, min(_INT32_MAX, round(float(w) * s))) for w, s in zip(wrench, scale, strict=True)]
    return _RECORD.pack(rdt_sequence & 0xFFFFFFFF, ft_sequence & 0xFFFFFFFF, status & 0xFFFFFFFF, *counts)


def unpack_record(data: bytes, counts_per_force: float, counts_per_torque: float) -> tuple[int, int, int, np.ndarray]:
    """(rdt_sequence, ft_sequence, status, wrench [N, N·m] (6,)) of one 36-byte RDT record."""
    if len(data) != RECORD_SIZE:
        raise ValueError(f"an RDT record is {RECORD_SIZE} bytes, got {len(data)}")
    rdt, ft, status, *counts = _RECORD.unpack(data)
    wrench = np.array(counts, dtype=float)
    wrench[:3] /= counts_per_force
    wrench[3:] /= counts_per_torque
    return rdt, ft, status, wrench


def parse_netft_address(text: str) -> tuple[str, int]:
    """``HOST`` or ``HOST:PORT`` (the ``--ft netft:HOST[:PORT]`` value after ``netft:``) → (host, port)."""
    host, _, port = text.strip().rpartition(":") if text.count(":") == 1 else (text.strip(), "", "")
    if not host:
        raise ConfigError(f"--ft netft:HOST[:PORT] needs a host, got 'netft:{text}'")
    if port:
        try:
            number = int(port)
        except ValueError:
            number = -1
        if not 0 < number < 65536:
            raise ConfigError(f"--ft netft:{text}: the port must be a number in 1..65535, got {port!r}")
        return host, number
    return host, NETFT_PORT


class NetFTClient:
    """Reads a Net F/T box's stream; :meth:`latest` drains what arrived and never blocks.

    No thread: the control loop polls the socket each tick (a few µs). A receiving thread in the
    control process would starve, since pylibfranka holds the GIL while it waits for the robot.

    Args:
        host, port: the box (``192.168.1.1``, 49152 by default).
        counts_per_force, counts_per_torque: the calibration's counts per N and per N·m.
        timeout_s: a stream silent for this long is lost: :meth:`latest` returns NaN and
            :attr:`lost` is True until records arrive again [s].
        tare_samples: records averaged at :meth:`start` and subtracted from every reading (the
            sensor's bias with the tool at rest; 0 disables the tare).
    """

    def __init__(self, host: str, port: int = NETFT_PORT, *, counts_per_force: float = 1e6,
                 counts_per_torque: float = 1e6, timeout_s: float = 0.05, tare_samples: int = 100) -> None:
        for name, v in (("counts_per_force", counts_per_force), ("counts_per_torque", counts_per_torque),
                        ("timeout_s", timeout_s)):
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"NetFTClient: {name} must be a positive number, got {v!r}")
        if int(tare_samples) != tare_samples or tare_samples < 0:
            raise ConfigError(f"NetFTClient: tare_samples must be an integer ≥ 0, got {tare_samples!r}")
        self.address = (host, int(port))
        self.counts_per_force = float(counts_per_force)
        self.counts_per_torque = float(counts_per_torque)
        self.timeout_s = float(timeout_s)
        self.tare_samples = int(tare_samples)
        self.bias = np.zeros(6)
        self.records = 0
        self.dropouts = 0  # records missing from the RDT sequence
        self.status_errors = 0  # records whose status word flags a sensor error
        self._latest = np.full(6, np.nan)
        self._stamp = -math.inf  # time.monotonic() of the latest record's arrival [s]
        self._polled_at = -math.inf  # time.monotonic() of the last look at the socket [s]
        self._rdt_last: int | None = None
        self._sock: socket.socket | None = None

    def start(self, wait_s: float = 2.0) -> None:
        """Open the socket, request the stream, wait for the first records and tare.

        Raises:
            SensorFault: no record arrived within ``wait_s`` (box off, wrong address, a firewall).
        """
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setblocking(False)
        sock.connect(self.address)
        self._sock = sock
        deadline = time.monotonic() + wait_s
        need = max(1, self.tare_samples)
        samples: list[np.ndarray] = []
        next_request = 0.0
        while time.monotonic() < deadline and len(samples) < need:
            if self.records == 0 and time.monotonic() >= next_request:  # UDP: ask again until it streams
                try:
                    sock.send(pack_request(CMD_START_REALTIME, 0))
                except OSError:  # nothing listens there (yet): ICMP refused the last request
                    pass
                next_request = time.monotonic() + 0.2
            seen = self.records
            self.poll()
            if self.records > seen:
                samples.append(self._latest.copy())
            time.sleep(0.001)
        if not samples:
            self.close()
            raise SensorFault(
                f"the Net F/T at {self.address[0]}:{self.address[1]} sent no data within {wait_s:g} s: check that it "
                "is on and reachable (its web page answers), the address (--ft netft:HOST[:PORT]) and that no "
                "firewall drops UDP port 49152")
        if self.tare_samples:
            self.bias = np.mean(samples, axis=0)

    def poll(self) -> int:
        """Read every record waiting in the socket (keeping the newest); the number read."""
        sock = self._sock
        self._polled_at = time.monotonic()
        if sock is None:
            return 0
        n = 0
        while True:
            try:
                data = sock.recv(RECORD_SIZE * 4)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # ICMP port unreachable: the box is gone for now
                break
            if len(data) < RECORD_SIZE:
                continue
            rdt, _ft, status, wrench = unpack_record(data[:RECORD_SIZE], self.counts_per_force,
                                                     self.counts_per_torque)
            if self._rdt_last is not None and rdt > self._rdt_last + 1:
                self.dropouts += rdt - self._rdt_last - 1
            self._rdt_last = rdt
            self.status_errors += int(status != 0)
            self._latest = wrench
            n += 1
        if n:
            self._stamp = self._polled_at
            self.records += n
        return n

    def latest(self, poll: bool = True) -> tuple[np.ndarray, float]:
        """(wrench [N, N·m] (6,) in the sensor frame, tared; its age [s]). NaN when the stream is lost.
        ``poll=False`` skips reading the socket (the caller has just called :meth:`poll`)."""
        if poll:
            self.poll()
        # the age at the last look: a reading fresh when the socket was read is not stale because
        # the caller then waited (a robot cycle that came late is the robot's delay, not the sensor's)
        age = self._polled_at - self._stamp
        if age > self.timeout_s:
            return np.full(6, np.nan), age
        return self._latest - self.bias, age

    @property
    def lost(self) -> bool:
        """True while no record arrived within ``timeout_s``."""
        self.poll()
        return self._polled_at - self._stamp > self.timeout_s

    def close(self) -> None:
        """Ask the box to stop streaming and close the socket (idempotent)."""
        if self._sock is not None:
            try:
                self._sock.send(pack_request(CMD_STOP, 0))
            except OSError:
                pass
            self._sock.close()
            self._sock = None


class NetFTServer:
    """The box's side of RDT on ``host:port``: streams ``wrench_fn()`` [N, N·m] (6,) at ``rate_hz``
    to the last client that asked, until it sends stop. A bias request zeroes the stream at the
    current reading (as the box's software bias does).

    :meth:`start` streams from a thread of its own; ``tactex twin`` instead calls :meth:`pump` from
    its simulation step. ``wrench_fn`` is called from whichever thread sends.
    """

    def __init__(self, wrench_fn: Callable[[], np.ndarray], host: str = "127.0.0.1", port: int = NETFT_PORT, *,
                 rate_hz: float = 1000.0, counts_per_force: float = 1e6, counts_per_torque: float = 1e6) -> None:
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ConfigError(f"NetFTServer: rate_hz must be a positive number, got {rate_hz!r}")
        self.wrench_fn = wrench_fn
        self.period_s = 1.0 / float(rate_hz)
        self.counts_per_force = float(counts_per_force)
        self.counts_per_torque = float(counts_per_torque)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, int(port)))
        self.sock.setblocking(False)
        self.address = self.sock.getsockname()
        self.sent = 0
        self.paused = threading.Event()  # set: records are not sent (a test's dead stream)
        self._seq = 0
        self._bias = np.zeros(6)
        self._client: tuple[str, int] | None = None
        self._remaining = 0  # records left to send; -1: until stopped
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="netft-server", daemon=True)

    def start(self) -> NetFTServer:
        self._thread.start()
        return self

    def _handle_requests(self) -> None:
        while True:
            try:
                data, addr = self.sock.recvfrom(64)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            try:
                command, count = unpack_request(data)
            except ValueError:
                continue  # the box ignores malformed requests
            if command == CMD_START_REALTIME:
                self._client, self._remaining = addr, (count if count > 0 else -1)
            elif command == CMD_STOP:
                self._remaining = 0
            elif command == CMD_SET_BIAS:
                self._bias = np.asarray(self.wrench_fn(), dtype=float).copy()

    def pump(self, wrench: np.ndarray | None = None) -> None:
        """Answer pending requests and send one record of ``wrench`` (default ``wrench_fn()``) now.

        For a simulation that samples its sensor at each physics step: called from the step, in the
        simulation's own thread, it streams one record per step with no extra latency (a thread of
        its own waits for the GIL and sends late, in bursts)."""
        self._handle_requests()
        if self._client is None or self._remaining == 0 or self.paused.is_set():
            return
        w = np.asarray(self.wrench_fn() if wrench is None else wrench, dtype=float) - self._bias
        status = 0 if np.all(np.isfinite(w)) else 0x80000000
        self._seq += 1
        record = pack_record(self._seq, self._seq, status, np.nan_to_num(w), self.counts_per_force,
                             self.counts_per_torque)
        try:
            self.sock.sendto(record, self._client)
            self.sent += 1
        except OSError:
            pass
        if self._remaining > 0:
            self._remaining -= 1

    def _serve(self) -> None:
        next_t = time.monotonic()
        while not self._stop.is_set():
            self.pump()
            next_t += self.period_s
            delay = next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                next_t = time.monotonic()  # late: do not burst to catch up

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)
        self.sock.close()
