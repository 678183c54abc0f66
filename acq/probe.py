"""`acq probe scanner`: talk to one scanner, print what it is and what it measures.

What a field engineer runs first: device identity and geometry, then N scans, as text
or as JSON lines (``--json``: one object for the device, one per scan).
"""

from __future__ import annotations

import json
import math
import sys
from typing import Any, TextIO

import numpy as np

from acq.records import Scan

__all__ = ["probe_scanner", "scan_json"]


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


def probe_scanner(
    driver: str,
    url: str,
    count: int = 10,
    as_json: bool = False,
    timeout: float = 2.0,
    out: TextIO | None = None,
) -> int:
    """Connect, print identity and geometry, then ``count`` scans; 0 on success, 1 on failure."""
    from drivers.scanner import ScannerError, scanner_for

    out = out if out is not None else sys.stdout

    scanner = scanner_for(driver, url, timeout=timeout)
    try:
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
        return 0
    except ScannerError as e:
        print(f"acq probe scanner: {url}: {type(e).__name__}: {e}", file=sys.stderr)
        return 1
    except OSError as e:
        print(f"acq probe scanner: {url}: {e}", file=sys.stderr)
        return 1
    finally:
        scanner.close()
