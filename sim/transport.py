"""Serving a simulated device on a real transport: TCP on 127.0.0.1, or a pseudo-terminal.

A device (``SimDevice``) is a protocol state machine that turns the client's bytes into
reply bytes and produces streamed telegrams when they are due; the server owns the
socket or pty, a thread, and the faults a test asks for (a disconnect in the middle of
a telegram, garbage bytes, a wrong checksum, a stall, a reboot).

Times are the host's ``time.monotonic()`` seconds: the simulated devices' clocks are
functions of it.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import select
import socket
import struct
import termios
import threading
import time
import tty
from abc import ABC, abstractmethod
from pathlib import Path
from typing import Protocol

import numpy as np

__all__ = ["DeviceServer", "PtyDeviceServer", "SimDevice", "TcpDeviceServer"]


class SimDevice(Protocol):
    """A simulated device's protocol side (acq.sim.scip_device, acq.sim.cola_device)."""

    def handle(self, data: bytes, now: float) -> bytes:
        """Bytes from the client (any split) -> the bytes the device answers."""
        ...

    def poll(self, now: float) -> bytes:
        """Streamed output due by ``now`` (scans of a running measurement), else b""."""
        ...

    def next_due(self, now: float) -> float | None:
        """When ``poll`` will next have output (monotonic s), None when idle."""
        ...

    def on_disconnect(self) -> None:
        """The client went away: stop streaming, forget partial input."""
        ...

    def reboot(self, now: float) -> None:
        """Restart: clock from zero, settings back to power-on defaults."""
        ...

    def corrupt_next(self) -> None:
        """Give the next telegram a wrong checksum."""
        ...


