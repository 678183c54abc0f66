"""The operating-system calls of V4L2 capture (:mod:`acq.drivers.camera_v4l2`).

:class:`V4L2System` is what the driver calls (open, close, ioctl on ctypes structures,
mmap, poll); :class:`OsV4L2` makes the real calls, and a test puts a fake kernel device
behind the same protocol.
"""

from __future__ import annotations

import fcntl
import mmap
import os
import select
from typing import Any, Protocol

__all__ = ["Buffer", "OsV4L2", "V4L2System"]


class Buffer(Protocol):
    """A mapped buffer: sliceable into bytes (``mmap.mmap``, or a test's ``bytearray``)."""

    def __getitem__(self, index: slice, /) -> bytes | bytearray: ...
    def __len__(self) -> int: ...


class V4L2System(Protocol):
    """The operating-system calls the driver makes (one object per driver)."""

    def open(self, path: str) -> int:
        """Open a device node read-write, non-blocking; returns a file descriptor."""
        ...

    def close(self, fd: int) -> None: ...

    def ioctl(self, fd: int, request: int, arg: Any) -> None:
        """The ioctl, reading and writing the ctypes structure ``arg`` in place.

        Raises OSError with the kernel's errno."""
        ...

    def mmap(self, fd: int, length: int, offset: int) -> Buffer:
        """Map ``length`` bytes of the device at ``offset`` (shared, read-write)."""
        ...

    def munmap(self, buffer: Buffer) -> None: ...

    def wait_readable(self, fd: int, timeout: float) -> bool:
        """True when ``fd`` is readable (a buffer is done) or in error within ``timeout`` s."""
        ...


class OsV4L2:
    """The real calls: ``os.open``, ``fcntl.ioctl``, ``mmap.mmap``, ``select.poll``."""

    def open(self, path: str) -> int:
        return os.open(path, os.O_RDWR | os.O_NONBLOCK | os.O_CLOEXEC)

    def close(self, fd: int) -> None:
        os.close(fd)

    def ioctl(self, fd: int, request: int, arg: Any) -> None:
        while True:
            try:
                fcntl.ioctl(fd, request, arg, True)
                return
            except InterruptedError:
                continue

    def mmap(self, fd: int, length: int, offset: int) -> Buffer:
        return mmap.mmap(
            fd, length, flags=mmap.MAP_SHARED, prot=mmap.PROT_READ | mmap.PROT_WRITE, offset=offset
        )

    def munmap(self, buffer: Buffer) -> None:
        if isinstance(buffer, mmap.mmap):
            buffer.close()

    def wait_readable(self, fd: int, timeout: float) -> bool:
        poller = select.poll()
        poller.register(fd, select.POLLIN | select.POLLPRI | select.POLLERR | select.POLLHUP)
        return bool(poller.poll(max(0, int(timeout * 1000.0 + 0.999))))
