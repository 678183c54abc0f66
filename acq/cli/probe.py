"""`acq probe scanner|camera`: talk to one device, print what it is and what it measures.

What a field engineer runs first: device identity and geometry, then N scans, as text
or as JSON lines (``--json``: one object for the device, one per scan).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from acq import json_text
from acq.cli import output_files
from acq.cli.option_types import integer, real
from acq.cli.output_files import IMAGE_SUFFIXES, Output
from acq.credentials import redact
from acq.errors import InputError

HELP = "talk to one device and print what it says"
MAX_COUNT = 1_000_000  # scans or frames; a frame's time is kept for the rate
TIMEOUT = real(0, 3600, lo_open=True, what="seconds")


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from acq.drivers.camera import camera_driver_names
    from acq.drivers.scanner import driver_names

    probe = sub.add_parser("probe", help=HELP)
    probe_sub = probe.add_subparsers(dest="probe_command", metavar="DEVICE", required=True)
    pscan = probe_sub.add_parser(
        "scanner",
        help="device info, then N scans",
        description="Connect to one laser scanner, print its identity and geometry, then N "
        "scans (with --json: one JSON object for the device, then one per scan with time, "
        "ranges in metres (null where there is no finite range) and intensities).",
    )
    pscan.add_argument("--driver", required=True, choices=driver_names())
    pscan.add_argument(
        "--url",
        required=True,
        help="hokuyo: a pyserial URL (/dev/ttyACM0, /dev/serial/by-id/..., "
        "socket://192.168.0.10:10940); sick: tcp://192.168.0.1:2112",
    )
    pscan.add_argument(
        "--count", type=integer(0, MAX_COUNT), default=10, help="scans to read (default 10)"
    )
    pscan.add_argument("--json", action="store_true", help="JSON lines instead of text")
    pscan.add_argument(
        "--timeout", type=TIMEOUT, default=2.0, help="seconds to wait for data (default 2)"
    )
    pscan.set_defaults(handler=run_scanner)

    pcam = probe_sub.add_parser(
        "camera",
        help="grab N frames: size, rate, timestamps, drops",
        description="Open one camera, print the format it applied, then N frames with their "
        "sequence numbers and times (the middle of exposure, and where that time came from), "
        "the measured rate and the frames known to be dropped.",
    )
    pcam.add_argument("--driver", required=True, choices=camera_driver_names())
    pcam.add_argument(
        "--source",
        required=True,
        help="opencv: an index, /dev/videoN, an http(s)/rtsp URL or a GStreamer pipeline; "
        "v4l2: /dev/videoN or /dev/v4l/by-id/...",
    )
    pcam.add_argument(
        "--count", type=integer(1, MAX_COUNT), default=25, help="frames to grab (default 25)"
    )
    pcam.add_argument(
        "--fps", type=real(0, 1000, lo_open=True, what="frames per second"), default=25.0,
        help="frame rate to request (default 25)",
    )  # fmt: skip
    pcam.add_argument("--json", action="store_true", help="JSON lines instead of text")
    pcam.add_argument(
        "--snapshot", type=Path, metavar="PNG",
        help="write the last frame to this PNG (or .jpg); an existing image is replaced, "
        "any other file refused",
    )  # fmt: skip
    pcam.add_argument(
        "--timeout", type=TIMEOUT, default=2.0, help="seconds to wait for a frame (default 2)"
    )
    pcam.add_argument("--force", action="store_true", help=output_files.FORCE_HELP)
    pcam.set_defaults(handler=run_camera)


class _Failed(Exception):
    """The probe failed; the line is printed already."""


@contextmanager
def _reported(command: str, where: str, close: Callable[[], None]) -> Iterator[None]:
    """A driver or I/O failure becomes one line ``command: where: Kind: message`` and
    :class:`_Failed`; the device is closed in every case."""
    from acq.drivers.errors import DriverError

    try:
        yield
    except (DriverError, OSError) as e:
        kind = f"{type(e).__name__}: " if isinstance(e, DriverError) else ""
        print(redact(f"{command}: {where}: {kind}{e}"), file=sys.stderr)
        raise _Failed from e
    finally:
        close()


def _emit(record: dict[str, Any]) -> None:
    print(redact(json_text.dumps(record, indent=None)), flush=True)


def run_scanner(args: argparse.Namespace) -> int:
    """Connect, print identity and geometry, then --count scans; 0 on success, 1 on failure."""
    import numpy as np

    from acq.drivers.scanner import scanner_for
    from acq.record.probe import scan_json, scanner_device

    scanner = scanner_for(args.driver, args.url, timeout=args.timeout)
    try:
        with _reported("acq probe scanner", args.url, scanner.close):
            info = scanner.connect()
            geo = scanner.geometry
            if args.json:
                _emit({"device": scanner_device(args.driver, args.url, info, geo)})
            else:
                print(f"{info.vendor} {info.model}, serial {info.serial}, firmware {info.firmware}")
                if geo is not None:
                    print(
                        f"{geo.n_points} points from {math.degrees(geo.angle_min):.2f} to "
                        f"{math.degrees(geo.angle_max):.2f} deg (REP-103), step "
                        f"{math.degrees(geo.angle_increment):.4f} deg, "
                        f"{1 / geo.scan_period:.1f} Hz, ranges {geo.range_min:g}-"
                        f"{geo.range_max:g} m"
                    )
            scanner.start()
            t_first = None
            for i in range(args.count):
                scan = scanner.read_scan()
                t_first = t_first if t_first is not None else scan.recv_ns
                if args.json:
                    _emit(scan_json(scan))
                    continue
                r = scan.ranges[np.isfinite(scan.ranges)]
                rate = f", {i / ((scan.recv_ns - t_first) * 1e-9):.1f} Hz" if i else ""
                span = f" ({r.min():.3f}-{r.max():.3f} m)" if r.size else ""
                print(
                    f"scan {i + 1}: {scan.size} points, {r.size} with a range{span}, "
                    f"device ticks {list(scan.device_ticks)}{rate}",
                    flush=True,
                )
            scanner.stop()
    except _Failed:
        return 1
    return 0


def run_camera(args: argparse.Namespace) -> int:
    """Open a camera, print the applied format, then --count frames with their times, the
    measured rate and the drops; --snapshot writes the last frame as a PNG."""
    from acq.drivers.camera import camera_for
    from acq.record.probe import camera_device, frame_json, write_snapshot

    source, snapshot = args.source, args.snapshot
    if snapshot is not None:
        if snapshot.suffix.lower() not in IMAGE_SUFFIXES:
            raise InputError(f"--snapshot {snapshot}: expected a .png or .jpg file")
        output_files.check([], [Output("--snapshot", snapshot, "image")], force=args.force)
    camera = camera_for(args.driver, source, fps=args.fps, timeout=args.timeout)
    try:
        with _reported("acq probe camera", source, camera.close):
            info = camera.connect()
            fmt = camera.format
            if args.json:
                _emit({"device": camera_device(args.driver, source, info, fmt)})
            else:
                print(f"{info.vendor} {info.model} {info.serial}".strip() or redact(source))
                if fmt is not None:
                    print(f"format {fmt.width}x{fmt.height} {fmt.fourcc} at {fmt.fps:g} fps "
                          "(as applied by the device)")  # fmt: skip
            camera.start()
            stamps: list[int] = []
            last = None
            for i in range(args.count):
                frame = camera.read_frame()
                stamps.append(frame.stamp_ns)
                last = frame
                if args.json:
                    _emit(frame_json(frame))
                else:
                    print(f"frame {i + 1}: seq {frame.sequence}, {frame.width}x{frame.height}, "
                          f"{len(frame.jpeg) or 'raw'} {'bytes JPEG' if frame.jpeg else ''}, "
                          f"stamp {frame.stamp_ns * 1e-9:.4f} s ({frame.time_source})",
                          flush=True)  # fmt: skip
            span_s = (stamps[-1] - stamps[0]) * 1e-9 if len(stamps) > 1 else 0.0
            rate = (len(stamps) - 1) / span_s if span_s else 0.0
            summary: dict[str, Any] = {
                "frames": camera.frames,
                "rate_hz": round(rate, 3),
                "drops": camera.drops,
                "corrupt": camera.corrupt,
            }
            if snapshot is not None and last is not None:
                write_snapshot(last, str(snapshot))  # whole or not at all
                summary["snapshot"] = str(snapshot)
            if args.json:
                _emit({"summary": summary})
            else:
                shot = f", snapshot {snapshot}" if snapshot else ""
                print(f"{summary['frames']} frames at {rate:.2f} Hz, {camera.drops} dropped, "
                      f"{camera.corrupt} corrupt{shot}")  # fmt: skip
            camera.stop()
    except _Failed:
        return 1
    return 0
