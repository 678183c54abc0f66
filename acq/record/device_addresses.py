"""How the configuration addresses each driver's device: pyserial URLs for serial
drivers, tcp://host:port for a SICK (CoLa) scanner, and what our camera drivers open
(:data:`CAMERA_SOURCES`). Each check returns the address as the driver takes it, or
raises :func:`acq.yamlcheck.fail` naming what was expected."""

from __future__ import annotations

import re
from urllib.parse import urlsplit

from acq.yamlcheck import fail

__all__ = ["CAMERA_SOURCES", "camera_source", "host_port", "serial_url", "tcp_url"]

# pyserial's URL handlers (serial.protocol_handler_*); tcp:// is taken as socket://
_SERIAL_SCHEMES = {"socket", "tcp", "rfc2217", "loop", "spy", "alt", "hwgrep", "cp2110"}
_SCHEME = re.compile(r"([A-Za-z][A-Za-z0-9+.-]*)://")
# the URLs OpenCV's FFmpeg backend streams from (http and https are read natively)
_OPENCV_SCHEMES = ("http", "https", "rtsp", "rtsps", "rtmp", "rtmps", "rtp", "udp", "tcp", "srt")
CAMERA_SOURCES = {
    "opencv": "an index (0), /dev/videoN, a video file, a GStreamer pipeline (with '!') or a "
    "URL (" + ", ".join(f"{s}://" for s in _OPENCV_SCHEMES) + ")",
    "v4l2": "an index (0) or a device path (/dev/videoN, /dev/v4l/by-id/...)",
}
"""What each of our camera drivers opens (a third-party driver's ``source`` is its own)."""


def host_port(v: str, rest: str, default_port: int | None, expected: str) -> None:
    host, sep, port = rest.rstrip("/").rpartition(":")
    if not sep:
        host, port = rest.rstrip("/"), ""
    if not host or (not port and default_port is None):
        raise fail(f"expected {expected}, got {v!r}")
    if port and not (port.isdigit() and 0 < int(port) < 65536):
        raise fail(f"expected {expected} with a port 1..65535, got {v!r}")


def serial_url(v: str) -> str:
    """A pyserial URL (a device path or scheme://...); tcp://host:port becomes socket://."""
    expected = "a pyserial URL (/dev/..., socket://host:port)"
    scheme, sep, rest = v.partition("://")
    if not sep:
        if not v.strip():
            raise fail(f"expected {expected}, got {v!r}")
        return v
    if scheme not in _SERIAL_SCHEMES:
        raise fail(f"expected {expected}; unknown scheme {scheme}://")
    if scheme in ("socket", "tcp"):
        host_port(v, rest.split("?")[0], None, "socket://host:port")
        return "socket://" + rest
    return v


def tcp_url(v: str, driver: str) -> str:
    """tcp://host:port or host[:port], as the SICK driver takes it (socket:// is pyserial's
    spelling, for serial drivers: refused)."""
    expected = "tcp://host:port or host[:port]"
    scheme, sep, rest = v.partition("://")
    if sep and scheme == "socket":
        raise fail(
            f"expected {expected} for driver {driver} (a TCP device); socket:// is a pyserial "
            f"URL, for serial drivers: write tcp://{rest}"
        )
    if sep and scheme != "tcp":
        raise fail(f"expected {expected} for driver {driver}, got {v!r}")
    host_port(v, rest if sep else v, 2112, "tcp://host:port")
    return v


def camera_source(driver: str, v: str) -> str:
    """``v`` if camera driver ``driver`` can open it (see :data:`CAMERA_SOURCES`)."""
    accepted = CAMERA_SOURCES.get(driver)
    if accepted is None:
        return v
    expected = f"expected {accepted} for driver {driver}"
    if not v.strip() or not v.isprintable():
        raise fail(f"{expected}, got {v!r}")
    scheme = _SCHEME.match(v)
    if driver == "v4l2":
        if v.isdigit() or (v.startswith("/") and scheme is None):
            return v
        raise fail(f"{expected}, got {v!r}")
    if scheme is None:
        return v  # an index, a device, a file, an image-sequence pattern or a pipeline
    if scheme.group(1).lower() not in _OPENCV_SCHEMES:
        raise fail(f"{expected}; unknown scheme {scheme.group(1)}://")
    try:
        url = urlsplit(v)
        url.port  # noqa: B018 (raises for a port out of range)
    except ValueError:
        raise fail(f"{expected}; a bad host or port in {v!r}") from None
    if not url.hostname:
        raise fail(f"{expected}; no host in {v!r}")
    return v
