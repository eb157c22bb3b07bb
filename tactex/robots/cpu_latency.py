"""Hold the CPUs out of deep idle states while torque control runs (Linux PM QoS).

Between two states from the robot the control thread sleeps in ``readOnce`` for most of the
millisecond. An idle CPU then enters an idle state, and leaving it again costs wake-up latency
before the state is even read: tens of microseconds from a deep C-state on a desktop CPU, and on a
virtual machine a halted virtual CPU waits for the host to run it again. Writing a latency bound to
``/dev/cpu_dma_latency`` and keeping the file open limits the idle states the kernel may choose; 0
keeps idle CPUs polling. The request ends when the file is closed (or the process exits), so a
crashed run cannot leave it behind. This is what ``cyclictest`` does by default and what real-time
tuning guides (e.g. Red Hat's "Controlling power management transitions") ask of a real-time
application. Polling CPUs draw more power, and on a virtual machine they keep their host threads busy.
"""

from __future__ import annotations

import errno
import os
import stat
import struct

from tactex.errors import ConfigError

#: The PM QoS device: a 32-bit latency bound [µs] written to it holds while the file is open.
PM_QOS_DEVICE = "/dev/cpu_dma_latency"
#: The largest bound the device takes (a signed 32-bit value) [µs].
MAX_LATENCY_US = 2**31 - 1


def check_latency_us(latency_us: object, name: str = "cpu_latency_us") -> int:
    """``latency_us`` as an int in [-1, :data:`MAX_LATENCY_US`] (-1: no request), else ConfigError."""
    if isinstance(latency_us, bool) or not isinstance(latency_us, int) or not -1 <= latency_us <= MAX_LATENCY_US:
        raise ConfigError(f"{name} must be a whole number of microseconds in 0..{MAX_LATENCY_US}, or -1 "
                          f"(no request), got {latency_us!r}")
    return latency_us


def _is_pm_qos_device(fd: int) -> bool:
    """A character device, as the kernel's PM QoS node is (a regular file would take the write and
    hold nothing)."""
    return stat.S_ISCHR(os.fstat(fd).st_mode)


class CpuLatencyRequest:
    """A held PM QoS request: CPUs may only enter idle states that wake within ``latency_us``.

    ``latency_us`` = -1 makes no request. Without permission (the device is root's unless a udev
    rule says otherwise, docs/real_robot.md) or without the device, nothing is held,
    :attr:`description` says why and :attr:`refused_errno` keeps the error; the run goes on.
    """

    def __init__(self, latency_us: int, device: str | None = None) -> None:
        self.latency_us = check_latency_us(latency_us)
        self._fd: int | None = None
        self.refused_errno = 0
        if latency_us < 0:
            self.description = "idle states not limited"
            return
        device = device or PM_QOS_DEVICE
        request = struct.pack("=i", latency_us)  # the kernel reads 4 bytes as a native s32
        try:
            # non-blocking: a FIFO at that path must not hang the set-up
            fd = os.open(device, os.O_WRONLY | os.O_NONBLOCK | os.O_CLOEXEC)
        except OSError as exc:
            self._refused(device, exc.errno, exc.strerror)
            return
        try:
            if not _is_pm_qos_device(fd):
                self._refused(device, errno.ENODEV, "not a PM QoS device")
                os.close(fd)
                return
            if os.write(fd, request) != len(request):
                self._refused(device, errno.EIO, "short write")
                os.close(fd)
                return
        except OSError as exc:
            os.close(fd)
            self._refused(device, exc.errno, exc.strerror)
            return
        self._fd = fd
        self.description = f"idle wake-up latency held at ≤ {latency_us} µs"

    def _refused(self, device: str, err: int, why: str) -> None:
        self.refused_errno = err
        self.description = f"idle states not limited ({device}: {why})"

    @property
    def held(self) -> bool:
        return self._fd is not None

    @property
    def permission_denied(self) -> bool:
        """The device is there but this user may not write it (a udev rule helps)."""
        return self.refused_errno in (errno.EACCES, errno.EPERM)

    def release(self) -> None:
        """End the request (idempotent)."""
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)
