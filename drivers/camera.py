"""What every camera driver offers, and the camera driver registry.

A driver owns one capture and is used from one thread: ``connect()`` opens the source
and applies the requested format (reading back what the device really applied),
``start()`` begins streaming, ``read_frame()`` blocks (at most ``timeout`` seconds) for
the next :class:`acq.records.Frame`. Every frame carries its time source (``kernel``
buffer timestamps, or ``receipt`` less the configured latency) and its sequence number;
drivers count the frames they know were dropped in ``drops``. Reconnection lives in
:class:`acq.drivers.reconnect.Relink`, as for the scanners.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar

from acq.drivers.errors import ConnectionLost, DeviceError, DriverError, ProtocolError, ReadTimeout
from acq.drivers.registry import REGISTRIES, Registry
from acq.records import DeviceInfo, Frame

__all__ = [
    "CAMERAS",
    "Camera",
    "ConnectionLost",
    "DeviceError",
    "DriverError",
    "FrameFormat",
    "FrameTimeout",
    "ProtocolError",
    "camera_class",
    "camera_driver_names",
    "camera_for",
]

FrameTimeout = ReadTimeout  # no frame within the timeout (a stalled camera)


@dataclass(frozen=True)
class FrameFormat:
    """A capture format: pixels, frames per second, and the FOURCC (``MJPG``, ``YUYV``...)."""

    width: int
    height: int
    fps: float
    fourcc: str


class Camera(ABC):
    """One capture from one camera (blocking, one thread).

    ``source`` is what the driver opens (an index, ``/dev/videoN``, a URL, a pipeline);
    ``width``/``height``/``fps``/``fourcc`` are requests, ``format`` what was applied.
    ``latency_s`` is the nominal delay from the middle of the exposure to receipt, used
    where the source gives no better time.
    """

    driver: ClassVar[str] = ""

    def __init__(
        self,
        source: str,
        *,
        name: str = "camera",
        width: int | None = None,
        height: int | None = None,
        fps: float = 25.0,
        fourcc: str | None = None,
        latency_s: float = 0.0,
        timeout: float = 1.0,
    ) -> None:
        self.source = source
        self.name = name
        self.width = width
        self.height = height
        self.fps = fps
        self.fourcc = fourcc
        self.latency_s = latency_s
        self.timeout = timeout
        self.info: DeviceInfo | None = None
        self.format: FrameFormat | None = None
        self.frames = 0  # delivered
        self.drops = 0  # known to be lost (sequence gaps, time gaps)
        self.corrupt = 0  # received but unusable (bad JPEG), skipped

    @property
    def url(self) -> str:
        """The source as a string, for logs and reachability checks."""
        return self.source

    @abstractmethod
    def connect(self) -> DeviceInfo:
        """Open the source, apply and read back the format; sets ``info`` and ``format``."""

    @abstractmethod
    def start(self) -> None:
        """Start streaming."""

    @abstractmethod
    def read_frame(self) -> Frame:
        """The next frame; raises FrameTimeout, ConnectionLost, ProtocolError, DeviceError."""

    @abstractmethod
    def stop(self) -> None:
        """Stop streaming (the source stays open)."""

    @abstractmethod
    def close(self) -> None:
        """Release the source; safe to call twice and after a failure."""

    def __enter__(self) -> Camera:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


CAMERAS: Registry[Camera] = REGISTRIES["camera"]


def camera_driver_names() -> list[str]:
    return CAMERAS.names()


def camera_class(driver: str) -> type[Camera]:
    """The class registered for a configuration's camera ``driver:`` value."""
    return CAMERAS.get(driver)


def camera_for(driver: str, source: str, **options: Any) -> Camera:
    """A driver instance for ``driver`` (a name in :data:`CAMERAS`) capturing from ``source``."""
    return CAMERAS.create(driver, source, **options)
