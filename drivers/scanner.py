"""What every laser-scanner driver offers, its typed errors, and the driver registry.

A driver owns one connection and is used from one thread: ``connect()`` identifies the
device and reads its geometry, ``start()`` begins continuous measurement, and
``read_scan()`` blocks (at most ``timeout`` seconds) for the next :class:`acq.records.Scan`.
Reconnection lives in :mod:`acq.drivers.reconnect`, not in the drivers. The registry maps a
configuration's ``driver:`` key to a class, the way python-can maps an interface name.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar

from acq.drivers.errors import ConnectionLost, DeviceError, DriverError, ProtocolError, ReadTimeout
from acq.drivers.registry import REGISTRIES, Registry
from acq.records import DeviceInfo, Scan

__all__ = [
    "SCANNERS",
    "ConnectionLost",
    "DeviceError",
    "ProtocolError",
    "ScanGeometry",
    "ScanTimeout",
    "Scanner",
    "ScannerError",
    "driver_names",
    "scanner_for",
]


# The scanner names of the shared driver errors.
ScannerError = DriverError
ScanTimeout = ReadTimeout  # no complete telegram within the timeout (a stalled stream)


@dataclass(frozen=True)
class ScanGeometry:
    """A scanner's measurement geometry in the REP-103 laser frame.

    Angles in radians (0 along x, counter-clockwise about z), times in seconds, ranges
    in metres. ``n_points`` is the number of points the driver delivers per scan (after
    any cropping). ``stamp_offset_s`` is the time from the instant the device's time
    stamp refers to until point 0 was measured (Hokuyo stamps a fixed step behind the
    sensor, not the first point; SICK stamps the first point).
    """

    angle_min: float
    angle_increment: float
    n_points: int
    scan_period: float
    time_increment: float
    range_min: float
    range_max: float
    stamp_offset_s: float = 0.0

    @property
    def angle_max(self) -> float:
        return self.angle_min + self.angle_increment * (self.n_points - 1)


class Scanner(ABC):
    """One connection to one laser scanner (blocking, one thread)."""

    driver: ClassVar[str] = ""
    tick_hz: ClassVar[float] = 1000.0  # the device clock in Scan.device_ticks[0]
    tick_bits: ClassVar[int] = 24  # its counter width (it wraps at 2**tick_bits)
    # what the configuration checks and replay serves, per driver:
    wire: ClassVar[str] = ""  # the wire protocol family (SCIP, CoLa); "" for none we know
    url_kind: ClassVar[str] = ""  # "serial": a pyserial URL; "tcp": tcp://host:port
    protocols: ClassVar[tuple[str, ...]] = ()  # encodings ``protocol:`` picks; default first
    # how ``latency_s: auto`` is measured ("": it is not): by time queries before
    # streaming (``measure_latency``) or from each telegram (``telegram_latency_s``)
    latency_probe: ClassVar[str] = ""

    def __init__(self, url: str, *, name: str = "laser", timeout: float = 1.0) -> None:
        self.url = url
        self.name = name
        self.timeout = timeout
        self.info: DeviceInfo | None = None
        self.geometry: ScanGeometry | None = None

    @abstractmethod
    def connect(self) -> DeviceInfo:
        """Open the transport, identify the device, read its geometry; sets ``info``."""

    @abstractmethod
    def start(self) -> None:
        """Start continuous measurement."""

    @abstractmethod
    def read_scan(self) -> Scan:
        """The next scan; raises ScanTimeout, ConnectionLost, ProtocolError, DeviceError."""

    @abstractmethod
    def stop(self) -> None:
        """Stop measurement (the connection stays open)."""

    @abstractmethod
    def close(self) -> None:
        """Close the transport; safe to call twice and after a failure."""

    def telegram_latency_s(self, scan: Scan) -> float | None:
        """Seconds from the instant ``scan``'s stamp (``device_ticks[0]``) refers to until
        the device sent it, where its telegram says (None: it does not)."""
        return None

    def __enter__(self) -> Scanner:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


SCANNERS: Registry[Scanner] = REGISTRIES["scanner"]


def driver_names() -> list[str]:
    return SCANNERS.names()


def scanner_for(driver: str, url: str, **options: Any) -> Scanner:
    """A driver instance for ``driver`` (a name in :data:`SCANNERS`) talking to ``url``."""
    return SCANNERS.create(driver, url, **options)
