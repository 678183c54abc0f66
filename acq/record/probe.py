"""`acq probe scanner|camera`: talk to one device, print what it is and what it measures.

What a field engineer runs first: device identity and geometry, then N scans, as text
or as JSON lines (``--json``: one object for the device, one per scan).
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, TextIO

import numpy as np

from acq.records import Scan

__all__ = ["probe_camera", "probe_scanner", "scan_json"]


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


@dataclass
class _Outcome:
    failed: bool = False


@contextmanager
def _reported(command: str, where: str, close: Callable[[], None]) -> Iterator[_Outcome]:
    """Run a probe: a driver or I/O failure becomes one line on stderr and
    ``outcome.failed``; the device is closed in every case."""
    from acq.drivers.errors import DriverError

    outcome = _Outcome()
    try:
        yield outcome
    except (DriverError, OSError) as e:
        kind = f"{type(e).__name__}: " if isinstance(e, DriverError) else ""
        print(f"{command}: {where}: {kind}{e}", file=sys.stderr)
        outcome.failed = True
    finally:
        close()


def probe_scanner(
    driver: str,
    url: str,
    count: int = 10,
    as_json: bool = False,
    timeout: float = 2.0,
    out: TextIO | None = None,
) -> int:
    """Connect, print identity and geometry, then ``count`` scans; 0 on success, 1 on failure."""
    from acq.drivers.scanner import scanner_for

    out = out if out is not None else sys.stdout
    scanner = scanner_for(driver, url, timeout=timeout)
    with _reported("acq probe scanner", url, scanner.close) as outcome:
        info = scanner.connect()
        geo = scanner.geometry
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
        if as_json:
            print(json.dumps({"device": device}), file=out, flush=True)
        else:
            print(f"{info.vendor} {info.model}, serial {info.serial}, firmware {info.firmware}",
                  file=out)  # fmt: skip
            if geo is not None:
                print(
                    f"{geo.n_points} points from {math.degrees(geo.angle_min):.2f} to "
                    f"{math.degrees(geo.angle_max):.2f} deg (REP-103), step "
                    f"{math.degrees(geo.angle_increment):.4f} deg, "
                    f"{1 / geo.scan_period:.1f} Hz, ranges {geo.range_min:g}-{geo.range_max:g} m",
                    file=out,
                )
        scanner.start()
        t_first = None
        for i in range(count):
            scan = scanner.read_scan()
            t_first = t_first if t_first is not None else scan.recv_ns
            if as_json:
                print(json.dumps(scan_json(scan)), file=out, flush=True)
                continue
            r = scan.ranges[np.isfinite(scan.ranges)]
            rate = f", {i / ((scan.recv_ns - t_first) * 1e-9):.1f} Hz" if i else ""
            span = f" ({r.min():.3f}-{r.max():.3f} m)" if r.size else ""
            print(
                f"scan {i + 1}: {scan.size} points, {r.size} with a range{span}, "
                f"device ticks {list(scan.device_ticks)}{rate}",
                file=out,
                flush=True,
            )
        scanner.stop()
    return 1 if outcome.failed else 0


def probe_camera(
    driver: str,
    source: str,
    count: int = 25,
    as_json: bool = False,
    snapshot: str | None = None,
    fps: float = 25.0,
    timeout: float = 2.0,
    out: TextIO | None = None,
) -> int:
    """Open a camera, print the applied format, then ``count`` frames with their times,
    the measured rate and the drops; ``snapshot`` writes the last frame as a PNG."""
    import cv2

    from acq.drivers.camera import camera_for

    out = out if out is not None else sys.stdout
    camera = camera_for(driver, source, fps=fps, timeout=timeout)
    with _reported("acq probe camera", source, camera.close) as outcome:
        info = camera.connect()
        fmt = camera.format
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
        if as_json:
            print(json.dumps({"device": device}), file=out, flush=True)
        else:
            print(f"{info.vendor} {info.model} {info.serial}".strip() or source, file=out)
            if fmt is not None:
                print(f"format {fmt.width}x{fmt.height} {fmt.fourcc} at {fmt.fps:g} fps "
                      "(as applied by the device)", file=out)  # fmt: skip
        camera.start()
        stamps: list[int] = []
        last = None
        for i in range(count):
            frame = camera.read_frame()
            stamps.append(frame.stamp_ns)
            last = frame
            record = {
                "sequence": frame.sequence,
                "recv": frame.recv_ns * 1e-9,
                "stamp": frame.stamp_ns * 1e-9,
                "time_source": frame.time_source,
                "width": frame.width,
                "height": frame.height,
                "jpeg_bytes": len(frame.jpeg),
            }
            if as_json:
                print(json.dumps(record), file=out, flush=True)
            else:
                print(f"frame {i + 1}: seq {frame.sequence}, {frame.width}x{frame.height}, "
                      f"{len(frame.jpeg) or 'raw'} {'bytes JPEG' if frame.jpeg else ''}, "
                      f"stamp {frame.stamp_ns * 1e-9:.4f} s ({frame.time_source})",
                      file=out, flush=True)  # fmt: skip
        rate = (len(stamps) - 1) / ((stamps[-1] - stamps[0]) * 1e-9) if len(stamps) > 1 else 0.0
        summary: dict[str, Any] = {
            "frames": camera.frames,
            "rate_hz": round(rate, 3),
            "drops": camera.drops,
            "corrupt": camera.corrupt,
        }
        if snapshot is not None and last is not None:
            image = last.image
            if image is None:
                image = cv2.imdecode(np.frombuffer(last.jpeg, np.uint8), cv2.IMREAD_COLOR)
            if image is None or not cv2.imwrite(snapshot, image):
                raise OSError(f"{snapshot}: cannot write the snapshot")
            summary["snapshot"] = snapshot
        if as_json:
            print(json.dumps({"summary": summary}), file=out, flush=True)
        else:
            print(f"{summary['frames']} frames at {rate:.2f} Hz, {camera.drops} dropped, "
                  f"{camera.corrupt} corrupt" + (f", snapshot {snapshot}" if snapshot else ""),
                  file=out)  # fmt: skip
        camera.stop()
    return 1 if outcome.failed else 0
