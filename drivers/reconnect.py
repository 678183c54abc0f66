"""Keeping a scanner streaming through cable pulls, reboots and stalls.

:class:`Reconnecting` wraps any :class:`acq.drivers.scanner.Scanner`: it connects, starts
measurement and yields scans; when the link fails (an I/O error, end of stream, a
device error, or nothing complete for ``stall_periods`` record periods) it closes
the driver and tries again with exponential backoff (0.5 s doubling to 5 s). Any other
exception the driver raises (a bug, a parser meeting bytes it was not written for) is a
``fault``: the link closes the driver too and waits its own backoff before connecting
again (growing while faults keep coming), so one device's bug neither ends the stream
nor spins reconnecting. While it waits it watches, cheaply, whether the device is
reachable again (the serial node is back, the TCP port answers), and then tries at once:
scans flow again well within 2 s of the device coming back, whatever the backoff had
reached. :class:`Reconnecting`
is the scanners' version: it also reports a device clock that restarted (a reboot),
never hiding it. Cameras use :class:`Relink` with their frame period.
"""

from __future__ import annotations

import math
import os
import socket
import threading
import time
from collections.abc import Callable, Generator, Iterator
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar
from urllib.parse import urlsplit

from acq.drivers.camera import Camera
from acq.drivers.errors import ConnectionLost, DeviceError, DriverError, ProtocolError, ReadTimeout
from acq.drivers.scanner import Scanner
from acq.records import DeviceInfo, Frame, Scan
from acq.time.clocksync import Unwrapper

__all__ = [
    "CAMERA_STALL_S",
    "Backoff",
    "CameraLink",
    "LinkEvent",
    "Reconnecting",
    "Relink",
    "describe",
    "url_reachable",
]

R = TypeVar("R")


class Driver(Protocol):
    """What :class:`Relink` needs of a driver."""

    timeout: float

    @property
    def url(self) -> str: ...

    def connect(self) -> DeviceInfo: ...
    def start(self) -> None: ...
    def stop(self) -> None: ...
    def close(self) -> None: ...


@dataclass(frozen=True)
class LinkEvent:
    """Something that happened to a device's link, for logs and /acq/status."""

    kind: str  # connected | connect_failed | disconnected | stalled | protocol_error
    #            | device_error | fault | clock_reset
    mono_ns: int  # host monotonic time
    detail: str = ""
    error: BaseException | None = None  # what was raised, for a traceback (a fault's)


@dataclass
class Backoff:
    """Delays between connection attempts: ``first`` doubling up to ``cap`` seconds."""

    first: float = 0.5
    cap: float = 5.0
    _next: float = 0.0

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._next = self.first

    def next(self) -> float:
        delay = self._next
        self._next = min(self.cap, self._next * 2)
        return delay


_DEFAULT_PORTS = {"http": 80, "https": 443, "rtsp": 554}
FAULTS_FORGOTTEN_S = 30.0  # after this long without a fault, the fault backoff starts afresh
CAMERA_STALL_S = 1.0  # a camera's stream without a frame for this long is closed, s


def describe(e: BaseException) -> str:
    """One line for an exception: a driver's message as it is; anything else (a bug)
    with its type, which its message alone may not make clear (``IndexError: 4``)."""
    text = str(e).splitlines()[0] if str(e) else ""
    if isinstance(e, DriverError | OSError):
        return text or type(e).__name__
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


def url_reachable(url: str, timeout: float = 0.2) -> bool:
    """Cheap check that a device may answer: its TCP port accepts (socket://, tcp://,
    http://, rtsp://, host:port), or its device node exists (a path, a camera index)."""
    if "://" in url:
        parts = urlsplit(url)
        port = parts.port or _DEFAULT_PORTS.get(parts.scheme)
        if parts.scheme in ("socket", "tcp", *_DEFAULT_PORTS) and parts.hostname and port:
            try:
                with socket.create_connection((parts.hostname, port), timeout=timeout):
                    return True
            except OSError:
                return False
        return True  # other URL handlers: no cheap check, rely on the backoff
    if url.isdigit():  # an OpenCV camera index
        return os.path.exists(f"/dev/video{url}")
    if "!" in url:  # a GStreamer pipeline
        return True
    if ":" in url and not url.startswith("/"):
        host, _, port_text = url.rpartition(":")
        return url_reachable(f"tcp://{host}:{port_text}", timeout)
    return os.path.exists(url)


