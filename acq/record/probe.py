"""What `acq probe scanner|camera` reports of one device: its identity and geometry or
format, each scan or frame, as JSON-ready dicts (the command, :mod:`acq.cli.probe`,
prints them as text or JSON lines)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from acq.drivers.camera import FrameFormat
from acq.drivers.scanner import ScanGeometry
from acq.provenance import write_image
from acq.records import DeviceInfo, Frame, Scan

__all__ = ["camera_device", "frame_json", "scan_json", "scanner_device", "write_snapshot"]


def _finite_or_none(values: np.ndarray, digits: int) -> list[float | None]:
    return [round(float(v), digits) if math.isfinite(v) else None for v in values]


def scan_json(scan: Scan) -> dict[str, Any]:
    """A scan as a JSON-ready dict: time (host monotonic s), ranges (m, null where there is
    no finite range) and counts of the REP-117 codes."""
    r = scan.ranges
    return {
        "time": scan.recv_ns * 1e-9,
        "device_ticks": list(scan.device_ticks),
        "sequence": scan.sequence,
        "angle_min": scan.angle_min,
        "angle_increment": scan.angle_increment,
        "time_increment": scan.time_increment,
        "ranges": _finite_or_none(r, 4),
        "intensities": _finite_or_none(scan.intensities, 1),
        "no_return": int(np.sum(r == np.inf)),
        "too_close": int(np.sum(r == -np.inf)),
        "error": int(np.sum(np.isnan(r))),
    }


def scanner_device(
    driver: str, url: str, info: DeviceInfo, geo: ScanGeometry | None
) -> dict[str, Any]:
    """A scanner's identity and geometry (radians, metres, seconds) as a JSON-ready dict."""
    device: dict[str, Any] = {
        "driver": driver,
        "url": url,
        "vendor": info.vendor,
        "model": info.model,
        "serial": info.serial,
        "firmware": info.firmware,
        **({"extra": info.extra} if info.extra else {}),
    }
    if geo is not None:
        device.update(
            angle_min=geo.angle_min,
            angle_max=geo.angle_max,
            angle_increment=geo.angle_increment,
            points=geo.n_points,
            scan_period=geo.scan_period,
            range_min=geo.range_min,
            range_max=geo.range_max,
        )
    return device


def camera_device(
    driver: str, source: str, info: DeviceInfo, fmt: FrameFormat | None
) -> dict[str, Any]:
    """A camera's identity and applied format as a JSON-ready dict."""
    device: dict[str, Any] = {
        "driver": driver,
        "source": source,
        "vendor": info.vendor,
        "model": info.model,
        "serial": info.serial,
        **({"extra": info.extra} if info.extra else {}),
    }
    if fmt is not None:
        device.update(width=fmt.width, height=fmt.height, fps=fmt.fps, fourcc=fmt.fourcc)
    return device


def frame_json(frame: Frame) -> dict[str, Any]:
    """A frame's sequence, times (host monotonic s), size and JPEG length."""
    return {
        "sequence": frame.sequence,
        "recv": frame.recv_ns * 1e-9,
        "stamp": frame.stamp_ns * 1e-9,
        "time_source": frame.time_source,
        "width": frame.width,
        "height": frame.height,
        "jpeg_bytes": len(frame.jpeg),
    }


def write_snapshot(frame: Frame, path: str) -> None:
    """The frame as an image file (PNG by the name); OSError when it cannot be written."""
    import cv2

    image = frame.image
    if image is None:
        image = cv2.imdecode(np.frombuffer(frame.jpeg, np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise OSError(f"{path}: the frame does not decode: no snapshot")
    write_image(path, image)