class DeviceServer(ABC):
    """Runs one device on one transport in a background thread."""

    def __init__(self, device: SimDevice, seed: int = 0) -> None:
        self.device = device
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._rng = np.random.default_rng(seed)
        self._cut_next = False
        self._garbage = b""
        self._silent_until = 0.0
        self._down_until = 0.0
        self._kick = False
        self.bytes_sent = 0
        self.connections = 0

    # --- faults -----------------------------------------------------------------------

    def disconnect_mid_telegram(self) -> None:
        """Send only the first half of the next output, then drop the link."""
        with self._lock:
            self._cut_next = True

    def inject_garbage(self, n: int = 64) -> None:
        """Send ``n`` random bytes before the next output."""
        with self._lock:
            self._garbage += self._rng.integers(0, 256, n, dtype=np.uint8).tobytes()

    def corrupt_checksum(self) -> None:
        with self._lock:
            self.device.corrupt_next()

    def stall(self, seconds: float) -> None:
        """The device says nothing for ``seconds`` (its output meanwhile is lost)."""
        with self._lock:
            self._silent_until = time.monotonic() + seconds

    def reboot(self, seconds: float = 1.0) -> None:
        """Drop the link, be unreachable for ``seconds``, come back with a fresh clock."""
        with self._lock:
            self._down_until = time.monotonic() + seconds
            self._kick = True
            self.device.reboot(self._down_until)

    def disconnect(self) -> None:
        """Drop the link now (a cable pull); the device stays up."""
        with self._lock:
            self._kick = True

    # --- life cycle -------------------------------------------------------------------

    def start(self) -> DeviceServer:
        """Start serving (once: a second call, e.g. ``with server.start():``, is a no-op)."""
        if self._thread is not None:
            return self
        self._thread = threading.Thread(target=self._run, name=type(self).__name__, daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self._close_transport()

    def __enter__(self) -> DeviceServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    @abstractmethod
    def url(self) -> str:
        """What a client opens (a pyserial URL or path)."""

    @abstractmethod
    def _accept(self, timeout: float) -> int | None:
        """Wait for a client; the fd to talk on, or None."""

    @abstractmethod
    def _drop(self, fd: int) -> None:
        """End the current client's link."""

    @abstractmethod
    def _close_transport(self) -> None: ...

    def _write(self, fd: int, data: bytes) -> None:
        view = memoryview(data)
        while view:
            _, w, _ = select.select([], [fd], [], 1.0)
            if not w:
                raise OSError("client not reading")
            n = os.write(fd, view)
            view = view[n:]
            self.bytes_sent += n

    @abstractmethod
    def _go_down(self) -> None:
        """The device is off: it no longer answers on its transport."""

    @abstractmethod
    def _come_up(self) -> None:
        """The device is on again."""

    def _run(self) -> None:
        down = False
        while not self._stop.is_set():
            now = time.monotonic()
            if now < self._down_until:
                if not down:
                    self._go_down()
                    down = True
                time.sleep(min(0.05, self._down_until - now))
                continue
            if down:
                self._come_up()
                down = False
            fd = self._accept(0.1)
            if fd is None:
                continue
            self.connections += 1
            try:
                self._serve(fd)
            except OSError:
                pass
            finally:
                self.device.on_disconnect()
                self._drop(fd)

    def _serve(self, fd: int) -> None:
        while not self._stop.is_set():
            now = time.monotonic()
            with self._lock:
                if self._kick:
                    self._kick = False
                    return
            due = self.device.next_due(now)
            wait = 0.05 if due is None else min(0.05, max(0.0, due - now))
            r, _, _ = select.select([fd], [], [], wait)
            now = time.monotonic()
            out = b""
            if r:
                data = os.read(fd, 65536)
                if not data:
                    return
                out += self.device.handle(data, now)
            out += self.device.poll(now)
            if not out:
                continue
            with self._lock:
                if now < self._silent_until:
                    continue
                garbage, self._garbage = self._garbage, b""
                cut, self._cut_next = self._cut_next, False
            if cut:
                self._write(fd, garbage + out[: max(1, len(out) // 2)])
                return
            self._write(fd, garbage + out)


class TcpDeviceServer(DeviceServer):
    """The device on TCP, 127.0.0.1 by default, one client at a time (as the devices)."""

    def __init__(self, device: SimDevice, host: str = "127.0.0.1", port: int = 0, seed: int = 0):
        super().__init__(device, seed)
        self._listener: socket.socket | None = self._listen(host, port)
        self.host, self.port = self._listener.getsockname()[:2]
        self._client: socket.socket | None = None

    @staticmethod
    def _listen(host: str, port: int) -> socket.socket:
        listener = socket.create_server((host, port), reuse_port=False)
        listener.settimeout(0.1)
        return listener

    def _go_down(self) -> None:
        # A device that is off refuses connections (no listener, so the kernel says RST).
        if self._listener is not None:
            self._listener.close()
            self._listener = None

    def _come_up(self) -> None:
        self._listener = self._listen(self.host, self.port)

    @property
    def url(self) -> str:
        return f"socket://{self.host}:{self.port}"

    def _accept(self, timeout: float) -> int | None:
        if self._listener is None:
            return None
        try:
            conn, _ = self._listener.accept()
        except (TimeoutError, OSError):
            return None
        conn.setblocking(True)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._client = conn
        return conn.fileno()

    def _drop(self, fd: int) -> None:
        if self._client is not None:
            with contextlib.suppress(OSError):
                self._client.shutdown(socket.SHUT_RDWR)
            self._client.close()
            self._client = None

    def _close_transport(self) -> None:
        if self._listener is not None:
            self._listener.close()


class PtyDeviceServer(DeviceServer):
    """The device on a pseudo-terminal, reached through a stable symlink (``url``).

    A real USB device gets a new ttyACM node when it is replugged while its
    /dev/serial/by-id name stays: a disconnect here closes the pty (the client reads
    an error), and the link path then points at a fresh one.
    """

    def __init__(self, device: SimDevice, link: str | Path | None = None, seed: int = 0):
        super().__init__(device, seed)
        self._tmp: str | None = None
        if link is None:
            import tempfile

            self._tmp = tempfile.mkdtemp(prefix="acq-sim-pty-")
            link = Path(self._tmp) / "ttyACM-sim"
        self.link = Path(link)
        self._master: int | None = None
        self._slave: int | None = None
        self._fresh_pty()

    @property
    def url(self) -> str:
        return str(self.link)

    def _fresh_pty(self) -> None:
        master, slave = os.openpty()
        tty.setraw(master)
        tty.setraw(slave)
        name = os.ttyname(slave)
        tmp = self.link.with_name(self.link.name + ".new")
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        tmp.symlink_to(name)
        tmp.replace(self.link)
        self._master, self._slave = master, slave

    def _go_down(self) -> None:
        # Unplugged: the device node and its by-id link disappear.
        with contextlib.suppress(FileNotFoundError):
            self.link.unlink()

    def _come_up(self) -> None:
        pass  # the next _accept makes a fresh pty and points the link at it

    def _accept(self, timeout: float) -> int | None:
        if self._master is None:
            self._fresh_pty()
        # A pty has no connect: the device "talks" as soon as the client writes.
        return self._master

    def _drop(self, fd: int) -> None:
        # Bytes already sent reach the host before the hangup (a pty would discard what
        # the client has not read yet): wait, briefly, for its input queue to drain. The
        # kernel moves written bytes to that queue asynchronously, so the queue must be
        # seen empty twice, a little apart. Up to 2 s: a loaded host may leave the client's
        # reading thread waiting for a core that long.
        deadline = time.monotonic() + 2.0
        empty_seen = 0
        while self._slave is not None and time.monotonic() < deadline and empty_seen < 2:
            time.sleep(0.01)
            try:
                raw = fcntl.ioctl(self._slave, termios.FIONREAD, b"\0" * 4)
            except OSError:
                break
            empty_seen = empty_seen + 1 if struct.unpack("i", raw)[0] == 0 else 0
        for f in (self._master, self._slave):
            if f is not None:
                with contextlib.suppress(OSError):
                    os.close(f)
        self._master = self._slave = None

    def _close_transport(self) -> None:
        self._drop(-1)
        with contextlib.suppress(FileNotFoundError):
            self.link.unlink()
        if self._tmp is not None:  # the folder made for the link, now empty
            with contextlib.suppress(OSError):
                os.rmdir(self._tmp)