class Relink(Generic[R]):
    """Yields the records ``read()`` returns for as long as asked, reconnecting as needed.

    ``on_event`` receives every :class:`LinkEvent`; ``on_connect`` runs at each
    connection, the device identified and not yet streaming (time queries go there);
    a connected device with no record for ``stall_periods`` record periods (at least
    ``min_stall_s`` seconds) is stalled: closed and connected again; counters
    (``disconnects``, ``protocol_errors``, ``faults``) are kept for status reports.
    """

    def __init__(
        self,
        device: Driver,
        read: Callable[[], R],
        *,
        backoff: Backoff | None = None,
        stall_periods: float = 3.0,
        min_stall_s: float = 0.25,
        max_protocol_errors: int = 10,
        on_event: Callable[[LinkEvent], None] | None = None,
        on_connect: Callable[[], None] | None = None,
        reachable: Callable[[str], bool] = url_reachable,
    ) -> None:
        self.device = device
        self.on_connect = on_connect
        self.read = read
        self.backoff = backoff if backoff is not None else Backoff()
        self.stall_periods = stall_periods
        self.min_stall_s = min_stall_s
        self.max_protocol_errors = max_protocol_errors
        self.on_event = on_event
        self.reachable = reachable
        self.connected = False
        self.disconnects = 0
        self.protocol_errors = 0
        self.faults = 0
        self._fault_backoff = Backoff(self.backoff.first, self.backoff.cap)
        self._last_fault = -math.inf  # monotonic s
        self._command_timeout = device.timeout  # for replies during connect

    def _emit(self, kind: str, detail: str = "", error: BaseException | None = None) -> None:
        if self.on_event is not None:
            self.on_event(LinkEvent(kind, time.monotonic_ns(), detail, error))

    def period(self) -> float | None:
        """Seconds between records once connected (None: unknown, keep the timeout)."""
        return None

    def check(self, record: R) -> None:
        """Look at each record before it is yielded (subclasses report anomalies)."""

    def _connect(self) -> None:
        self.device.timeout = self._command_timeout
        info = self.device.connect()
        if self.on_connect is not None:
            self.on_connect()
        self.device.start()
        period = self.period()
        if period is not None:
            # a stream with nothing for this long is stalled (at least min_stall_s: a busy
            # host can hold a reader up for tens of ms, which is not a stalled device)
            self.device.timeout = max(self.stall_periods * period, self.min_stall_s)
        self.connected = True
        self.backoff.reset()
        self._emit("connected", f"{info.vendor} {info.model} {info.serial}".strip())

    def _drop(self, kind: str, detail: str, error: BaseException | None = None) -> None:
        self.connected = False
        self.disconnects += 1
        self._emit(kind, detail, error)
        self._close()

    def _close(self) -> None:
        """Close the driver, whatever its close raises (it is being given up on)."""
        try:
            self.device.close()
        except Exception:
            pass

    def _fault_delay(self) -> float:
        """Seconds to wait after a fault of a connected device: its own backoff (a
        successful connection resets the other), afresh after a quiet while."""
        now = time.monotonic()
        if now - self._last_fault > FAULTS_FORGOTTEN_S:
            self._fault_backoff.reset()
        self._last_fault = now
        return self._fault_backoff.next()

    def _wait(self, delay: float, stop: threading.Event) -> None:
        """Sleep up to ``delay`` s, returning early when the device becomes reachable."""
        url = self.device.url
        deadline = time.monotonic() + delay
        was_reachable = self.reachable(url)
        while not stop.is_set():
            left = deadline - time.monotonic()
            if left <= 0:
                return
            stop.wait(min(0.1, left))
            now_reachable = self.reachable(url)
            if now_reachable and not was_reachable:
                return  # it came back: try at once
            was_reachable = now_reachable

    def records(self, stop: threading.Event | None = None) -> Generator[R, None, None]:
        """Records until ``stop`` is set (forever without one)."""
        stop = stop if stop is not None else threading.Event()
        errors_in_row = 0
        try:
            while not stop.is_set():
                if not self.connected:
                    try:
                        self._connect()
                    except (DriverError, OSError) as e:
                        self._emit("connect_failed", describe(e))
                        self._close()
                        self._wait(self.backoff.next(), stop)
                        continue
                    except Exception as e:  # a driver's bug, or bytes it cannot parse
                        self.connected = False
                        self.faults += 1
                        self._emit("fault", describe(e), e)
                        self._close()
                        self._wait(self.backoff.next(), stop)
                        continue
                try:
                    record = self.read()
                    self.check(record)
                except ProtocolError as e:
                    self.protocol_errors += 1
                    errors_in_row += 1
                    self._emit("protocol_error", str(e))
                    if errors_in_row >= self.max_protocol_errors:
                        self._drop("disconnected", f"{errors_in_row} bad telegrams in a row")
                    continue
                except ReadTimeout as e:
                    self._drop("stalled", str(e))
                    continue
                except DeviceError as e:
                    self._drop("device_error", str(e))
                    continue
                except (ConnectionLost, OSError) as e:
                    self._drop("disconnected", str(e))
                    continue
                except Exception as e:  # a driver's bug, or bytes it cannot parse
                    self.faults += 1
                    self._drop("fault", describe(e), e)
                    self._wait(self._fault_delay(), stop)
                    continue
                errors_in_row = 0
                yield record
        finally:
            if self.connected:
                try:
                    self.device.stop()
                except Exception:
                    pass
            self._close()
            self.connected = False


