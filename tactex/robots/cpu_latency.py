"""Hold the CPUs out of deep idle states while torque control runs (Linux PM QoS).

Between two states from the robot the control thread sleeps in ``readOnce`` for most of the
millisecond. An idle CPU then enters an idle state, and leaving it again costs wake-up latency
before the state is even read: tens of microseconds from a deep C-state on a desktop CPU, and on a
virtual machine a halted virtual CPU waits for the host to run it again. Writing a latency bound to
``/dev/cpu_dma_latency`` and keeping the file open limits the idle states the kernel may choose; 0
keeps idle CPUs polling. The request ends when the file is closed (or the process exits), so a
crashed run cannot leave it behind. This is what ``cyclictest`` does by default and what real-time
tuning guides (e.g. Red Hat's "Controlling power management transitions") ask of a real-time
application; it costs power, not CPU time of other programs.
"""

from __future__ import annotations

import os
import struct

from tactex.errors import ConfigError

#: The PM QoS device: a 32-bit latency bound [µs] written to it holds while the file is open.
PM_QOS_DEVICE = "/dev/cpu_dma_latency"


class CpuLatencyRequest:
    """A held PM QoS request: CPUs may only enter idle states that wake within ``latency_us``.

    ``latency_us`` < 0 makes no request. Without permission (the device is root's unless a udev
    rule says otherwise, docs/real_robot.md) or without the device, nothing is held and
    :attr:`description` says why; the run goes on.
    """

    def __init__(self, latency_us: int, device: str | None = None) -> None:
        if isinstance(latency_us, bool) or not isinstance(latency_us, int):
            raise ConfigError(f"cpu_latency_us must be a whole number of microseconds (-1: no request), "
                              f"got {latency_us!r}")
        self.latency_us = latency_us
        self._fd: int | None = None
        if latency_us < 0:
            self.description = "idle states not limited"
            return
        device = device or PM_QOS_DEVICE
        try:
            fd = os.open(device, os.O_WRONLY)
        except OSError as exc:
            self.description = f"idle states not limited ({device}: {exc.strerror})"
            return
        try:
            os.write(fd, struct.pack("i", latency_us))
        except OSError as exc:
            os.close(fd)
            self.description = f"idle states not limited ({device}: {exc.strerror})"
            return
        self._fd = fd
        self.description = f"idle wake-up latency held at ≤ {latency_us} µs"

    @property
    def held(self) -> bool:
        return self._fd is not None

    def release(self) -> None:
        """End the request (idempotent)."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
