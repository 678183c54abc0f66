"""The typed errors every driver raises (scanners, cameras, odometry, GNSS)."""

from __future__ import annotations

from acq.errors import AcqError

__all__ = ["ConnectionLost", "DeviceError", "DriverError", "ProtocolError", "ReadTimeout"]


class DriverError(AcqError):
    """Base of every device failure."""


class ProtocolError(DriverError):
    """Bytes that do not follow the protocol; the message says where (command, offset)."""


class DeviceError(DriverError):
    """The device answered with an error status (``status`` holds it as sent)."""

    def __init__(self, message: str, status: str = "") -> None:
        super().__init__(message)
        self.status = status


class ConnectionLost(DriverError):
    """The transport closed or failed (cable pulled, device rebooting)."""


class ReadTimeout(DriverError):
    """Nothing complete arrived within the timeout (a stalled stream)."""