class Reconnecting(Relink[Scan]):
    """A scanner's scans through reconnections; a restarted device clock is reported."""

    def __init__(self, scanner: Scanner, **options: Any) -> None:
        """``options`` as for :class:`Relink`."""
        super().__init__(scanner, scanner.read_scan, **options)
        self.scanner = scanner
        self.clock_resets = 0
        cls = type(scanner)
        self._unwrapper = Unwrapper(cls.tick_hz, cls.tick_bits)  # detects restarts

    def period(self) -> float | None:
        geometry = self.scanner.geometry
        return None if geometry is None else geometry.scan_period

    def check(self, record: Scan) -> None:
        self._check_clock(record)

    def _check_clock(self, scan: Scan) -> None:
        if not scan.device_ticks:
            return
        epoch = self._unwrapper.epoch
        self._unwrapper.unwrap(scan.device_ticks[0], scan.recv_ns)
        if self._unwrapper.epoch != epoch:
            self.clock_resets += 1
            self._emit(
                "clock_reset",
                f"device clock read {scan.device_ticks[0]}, which the host time since the "
                "last scan cannot explain: the device restarted its clock",
            )

    def scans(self, stop: threading.Event | None = None) -> Iterator[Scan]:
        """Scans until ``stop`` is set (forever without one)."""
        return self.records(stop)


class CameraLink(Relink[Frame]):
    """A camera's frames through reconnections (an unplugged, stalled or hostile camera).

    A stream is closed as stalled only after :data:`CAMERA_STALL_S` without a frame (or
    ``stall_periods`` frame periods, if longer): a frame late by a few periods (a busy
    camera or host) comes on the same connection, which costs nothing to keep, whereas
    closing it would lose every frame sent until the next connection is made; a
    camera that goes away closes its connection, which is noticed at once. A camera
    that takes a connection but sends no frame within the timeout (stalled, or
    its process frozen) is tried again at once, not after a growing backoff: each attempt
    waits its timeout anyway, and the attempt in flight gets the first frame the moment
    the camera sends again. A connection that ends, other than by a stall, within
    ``settle_s`` of being made and before it gave ``settle_frames`` frames (a camera
    that floods junk after a good frame, or hangs up after each) is not made again at
    once: the next attempt waits a backoff of its own, which grows while that goes on
    and is reset by a connection that lasts or streams. Any other is made again at once,
    so frames flow again within a frame or two of the camera taking connections.
    """

    def __init__(
        self, camera: Camera, *, settle_s: float = 1.0, settle_frames: int = 5, **options: Any
    ) -> None:
        """``options`` as for :class:`Relink`."""
        options.setdefault("min_stall_s", CAMERA_STALL_S)
        super().__init__(camera, camera.read_frame, **options)
        self.camera = camera
        self.settle_s = settle_s
        self.settle_frames = settle_frames
        self._frames = 0  # frames read on this connection
        self.hold_off = Backoff()  # before reconnecting after a connection that did not last
        self._stop = threading.Event()
        self._connected_at = 0.0  # monotonic s
        self._timed_out = False  # the last connection attempt: a frame was not sent in time

    def period(self) -> float | None:
        fmt = self.camera.format
        fps = fmt.fps if fmt is not None and fmt.fps > 0 else self.camera.fps
        return 1.0 / fps if fps > 0 else None

    def _connect(self) -> None:
        self._timed_out = False
        try:
            super()._connect()
        except ReadTimeout:
            self._timed_out = True
            raise
        self._connected_at = time.monotonic()
        self._frames = 0

    def check(self, record: Frame) -> None:
        self._frames += 1

    def _wait(self, delay: float, stop: threading.Event) -> None:
        if self._timed_out:
            self._timed_out = False
            return  # the attempt waited its timeout: try again at once
        super()._wait(delay, stop)

    def _drop(self, kind: str, detail: str, error: BaseException | None = None) -> None:
        super()._drop(kind, detail, error)
        if kind == "stalled":
            return
        lasted = time.monotonic() - self._connected_at >= self.settle_s
        if lasted or self._frames >= self.settle_frames:
            self.hold_off.reset()
            return
        super()._wait(self.hold_off.next(), self._stop)

    def records(self, stop: threading.Event | None = None) -> Generator[Frame, None, None]:
        """Frames until ``stop`` is set (forever without one)."""
        self._stop = stop if stop is not None else threading.Event()
        return super().records(self._stop)

    def frames(self, stop: threading.Event | None = None) -> Iterator[Frame]:
        """Frames until ``stop`` is set (forever without one)."""
        return self.records(stop)
